"""Kalibr camchain YAML: exact round trips, real-file layout, one error per malformed input; dataset calibration choice."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.errors import InputError, InputWarning
from ifmi.io.camera_file import calibration_path, read_camera, write_camera
from ifmi.io.kalibr import format_kalibr, parse_kalibr, read_kalibr, write_kalibr

from camera_examples import EXAMPLES

KALIBR_NAMES = sorted(set(EXAMPLES) - {"ocamcalib"})

# The layout Kalibr writes (camchain of a double-sphere calibration), with its extra keys.
CAMCHAIN = """\
cam0:
  T_cam_imu:
  - [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975]
  - [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768]
  - [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: ds
  distortion_coeffs: []
  distortion_model: none
  intrinsics: [-0.2, 0.59, 313.0, 314.0, 376.0, 240.0]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
  timeshift_cam_imu: 0.0
cam1:
  camera_model: ds
  intrinsics: [-0.2, 0.59, 313.0, 314.0, 376.0, 240.0]
"""


def _cam0(**overrides) -> str:
    fields = {"camera_model": "omni", "intrinsics": "[0.9, 260.0, 258.0, 319.5, 239.8]",
              "distortion_model": "radtan", "distortion_coeffs": "[-0.28, 0.07, 0.0002, -0.0001]",
              "resolution": "[640, 480]"}
    fields.update(overrides)
    return "cam0:\n" + "".join(f"  {k}: {v}\n" for k, v in fields.items() if v is not None)


@pytest.mark.parametrize("name", KALIBR_NAMES)
def test_write_read_round_trip_is_exact(tmp_path, name):
    model = EXAMPLES[name]
    write_kalibr(tmp_path / "camera.yaml", model)
    back = read_kalibr(tmp_path / "camera.yaml")
    assert type(back) is type(model)
    assert back == model
    assert format_kalibr(back) == (tmp_path / "camera.yaml").read_text()


def test_reads_a_kalibr_camchain_with_extra_keys():
    with pytest.warns(InputWarning) as record:
        model = parse_kalibr(CAMCHAIN, source="stereo.yaml")
    assert model == EXAMPLES["ds"]
    assert model.size == (480, 752)
    assert [str(r.message) for r in record] == [
        "stereo.yaml: a camchain of 2 cameras; the images are taken to be cam0's (cam1 ignored)"]


def test_one_camera_camchain_reads_without_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert parse_kalibr(_cam0()) == EXAMPLES["omni-radtan"]


def test_example_file_reads_as_written():
    model = parse_kalibr(_cam0())
    assert model == EXAMPLES["omni-radtan"]


def test_numbers_without_a_dot_are_read():
    # YAML 1.1 reads 1e-4 (no dot) as a string; such files come from other writers.
    model = parse_kalibr(_cam0(distortion_coeffs="[-0.28, 0.07, 2e-4, -1e-4]"))
    assert model.distortion == (-0.28, 0.07, 2e-4, -1e-4)
    tiny = EXAMPLES["omni-radtan"].__class__(0.9, (260.0, 258.0), (319.5, 239.8), (480, 640),
                                             (1e-05, 0.0, 3e-17, 0.0))
    assert parse_kalibr(format_kalibr(tiny)) == tiny


@pytest.mark.parametrize("text, message", [
    ("camera_model: omni\n", "'cam0'"),
    (_cam0(camera_model="fisheye"), "cam0.camera_model: expected one of"),
    (_cam0(intrinsics="[0.9, 260.0, 258.0, 319.5]"), "cam0.intrinsics: expected 5 values, got 4"),
    (_cam0(intrinsics="[0.9, .nan, 258.0, 319.5, 239.8]"), "expected finite numbers"),
    (_cam0(distortion_coeffs="[-0.28, .inf, 0.0, 0.0]"), "expected finite numbers"),
    (_cam0(resolution="[640]"), "cam0.resolution: expected [width, height]"),
    (_cam0(resolution="[640, -480]"), "cam0.resolution"),
    (_cam0(resolution="[640.5, 480]"), "cam0.resolution"),
    (_cam0(distortion_model="fov"), "cam0.distortion_model: expected one of radtan, none"),
    (_cam0(camera_model="ds", intrinsics="[0.1, 0.5, 300, 300, 320, 240]"),
     "cam0.distortion_model: expected one of none for camera_model ds"),
    (_cam0(distortion_coeffs="[-0.28, 0.07]"), "cam0.distortion_coeffs: expected 4 values, got 2"),
    (_cam0(intrinsics="[0.9, 260.0, x, 319.5, 239.8]"), "cam0.intrinsics: expected a list of numbers"),
    (_cam0(intrinsics="[-0.9, 260.0, 258.0, 319.5, 239.8]"), "xi must be >= 0"),
    (_cam0(resolution=None), "cam0.resolution: missing"),
    ("cam0: [1, 2\n", "not valid YAML at line"),
    ("cam0:\n  camera_model: omni\n intrinsics: [1]\n", "not valid YAML"),
    # Both were tracebacks: a TypeError of the duplicate-key check, PyYAML's RecursionError.
    ("cam0:\n  ? [1, 2]\n  : x\n", "not valid YAML at line 2, column 5: found unhashable key"),
    ("cam0: " + "[" * 50_000 + "]" * 50_000 + "\n", "not valid YAML: nested too deeply"),
])
@pytest.mark.slow
def test_malformed_yaml_gives_one_line_error(tmp_path, text, message):
    path = tmp_path / "camera.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_kalibr(path)
    assert message in str(info.value)
    assert str(info.value).startswith(str(path))
    assert "\n" not in str(info.value)


def test_missing_and_undecodable_files(tmp_path):
    with pytest.raises(InputError, match="calibration file not found"):
        read_kalibr(tmp_path / "camera.yaml")
    (tmp_path / "camera.yaml").write_bytes(b"\xff\xfe\x00bad")
    with pytest.raises(InputError, match="cannot read"):
        read_kalibr(tmp_path / "camera.yaml")


def test_dataset_folder_holds_one_calibration_of_either_format(tmp_path):
    ocam = paracatadioptric_model((64, 64), horizon_radius_px=20.0)
    a, b = tmp_path / "a", tmp_path / "b"
    assert write_camera(a, ocam).name == "calib_results.txt"
    assert write_camera(b, EXAMPLES["kb"]).name == "camera.yaml"
    assert read_camera(calibration_path(a)) == ocam
    assert read_camera(calibration_path(b)) == EXAMPLES["kb"]
    write_camera(a, EXAMPLES["kb"])
    with pytest.raises(InputError, match="holds both calib_results.txt and camera.yaml"):
        calibration_path(a)
    with pytest.raises(InputError, match="calibration file not found"):
        calibration_path(tmp_path / "c")


def test_a_calibration_link_to_a_missing_file_is_refused_not_passed_over(tmp_path):
    # Beside a valid camera.yaml, a dangling calib_results.txt link was skipped without a word and
    # the yaml used; alone, it read as "not found". Either way the calibration meant is unknown.
    b = tmp_path / "b"
    write_camera(b, EXAMPLES["kb"])
    (b / "calib_results.txt").symlink_to(tmp_path / "moved" / "calib_results.txt")
    with pytest.raises(InputError, match=r"calib_results.txt: is a link to a missing file \(.*moved"):
        calibration_path(b)
    (b / "camera.yaml").unlink()
    with pytest.raises(InputError, match="is a link to a missing file"):
        calibration_path(b)


def test_read_dataset_uses_camera_yaml(tmp_path):
    import cv2

    from ifmi.io.dataset import read_dataset

    model = EXAMPLES["ds"].scaled(0.25)
    write_camera(tmp_path, model)
    (tmp_path / "images").mkdir()
    cv2.imwrite(str(tmp_path / "images" / "000000.png"), np.zeros(model.size, np.uint8))
    dataset = read_dataset(tmp_path)
    assert dataset.model == model
    assert dataset.calib_path.name == "camera.yaml"


def test_estimate_command_refuses_a_dataset_with_both_calibrations(tmp_path, capsys):
    import cv2

    from ifmi.cli import main

    model = EXAMPLES["kb"].scaled(0.25)
    write_camera(tmp_path, model)
    write_camera(tmp_path, paracatadioptric_model(model.size, horizon_radius_px=40.0))
    (tmp_path / "images").mkdir()
    cv2.imwrite(str(tmp_path / "images" / "000000.png"), np.zeros(model.size, np.uint8))
    assert main(["estimate", str(tmp_path), "--out", str(tmp_path / "est.txt")]) == 2
    err = capsys.readouterr().err.strip()
    assert "holds both calib_results.txt and camera.yaml" in err and "\n" not in err
