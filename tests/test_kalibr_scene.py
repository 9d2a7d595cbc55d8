"""Scene files with ``[camera] kalibr = "camera.yaml"`` (no Mitsuba needed)."""

from __future__ import annotations

import pytest

from ifmi.errors import InputError
from ifmi.io.kalibr import write_kalibr
from omnisim.config import load_scene_config

from camera_examples import EXAMPLES


def _scene(tmp_path, camera_lines: str) -> str:
    path = tmp_path / "scene.toml"
    path.write_text(f"[scene]\nname = \"k\"\n\n[render]\nresolution = [480, 640]\n\n[camera]\n{camera_lines}\n")
    return path


def test_kalibr_file_relative_to_the_scene_and_scaled_by_resolution(tmp_path):
    (tmp_path / "cams").mkdir()
    write_kalibr(tmp_path / "cams" / "camera.yaml", EXAMPLES["omni-radtan"])
    scene = _scene(tmp_path, 'kalibr = "cams/camera.yaml"')
    assert load_scene_config(scene).camera.model == EXAMPLES["omni-radtan"]
    half = load_scene_config(scene, resolution=(240, 320)).camera.model
    assert half == EXAMPLES["omni-radtan"].scaled(0.5)
    assert load_scene_config(scene).settings_dict()["camera"]["kalibr"]["camera_model"] == "omni"


def test_kalibr_with_ocamcalib_keys_is_an_error(tmp_path):
    write_kalibr(tmp_path / "camera.yaml", EXAMPLES["ds"])
    with pytest.raises(InputError, match=r"\[camera\] pol: not used with 'kalibr'"):
        load_scene_config(_scene(tmp_path, 'kalibr = "camera.yaml"\npol = [1.0]'))


def test_missing_kalibr_file_is_named_with_the_scene_file_section_and_key(tmp_path):
    """Before: "camera.yaml: calibration file not found", without the scene that names it."""
    scene = _scene(tmp_path, 'kalibr = "cams/camera.yaml"')
    with pytest.raises(InputError) as error:
        load_scene_config(scene)
    assert str(error.value) == f"{scene}: [camera] kalibr: file not found: {tmp_path / 'cams' / 'camera.yaml'}"


def test_kalibr_errors_name_the_yaml_file(tmp_path):
    (tmp_path / "camera.yaml").write_text("cam0: {camera_model: kb}\n")
    with pytest.raises(InputError, match="camera.yaml: cam0.intrinsics: missing"):
        load_scene_config(_scene(tmp_path, 'kalibr = "camera.yaml"'))


def test_resolution_of_another_aspect_is_refused(tmp_path):
    write_kalibr(tmp_path / "camera.yaml", EXAMPLES["ds"])
    with pytest.raises(InputError, match="resolution: expected the calibration's aspect"):
        load_scene_config(_scene(tmp_path, 'kalibr = "camera.yaml"'), resolution=(300, 300))
