"""omnisim warp: one omni image turned into a pure-rotation sequence with exact ground truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model, pixels_from_rays, radius_from_pixels, rays_from_pixels
from ifmi.errors import InputError
from ifmi.io.calib import write_calib
from ifmi.io.dataset import read_dataset
from ifmi.io.tum import read_tum
from ifmi.geometry.rotations import geodesic_angle
from ifmi.synthetic import environment_texture, omni_from_environment

SIZE = 128
MODEL = paracatadioptric_model((SIZE, SIZE), horizon_radius_px=40.0)
BAND = (12.0, 60.0)


@pytest.fixture(scope="module")
def source_files(tmp_path_factory):
    root = tmp_path_factory.mktemp("warp_source")
    image = omni_from_environment(environment_texture(height=256, seed=3), MODEL, np.eye(3), band_px=BAND)
    rgb = np.repeat(image[..., None], 3, axis=2)
    cv2.imwrite(str(root / "photo.png"), rgb)
    write_calib(root / "calib_results.txt", MODEL)
    return root / "photo.png", root / "calib_results.txt"


def _warp_error(image0, imagek, rotation_0k):
    """Mean gray difference after moving frame k onto frame 0 with ``rotation_0k`` (bilinear, OpenCV)."""
    rows, cols = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    grid = np.stack([rows, cols], axis=-1)
    pix = pixels_from_rays(MODEL, rays_from_pixels(MODEL, grid) @ rotation_0k)
    back = cv2.remap(imagek.astype(np.float32), pix[..., 1].astype(np.float32), pix[..., 0].astype(np.float32),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    r0, rk = radius_from_pixels(MODEL, grid), radius_from_pixels(MODEL, pix)
    valid = (r0 > BAND[0] + 4) & (r0 < BAND[1] - 4) & (rk > BAND[0] + 4) & (rk < BAND[1] - 4)
    valid &= back > 0
    return float(np.abs(back - image0.astype(np.float32))[valid].mean()), float(valid.mean())


def test_warped_sequence_ground_truth_agrees_with_pixels(tmp_path, source_files):
    from omnisim.warp import WarpSettings, warp_dataset

    out = tmp_path / "warped"
    settings = WarpSettings(frames=4, seed=5, max_step_deg=6.0, max_tilt_deg=4.0)
    result = warp_dataset(*source_files, out, settings=settings, progress=False)
    assert result.frames == 4 and result.written == 4
    data = read_dataset(out)
    gt = read_tum(out / "groundtruth.txt")
    assert len(data.image_paths) == 4 and len(gt) == 4
    assert geodesic_angle(np.eye(3), gt.rotations[0]) < 1e-12
    steps = [geodesic_angle(gt.rotations[k - 1], gt.rotations[k]) for k in range(1, 4)]
    assert max(steps) <= np.radians(6.0) + 1e-12
    gray = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in data.image_paths]
    k = 3
    true_err, share = _warp_error(gray[0], gray[k], gt.rotations[k])
    identity_err, _ = _warp_error(gray[0], gray[k], np.eye(3))
    transposed_err, _ = _warp_error(gray[0], gray[k], gt.rotations[k].T)
    # Measured: 4.8 grey levels (mean) with the truth (bilinear re-warp of a texture sharp at
    # the pixel scale) against 33 and 37 with the identity and the transposed rotation.
    assert share > 0.3
    assert true_err * 4 < identity_err and true_err * 4 < transposed_err, (true_err, identity_err,
                                                                             transposed_err)


def test_round_trip_error_is_the_interpolation_error(source_files):
    from omnisim.warp import round_trip_error, rotation_walk, valid_source_band, warp_image, WarpSettings

    source = cv2.imread(str(source_files[0]), cv2.IMREAD_GRAYSCALE)
    band = valid_source_band(MODEL, source)
    assert BAND[0] - 2 <= band[0] <= BAND[0] + 4 and BAND[1] - 4 <= band[1] <= BAND[1] + 1
    rotation = rotation_walk(WarpSettings(frames=3, seed=1, max_step_deg=8.0))[2]
    frame = warp_image(source, MODEL, rotation, band=band)
    rms, share = round_trip_error(source, frame, MODEL, rotation, band=band)
    wrong, _ = round_trip_error(source, frame, MODEL, rotation.T, band=band)
    # Two cubic B-spline interpolations of a texture sharp at the pixel scale; measured 5.0
    # grey levels (rms) against 50 for a wrong rotation.
    assert share > 0.4 and rms < 7.0 and wrong > 4 * rms
    # Frame 0 is the source, unchanged inside the band.
    same = warp_image(source, MODEL, np.eye(3), band=band)
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    radius = radius_from_pixels(MODEL, np.stack([rows, cols], axis=-1).astype(float))
    inside = (radius > band[0] + 1) & (radius < band[1] - 1)
    assert np.array_equal(same[inside], source[inside])


def test_rotation_walk_is_seeded_and_bounded():
    from omnisim.warp import WarpSettings, rotation_walk

    settings = WarpSettings(frames=50, seed=2, max_step_deg=10.0, max_tilt_deg=5.0)
    a, b = rotation_walk(settings), rotation_walk(settings)
    assert np.array_equal(a, b)
    steps = geodesic_angle(a[:-1], a[1:])
    assert np.max(steps) <= np.radians(10.0) and np.max(steps) > np.radians(3.0)
    from scipy.spatial.transform import Rotation

    _, pitch, roll = np.degrees(Rotation.from_matrix(a).as_euler("ZYX")).T
    assert np.max(np.abs(pitch)) <= 5.0 + 1e-9 and np.max(np.abs(roll)) <= 5.0 + 1e-9


def test_rerun_resumes_and_other_settings_are_refused(tmp_path, source_files):
    from omnisim.warp import WarpSettings, warp_dataset

    out = tmp_path / "w"
    settings = WarpSettings(frames=2, seed=0, max_step_deg=3.0)
    warp_dataset(*source_files, out, settings=settings, progress=False)
    (out / "images" / "000001.png").unlink()
    assert warp_dataset(*source_files, out, settings=settings, progress=False).written == 1
    with pytest.raises(InputError, match="different settings"):
        warp_dataset(*source_files, out, settings=WarpSettings(frames=2, seed=1), progress=False)


def test_cli_errors_name_the_file(tmp_path, source_files, capsys):
    from omnisim.cli import main

    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((10, 10), np.uint8))
    code = main(["warp", str(small), "--calib", str(source_files[1]), "--out", str(tmp_path / "o"),
                 "--frames", "2", "--no-progress"])
    assert code == 2 and "small.png" in capsys.readouterr().err
    code = main(["warp", str(source_files[0]), "--calib", str(source_files[1]), "--out", str(tmp_path / "o"),
                 "--frames", "0", "--no-progress"])
    assert code == 2 and "frames" in capsys.readouterr().err
    code = main(["warp", str(source_files[0]), "--calib", str(source_files[1]), "--out", str(tmp_path / "o"),
                 "--frames", "100000000", "--no-progress"])
    assert code == 2 and "error: --frames: expected 1 <= frames <= 1000000" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    code = main(["warp", str(source_files[0]), "--calib", str(tmp_path / "missing.txt"),
                 "--out", str(tmp_path / "o"), "--frames", "2", "--no-progress"])
    assert code == 2 and "missing.txt" in capsys.readouterr().err


# --- Other camera models (Kalibr camera.yaml) ----------------------------------------------------

LENS_CIRCLE_DEG = 80.0  # the synthetic lens images rays up to this angle from the axis; black beyond


def _lens_image(model, environment, rotation):
    """The environment seen by ``model`` turned by ``rotation``; black outside the lens circle."""
    from ifmi.geometry.camera import angles_from_axis

    h, w = model.size
    grid = np.stack(np.mgrid[0:h, 0:w], axis=-1).astype(np.float64)
    image = omni_from_environment(environment, model, rotation)
    angle = angles_from_axis(rays_from_pixels(model, grid), getattr(model, "panorama_axis", model.optical_axis))
    image[~model.valid_pixels(grid) | ~(np.nan_to_num(angle, nan=np.pi) <= np.radians(LENS_CIRCLE_DEG))] = 0
    return image


@pytest.mark.slow
@pytest.mark.parametrize("name", ["kb", "ds", "equirectangular"])
def test_kalibr_camera_warp_agrees_with_a_direct_render(tmp_path, name):
    """Frame k of a camera.yaml warp equals the scene rendered directly at the ground-truth orientation."""
    from camera_examples import EXAMPLES

    from ifmi.io.kalibr import write_kalibr
    from omnisim.warp import WarpSettings, warp_dataset

    model = EXAMPLES[name]
    model = model.scaled(0.5) if model.height > 300 else model
    environment = environment_texture(height=256, seed=3)
    cv2.imwrite(str(tmp_path / "photo.png"), _lens_image(model, environment, np.eye(3)))
    write_kalibr(tmp_path / "camera.yaml", model)
    out = tmp_path / "warped"
    warp_dataset(tmp_path / "photo.png", tmp_path / "camera.yaml", out, progress=False,
                 settings=WarpSettings(frames=4, seed=5, max_step_deg=6.0, max_tilt_deg=4.0))
    data = read_dataset(out)
    assert (out / "camera.yaml").is_file() and not (out / "calib_results.txt").exists()
    assert type(data.model) is type(model)
    gt = read_tum(out / "groundtruth.txt")
    frame = cv2.imread(str(data.image_paths[3]), cv2.IMREAD_GRAYSCALE).astype(np.float64)
    errors = {}
    for label, rotation in (("truth", gt.rotations[3]), ("transposed", gt.rotations[3].T), ("identity", np.eye(3))):
        direct = _lens_image(model, environment, rotation).astype(np.float64)
        both = (frame > 0) & (direct > 0)
        errors[label] = float(np.abs(frame - direct)[both].mean())
        if label == "truth":
            share = both.mean()
    # Measured (mean grey levels, truth / transposed / identity): kb 1.7 / 26 / 24,
    # ds 1.1 / 27 / 24, equirectangular 4.1 / 31 / 26 (a texture sharp at the pixel scale,
    # cubic B-spline against the direct bilinear render).
    assert share > 0.3 and errors["truth"] < 5.0, (share, errors)
    assert errors["truth"] * 4 < min(errors["transposed"], errors["identity"]), errors


@pytest.mark.parametrize("name", ["kb", "equirectangular"])
def test_kalibr_camera_walk_turns_about_the_panorama_axis(name):
    """Without tilt, every orientation keeps the camera's panorama axis (yaw is the heading)."""
    from camera_examples import EXAMPLES

    from omnisim.warp import WarpSettings, rotation_walk, rotations_in_camera_frame

    model = EXAMPLES[name]
    axis = getattr(model, "panorama_axis", model.optical_axis)
    rotations = rotations_in_camera_frame(model, rotation_walk(WarpSettings(frames=6, seed=1, max_tilt_deg=0.0)))
    assert np.allclose(rotations @ axis, axis, atol=1e-12)
    assert geodesic_angle(rotations[0], rotations[-1]) > np.radians(3.0)


def test_lit_band_of_a_fisheye_ends_at_its_lens_circle():
    """The black surround beyond the lens circle, inside the model's valid region, is not source."""
    from camera_examples import EXAMPLES

    from omnisim.warp import valid_source_band

    model = EXAMPLES["kb"].scaled(0.5)
    image = _lens_image(model, environment_texture(height=256, seed=3), np.eye(3))
    inner, outer = valid_source_band(model, image)
    # Rings probed every 0.25 degrees; the kernel margin is 2 px (about 0.75 degrees here).
    assert inner == 0.0 and LENS_CIRCLE_DEG - 1.5 <= np.degrees(outer) <= LENS_CIRCLE_DEG, np.degrees(outer)


def test_black_image_through_a_kalibr_camera_is_a_one_line_error(tmp_path, capsys):
    from camera_examples import EXAMPLES

    from ifmi.io.kalibr import write_kalibr
    from omnisim.cli import main

    model = EXAMPLES["kb"].scaled(0.25)
    cv2.imwrite(str(tmp_path / "black.png"), np.zeros(model.size, np.uint8))
    write_kalibr(tmp_path / "camera.yaml", model)
    code = main(["warp", str(tmp_path / "black.png"), "--calib", str(tmp_path / "camera.yaml"),
                 "--out", str(tmp_path / "o"), "--frames", "2", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "black.png" in err[0] and "no lit ring" in err[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("level, shown", [(0, "0 (black)"), (128, "colour (128, 128, 128)")])
def test_image_without_texture_is_a_one_line_error(tmp_path, source_files, capsys, level, shown):
    """A black (or flat) photo through an OCamCalib calibration gave black (or flat) frames, exit 0."""
    from omnisim.cli import main

    cv2.imwrite(str(tmp_path / "flat.png"), np.full((SIZE, SIZE, 3), level, np.uint8))
    code = main(["warp", str(tmp_path / "flat.png"), "--calib", str(source_files[1]),
                 "--out", str(tmp_path / "o"), "--frames", "2", "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err
    assert err.startswith(f"omnisim warp: error: {tmp_path / 'flat.png'}: no texture: every pixel of its mirror "
                          f"band (radius ") and f"px) is {shown}, so every rotation gives the same frame" in err
    assert not (tmp_path / "o").exists()


def test_flat_image_through_a_kalibr_camera_is_a_one_line_error(tmp_path, capsys):
    from camera_examples import EXAMPLES

    from ifmi.io.kalibr import write_kalibr
    from omnisim.cli import main

    model = EXAMPLES["kb"].scaled(0.25)
    cv2.imwrite(str(tmp_path / "flat.png"), np.full(model.size, 90, np.uint8))
    write_kalibr(tmp_path / "camera.yaml", model)
    code = main(["warp", str(tmp_path / "flat.png"), "--calib", str(tmp_path / "camera.yaml"),
                 "--out", str(tmp_path / "o"), "--frames", "2", "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "flat.png: no texture" in err and "is gray level 90" in err
    assert "degrees from the panorama axis" in err and not (tmp_path / "o").exists()


def test_dark_textured_image_is_warped(tmp_path, source_files):
    """Texture of a few gray levels in a dark photo is still texture: the frames move with it."""
    from omnisim.warp import WarpSettings, warp_dataset

    dark = cv2.imread(str(source_files[0]), cv2.IMREAD_GRAYSCALE) // 64  # levels 0..3
    assert dark.max() <= 3 and dark.std() > 0
    cv2.imwrite(str(tmp_path / "dark.png"), dark)
    result = warp_dataset(tmp_path / "dark.png", source_files[1], tmp_path / "o", progress=False,
                          settings=WarpSettings(frames=2, max_step_deg=5.0))
    assert result.written == 2
    frames = [cv2.imread(str(tmp_path / "o" / "images" / f"{k:06d}.png"), cv2.IMREAD_UNCHANGED) for k in range(2)]
    assert frames[1].max() > 0 and not np.array_equal(frames[0], frames[1])


# --- rolling shutter ------------------------------------------------------------------

def test_walk_read_between_frames_is_continuous():
    from omnisim.warp import WarpSettings, rotation_walk

    settings = WarpSettings(frames=6, seed=3, max_step_deg=9.0, max_tilt_deg=4.0)
    frames = rotation_walk(settings)
    np.testing.assert_array_equal(rotation_walk(settings, np.arange(6.0)), frames)
    fine = rotation_walk(settings, np.linspace(0.0, 5.0, 501))
    np.testing.assert_allclose(fine[::100], frames, atol=1e-15)
    # 1/100 of a frame turns at most 1/100 of the largest step (and then some rounding).
    assert np.max(geodesic_angle(fine[:-1], fine[1:])) <= np.radians(9.0) / 100 + 1e-12


def test_rolling_shutter_rows_are_warped_through_their_own_time(source_files):
    from omnisim.warp import WarpSettings, rotation_walk, valid_source_band, warp_image

    from ifmi.backend.rolling_shutter import row_time_offsets

    source = cv2.imread(str(source_files[0]), cv2.IMREAD_GRAYSCALE)
    band = valid_source_band(MODEL, source)
    settings = WarpSettings(frames=3, seed=1, max_step_deg=10.0, rolling_shutter=0.6)
    times = 2 + row_time_offsets(np.arange(SIZE), height=SIZE, readout=0.6)
    rows = rotation_walk(settings, times)
    frame = warp_image(source, MODEL, rows, band=band)
    for r in (0, 40, 64, 127):
        assert np.array_equal(frame[r], warp_image(source, MODEL, rows[r], band=band)[r])
    with pytest.raises(ValueError, match=r"one per row, \(128, 3, 3\), got \(5, 3, 3\)"):
        warp_image(source, MODEL, rows[:5], band=band)


def test_rolling_shutter_warp_writes_every_rows_pose(tmp_path, source_files):
    import json

    from omnisim.warp import WarpSettings, rotation_walk, warp_dataset

    from ifmi.backend.rolling_shutter import row_time_offsets

    settings = WarpSettings(frames=3, seed=2, max_step_deg=8.0, rolling_shutter=0.4)
    out = tmp_path / "rs"
    warp_dataset(*source_files, out, settings=settings, progress=False)
    gt = read_tum(out / "groundtruth.txt")
    np.testing.assert_allclose(gt.rotations, rotation_walk(settings), atol=1e-9)  # the middle row's pose
    meta = json.loads((out / "meta.json").read_text())
    assert meta["settings"]["rolling_shutter"] == 0.4 and sorted(meta["rolling_shutter"]) == [
        "000000.txt", "000001.txt", "000002.txt"]
    rows = read_tum(out / "rolling_shutter" / "000002.txt")
    times = 2 + row_time_offsets(np.arange(SIZE), height=SIZE, readout=0.4)
    np.testing.assert_allclose(rows.timestamps, times, atol=1e-6)
    np.testing.assert_allclose(rows.rotations, rotation_walk(settings, times), atol=1e-9)
    assert "round_trip_last_frame" not in meta


def test_rolling_shutter_rows_are_made_one_frame_at_a_time(tmp_path, source_files, monkeypatch):
    """--frames 1000000 --rolling-shutter 0.5 built every row's matrix of every frame at once (35 GB
    for 480 rows) and died of a MemoryError traceback after writing part of the folder. The walk is
    now read for one frame's rows at a time."""
    import omnisim.warp as warp

    sizes = []
    walk = warp.rotation_walk
    monkeypatch.setattr(warp, "rotation_walk", lambda settings, times=None: sizes.append(
        settings.frames if times is None else len(times)) or walk(settings, times))
    settings = warp.WarpSettings(frames=4, seed=2, rolling_shutter=0.5)
    warp.warp_dataset(*source_files, tmp_path / "rs", settings=settings, progress=False)
    assert max(size for size in sizes) == max(SIZE, settings.frames)


def test_global_shutter_warp_keeps_its_folder_identity(tmp_path, source_files):
    """A folder written before the option existed resumes: a global shutter is not part of its settings."""
    import json

    from omnisim.warp import WarpSettings, warp_dataset

    out = tmp_path / "gs"
    warp_dataset(*source_files, out, settings=WarpSettings(frames=2), progress=False)
    meta = json.loads((out / "meta.json").read_text())
    assert "rolling_shutter" not in meta["settings"] and not (out / "rolling_shutter").exists()


@pytest.mark.parametrize("value", ["-0.1", "1.5", "nan"])
def test_rolling_shutter_out_of_range_is_a_one_line_error(tmp_path, source_files, capsys, value):
    from omnisim.cli import main

    code = main(["warp", str(source_files[0]), "--calib", str(source_files[1]), "--out", str(tmp_path / "w"),
                 "--frames", "2", "--rolling-shutter", value, "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    assert err == (f"omnisim warp: error: --rolling-shutter: expected 0 <= rolling_shutter <= 1 (a fraction "
                   f"of the frame interval), got {float(value)}")


def test_image_too_small_for_a_round_trip_is_a_one_line_error(tmp_path, capsys):
    # 8x8 px: no pixel lies 6 px inside the edges, so the round trip compared nothing
    # (NaN in meta.json, numpy warnings on stderr) after writing the whole dataset.
    from omnisim.cli import main

    image = cv2.GaussianBlur((np.random.default_rng(0).random((8, 8)) * 255).astype(np.uint8), (0, 0), 1)
    cv2.imwrite(str(tmp_path / "tiny.png"), image)
    (tmp_path / "camera.yaml").write_text(
        "cam0:\n  camera_model: pinhole\n  intrinsics: [4.0, 4.0, 3.5, 3.5]\n"
        "  distortion_model: none\n  distortion_coeffs: []\n  resolution: [8, 8]\n")
    code = main(["warp", str(tmp_path / "tiny.png"), "--calib", str(tmp_path / "camera.yaml"),
                 "--out", str(tmp_path / "o"), "--frames", "3", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"omnisim warp: error: {tmp_path / 'tiny.png'}: image of 8x8 px too small to "
                                 "warp: no pixel of its valid band lies 6 px inside the band and the image "
                                 "edges (expected a larger image)"]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("option, value, expected", [
    ("--max-step-deg", "0", "expected 0 < max_step_deg <= 90, got 0.0"),
    ("--max-tilt-deg", "100", "expected 0 <= max_tilt_deg <= 45, got 100.0"),
    ("--seed", "-1", "expected seed >= 0, got -1"),
])
def test_warp_option_out_of_range_is_named_by_its_option(tmp_path, source_files, capsys, option, value, expected):
    """The message named the image, and both motion bounds at once, whichever was wrong."""
    from omnisim.cli import main

    code = main(["warp", str(source_files[0]), "--calib", str(source_files[1]), "--out", str(tmp_path / "w"),
                 "--frames", "2", option, value, "--no-progress"])
    assert code == 2 and capsys.readouterr().err.strip() == f"omnisim warp: error: {option}: {expected}"
    assert not (tmp_path / "w").exists()


@pytest.mark.skipif(not hasattr(__import__("os"), "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("which, what", [("image", "an image file"), ("calib", "a calibration file")])
def test_warp_input_that_is_a_fifo_is_one_line(tmp_path, source_files, capsys, which, what):
    """A FIFO given as the image or the calibration made warp wait forever reading it."""
    import os

    from omnisim.cli import main

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    image, calib = (fifo, source_files[1]) if which == "image" else (source_files[0], fifo)
    code = main(["warp", str(image), "--calib", str(calib), "--out", str(tmp_path / "w"), "--frames", "2",
                 "--no-progress"])
    assert code == 2
    assert capsys.readouterr().err.strip() == (f"omnisim warp: error: {fifo}: is a FIFO, device or socket, not "
                                               f"{what}; expected a regular file")
    assert not (tmp_path / "w").exists()
