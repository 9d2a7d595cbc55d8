"""Calibrations with extreme or implausible values are refused when read, in one line naming the file.

Each case is one a fuzzing run found: before, these gave tracebacks (``TypeError``,
``OverflowError``, ``ValueError: pixel_angle_rad ... nan``), errors naming no file
(``ifmi.panorama: ...``), a misleading reason, scipy's raw text, or all-black output with
exit status 0.
"""

from __future__ import annotations

import pytest

from ifmi.geometry.calib_fit import fit_camera_model
from ifmi.geometry.camera import paracatadioptric_model
from ifmi.geometry.camera_models import DoubleSphereModel, KannalaBrandtModel, UnifiedModel
from ifmi.cli import main
from ifmi.errors import InputError
from ifmi.io.calib import format_calib, read_calib
from ifmi.io.camera_file import read_camera
from ifmi.io.kalibr import read_kalibr, write_kalibr

from scene_files import camera_128_section, write_scene

# A 64x64 paracatadioptric camera: small enough to convert in well under a second.
OCAM = paracatadioptric_model((64, 64), horizon_radius_px=20.0, center=(31.6, 32.2))
# The double sphere of a 256x256 catadioptric camera (the fuzzing run's base dataset).
DS_INTRINSICS = "[1.0, 0.0, 80.0, 80.1, 129.7, 127.2]"


def _one_line_error(path, read, match: str) -> str:
    with pytest.raises(InputError) as info:
        read(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message, message
    assert match in message, message
    return message


def _calib_with(tmp_path, *, center=None, affine=None, size=None):
    text = format_calib(OCAM)
    lines = text.splitlines()
    data = [i for i, line in enumerate(lines) if line and not line.startswith("#")]
    for index, value in ((2, center), (3, affine), (4, size)):
        if value is not None:
            lines[data[index]] = value
    path = tmp_path / "calib_results.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def _yaml_with(tmp_path, *, camera_model="ds", intrinsics=DS_INTRINSICS, resolution="[256, 256]"):
    path = tmp_path / "camera.yaml"
    path.write_text(f"cam0:\n  camera_model: {camera_model}\n  intrinsics: {intrinsics}\n"
                    f"  distortion_model: none\n  distortion_coeffs: []\n  resolution: {resolution}\n")
    return path


# --- OCamCalib files -----------------------------------------------------------------------

@pytest.mark.parametrize("affine", ["1e10 0 0", "1e-6 0 0", "-1 0 0", "0.01 0 0", "1 0 100", "1 0.8 0"])
def test_an_implausible_affine_part_is_refused(tmp_path, affine):
    _one_line_error(_calib_with(tmp_path, affine=affine), read_calib,
                    "affine (c d e): expected an affine part close to the identity")


def test_a_plausible_affine_part_is_read(tmp_path):
    # Non-square pixels (aspect 1.3) and a small skew are what the affine part is for.
    assert read_calib(_calib_with(tmp_path, affine="1.3 0.02 -0.01")).affine == (1.3, 0.02, -0.01)


@pytest.mark.parametrize("center", ["1000 1000", "-500 -500", "0 32", "31.6 63"])
def test_a_centre_outside_the_image_is_named_as_such(tmp_path, center):
    # Before: "direct polynomial: ... check the signs of the coefficients".
    message = _one_line_error(_calib_with(tmp_path, center=center), read_calib,
                              "center (row col): expected a point inside the 64x64 image")
    assert "direct polynomial" not in message


@pytest.mark.parametrize("size", ["1 1", "100000000 100000000", "64 40000"])
def test_an_image_size_out_of_bounds_is_refused(tmp_path, size):
    _one_line_error(_calib_with(tmp_path, size=size), read_calib,
                    "image size (height width): expected image sides from 8 to 32768 px")


def test_warp_refuses_an_implausible_affine_part(tmp_path, capsys):
    """Before: all-black frames and exit status 0."""
    import cv2
    import numpy as np

    from omnisim.cli import main as omnisim_main

    calib = _calib_with(tmp_path, affine="1e10 0 0")
    image = tmp_path / "photo.png"
    cv2.imwrite(str(image), np.full(OCAM.size, 128, np.uint8))
    assert omnisim_main(["warp", str(image), "--calib", str(calib), "--out", str(tmp_path / "w"),
                         "--frames", "2"]) == 2
    err = capsys.readouterr().err.strip()
    assert str(calib) in err and "affine (c d e)" in err and "\n" not in err
    assert not (tmp_path / "w").exists()


# --- Kalibr files --------------------------------------------------------------------------

@pytest.mark.parametrize("field, value", [("camera_model", "[ds]"), ("camera_model", "{ds: 1}")])
def test_a_camera_model_that_is_no_name_is_refused(tmp_path, field, value):
    _one_line_error(_yaml_with(tmp_path, **{field: value}), read_kalibr, "cam0.camera_model: expected one of")


def test_a_distortion_model_that_is_no_name_is_refused(tmp_path):
    path = _yaml_with(tmp_path)
    path.write_text(path.read_text().replace("distortion_model: none", "distortion_model: [none]"))
    _one_line_error(path, read_kalibr, "cam0.distortion_model: expected one of none")


def test_an_integer_beyond_the_float_range_is_refused(tmp_path):
    message = _one_line_error(_yaml_with(tmp_path, intrinsics="[1, 0, " + "9" * 400 + ", 80, 129.7, 127.2]"),
                              read_kalibr, "cam0.intrinsics: expected finite numbers")
    assert "9" * 40 not in message  # shown by its size, not its 400 digits


def test_an_integer_too_long_for_python_is_refused(tmp_path):
    # Python refuses to parse integers of more than 4300 digits (a ValueError inside PyYAML).
    _one_line_error(_yaml_with(tmp_path, intrinsics="[1, 0, " + "9" * 5000 + ", 80, 129.7, 127.2]"),
                    read_kalibr, "not valid YAML")


@pytest.mark.parametrize("resolution", ["[" + "9" * 400 + ", 256]", "[1, 1]", "[40000, 256]",
                                        "[0x" + "f" * 2000 + ", 8]"])
def test_a_resolution_out_of_bounds_is_refused(tmp_path, resolution):
    message = _one_line_error(_yaml_with(tmp_path, resolution=resolution), read_kalibr,
                              "cam0.resolution: expected [width, height] integers from 8 to 32768")
    assert len(message) < 300


def test_an_equirectangular_camera_of_one_pixel_is_refused(tmp_path):
    # Before: "ifmi estimate: error: ifmi.panorama: the camera model images no full ring ..." (no file).
    _one_line_error(_yaml_with(tmp_path, camera_model="equirectangular", intrinsics="[]", resolution="[1, 1]"),
                    read_kalibr, "cam0.resolution")


@pytest.mark.parametrize("camera_model, intrinsics", [
    ("omni", "[1e6, 79.5, 79.6, 129.7, 127.2]"),
    ("ds", "[1e9, 0.5, 80.0, 80.0, 129.7, 127.2]"),
    ("ds", "[1.0, 0.0, 1.0e-300, 80.0, 129.7, 127.2]"),
    ("ds", "[1.0, 0.0, 1.0e+300, 1.0e+300, 129.7, 127.2]"),
    ("pinhole", "[1.0e-300, 1.0e-300, 129.7, 127.2]"),
    ("omni", "[1e300, 79.5, 79.6, 129.7, 127.2]"),  # before: OverflowError traceback (xi ** 2)
])
def test_parameters_that_image_no_usable_region_are_refused(tmp_path, camera_model, intrinsics):
    # Before: "ValueError: pixel_angle_rad must be finite and > 0, got nan" (a traceback), or
    # "ifmi.panorama: empty band" (no file).
    message = _one_line_error(_yaml_with(tmp_path, camera_model=camera_model, intrinsics=intrinsics),
                              read_kalibr, "cam0.intrinsics: the camera images no usable region")
    assert "nan" not in message  # an angle that cannot be measured is said in words


@pytest.mark.parametrize("intrinsics", ["[1.0, 0.0, 80.0, 80.0, 5000.0, 5000.0]",
                                        "[1.0, 0.0, 80.0, 80.0, 0.0, 127.2]"])
def test_a_principal_point_outside_the_image_is_refused(tmp_path, intrinsics):
    _one_line_error(_yaml_with(tmp_path, intrinsics=intrinsics), read_kalibr,
                    "cam0.intrinsics: principal point (pu, pv)")


def test_usual_kalibr_files_still_read(tmp_path):
    assert read_kalibr(_yaml_with(tmp_path)).size == (256, 256)
    assert read_kalibr(_yaml_with(tmp_path, camera_model="equirectangular", intrinsics="[]",
                                  resolution="[16, 8]")).size == (8, 16)


@pytest.mark.parametrize("command", [["estimate", "{folder}", "--out", "{tmp}/e.txt"],
                                     ["convert-calib", "{folder}", "--to", "ds", "--out", "{tmp}/c.yaml"]])
def test_commands_report_a_list_camera_model_in_one_line(tmp_path, capsys, command):
    folder = tmp_path / "data"
    folder.mkdir()
    _yaml_with(folder, camera_model="[ds]")
    (folder / "images").mkdir()
    argv = [a.format(folder=folder, tmp=tmp_path) for a in command]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(folder / "camera.yaml") in err and "cam0.camera_model" in err


# --- convert-calib -------------------------------------------------------------------------

@pytest.mark.parametrize("target, out", [("ocamcalib", "x.yaml"), ("ocamcalib", "x.YML"), ("ds", "x.txt"),
                                         ("eucm", "calib_results")])
def test_convert_calib_out_suffix_must_match_the_format(tmp_path, capsys, target, out):
    source = tmp_path / "calib_results.txt"
    source.write_text(format_calib(OCAM))
    assert main(["convert-calib", str(source), "--to", target, "--out", str(tmp_path / out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"ifmi convert-calib: error: {tmp_path / out}: --out: ") and "\n" not in err
    assert not (tmp_path / out).exists()


@pytest.mark.parametrize("target, out", [("ocamcalib", "o.txt"), ("omni", "k.yml")])
def test_convert_calib_writes_what_reads_back(tmp_path, target, out):
    source = tmp_path / "calib_results.txt"
    source.write_text(format_calib(OCAM))
    assert main(["convert-calib", str(source), "--to", target, "--out", str(tmp_path / out)]) == 0
    assert read_camera(tmp_path / out).size == OCAM.size


def test_a_source_with_too_small_a_valid_region_is_named_not_scipy():
    # Before: "Method 'lm' doesn't work when the number of residuals is less than ..."
    source = UnifiedModel(1e6, (20.0, 20.0), (31.7, 31.2), (64, 64))
    with pytest.raises(ValueError, match=r"valid region holds 0 of the 60x60 sample pixels, at least 10"):
        fit_camera_model(source, "ds")


def test_a_source_with_a_degenerate_pixel_angle_is_named_not_scipy():
    # Before: "Initial guess is outside of provided bounds" (the start's focal scale was infinite).
    source = DoubleSphereModel(1.0, 0.0, (1e300, 1e300), (31.7, 31.2), (64, 64))
    with pytest.raises(ValueError, match=r"optical axis images at pixel .* 0 rad per pixel"):
        fit_camera_model(source, "ds")


def test_an_ocamcalib_fit_that_would_not_read_back_is_not_written(tmp_path, capsys):
    """A Kannala-Brandt lens with wild coefficients: the fitted polynomial has no usable inverse.

    Before: the file was written (exit 0) and reading it failed.
    """
    source = tmp_path / "camera.yaml"
    write_kalibr(source, KannalaBrandtModel((20.0, 20.0), (31.7, 31.2), (64, 64), (100.0, -100.0, 100.0, -100.0)))
    out = tmp_path / "calib_results.txt"
    assert main(["convert-calib", str(source), "--to", "ocamcalib", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"ifmi convert-calib: error: {source}: this camera cannot be converted to ocamcalib")
    assert "inverse polynomial" in err and "\n" not in err
    assert not out.exists()


# --- scene files ---------------------------------------------------------------------------

SCENE = """
[render]
resolution = [64, 64]
spp = 1

""" + camera_128_section() + """
[trajectory]
frames = 1
"""


@pytest.mark.parametrize("old, new, message", [
    ("center = [64.35, 63.3]", "center = [642.6, 633.0]", "[camera] center: expected a point inside the 128x128"),
    ("affine = [1.0012, 0.0021, -0.0017]", "affine = [1e10, 0.0, 0.0]", "[camera] affine: expected an affine part"),
    ("size = [128, 128]", "size = [4, 4]", "[camera] size: expected image sides from 8"),
    ("radius_min = 10.0\nradius_max = 61.5", "radius_min = 150.0\nradius_max = 200.0",
     "[camera] radius_min: expected under"),
])
def test_a_scene_camera_that_images_nothing_is_refused_when_read(tmp_path, old, new, message):
    """Before: ``omnisim render`` wrote all-black frames with exit status 0."""
    pytest.importorskip("skimage")  # omnisim's scene generators, as in test_omnisim_config.py
    from omnisim.config import load_scene_config

    assert old in SCENE
    path = write_scene(tmp_path, SCENE.replace(old, new))
    _one_line_error(path, load_scene_config, message)
