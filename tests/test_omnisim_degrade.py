"""Capture effects applied to an existing dataset: statistics, determinism, resume, errors."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from ifmi.errors import InputError
from ifmi.io.dataset import read_dataset
from omnisim.cli import main as omnisim_main
from omnisim.config import EffectsSettings
from omnisim.degrade import degrade_dataset, degrade_image
from omnisim.effects import linear_from_srgb_uint8, srgb_uint8_from_linear
from omnisim.settings import SettingError

pytest.importorskip("skimage")
from ifmi.synthetic import (example_band_px, example_omni_model, synthetic_sequence,  # noqa: E402
                            write_synthetic_dataset)


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    model = example_omni_model(96)
    sequence = synthetic_sequence(model, 4, seed=0, band_px=example_band_px(model))
    return write_synthetic_dataset(tmp_path_factory.mktemp("src"), sequence)


def _images(folder):
    return [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((folder / "images").glob("*.png"))]


def test_srgb_round_trip_is_exact_for_every_level():
    levels = np.arange(256, dtype=np.uint8)
    assert np.array_equal(srgb_uint8_from_linear(linear_from_srgb_uint8(levels)), levels)


def test_noise_has_the_requested_sigma_and_is_seeded():
    flat = np.full((200, 200), 128, dtype=np.uint8)
    effects = EffectsSettings(noise_sigma=5.0)
    out = degrade_image(flat, effects, gain=1.0, seed=3, frame=7)
    assert out.shape == flat.shape and out.dtype == np.uint8
    # Rounding to whole levels adds 1/12 to the variance.
    assert abs(np.std(out.astype(float) - 128) - np.sqrt(25 + 1 / 12)) < 0.1
    assert np.array_equal(out, degrade_image(flat, effects, gain=1.0, seed=3, frame=7))
    assert not np.array_equal(out, degrade_image(flat, effects, gain=1.0, seed=3, frame=8))


def test_exposure_gain_acts_on_linear_intensity():
    level = np.full((4, 4), 100, dtype=np.uint8)
    out = degrade_image(level, EffectsSettings(), gain=2.0, seed=0, frame=0)
    expected = srgb_uint8_from_linear(2.0 * linear_from_srgb_uint8(level))
    assert np.array_equal(out, expected) and out[0, 0] > 130


def test_degraded_copy_keeps_calibration_and_truth_and_is_reproducible(source, tmp_path):
    effects = EffectsSettings(noise_sigma=3.0, jpeg_quality=70, exposure_stops=0.3)
    first = degrade_dataset(source, tmp_path / "a", effects=effects, seed=5, progress=False)
    assert (first.frames, first.written) == (4, 4)
    again = degrade_dataset(source, tmp_path / "a", effects=effects, seed=5, progress=False)
    assert again.written == 0
    degrade_dataset(source, tmp_path / "b", effects=effects, seed=5, progress=False)
    for name in ("calib_results.txt", "groundtruth.txt"):
        assert (tmp_path / "a" / name).read_bytes() == (source / name).read_bytes()
    a, b, clean = _images(tmp_path / "a"), _images(tmp_path / "b"), _images(source)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    difference = np.std(a[2].astype(float) - clean[2].astype(float))
    assert 2.0 < difference < 30.0
    assert len(read_dataset(tmp_path / "a").image_paths) == 4
    meta = json.loads((tmp_path / "a" / "meta.json").read_text())
    assert meta["complete"] and meta["effects"]["jpeg_quality"] == 70


def test_a_damaged_image_is_rewritten_on_resume(source, tmp_path):
    effects = EffectsSettings(noise_sigma=2.0)
    degrade_dataset(source, tmp_path / "d", effects=effects, progress=False)
    victim = tmp_path / "d" / "images" / "000001.png"
    good = victim.read_bytes()
    victim.write_bytes(good[:100])
    assert degrade_dataset(source, tmp_path / "d", effects=effects, progress=False).written == 1
    assert victim.read_bytes() == good


def test_other_settings_into_the_same_folder_are_refused(source, tmp_path):
    degrade_dataset(source, tmp_path / "o", effects=EffectsSettings(noise_sigma=2.0), progress=False)
    with pytest.raises(InputError, match="different effects"):
        degrade_dataset(source, tmp_path / "o", effects=EffectsSettings(noise_sigma=3.0), progress=False)


def test_output_equal_to_source_is_refused(source):
    with pytest.raises(InputError, match="is the source dataset"):
        degrade_dataset(source, source, effects=EffectsSettings(), progress=False)


def test_cli_reports_bad_settings_in_one_line(source, tmp_path, capsys):
    assert omnisim_main(["degrade", str(source), "--out", str(tmp_path / "q"), "--jpeg-quality", "101"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "jpeg_quality" in err and "got 101" in err


@pytest.mark.parametrize("option, value, expected", [
    ("--noise-sigma", "1e30", "noise_sigma: expected <= 255.0, got 1e+30"),
    ("--exposure-stops", "40", "exposure_stops: expected <= 12.0, got 40.0"),
    ("--exposure-step-stops", "1e9", "exposure_step_stops: expected <= 24.0, got 1000000000.0"),
])
def test_cli_refuses_effects_past_what_8_bits_show(source, tmp_path, capsys, option, value, expected):
    """Noise far wider than the 8-bit range, or exposure past its 11.7 stops, wrote saturated frames."""
    assert omnisim_main(["degrade", str(source), "--out", str(tmp_path / "q"), option, value]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"omnisim degrade: error: {option}: {expected}"
    assert not (tmp_path / "q").exists()


@pytest.mark.parametrize("kind", ["folder", "fifo"])
def test_source_meta_json_that_is_no_file_is_one_line(source, tmp_path, capsys, kind):
    """A folder named meta.json in the source ended the copy in an IsADirectoryError traceback; a
    FIFO made degrade wait forever (reading the dataset's provenance, then copying it)."""
    import os

    if kind == "fifo" and not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this system")
    copy = tmp_path / "copy"
    shutil.copytree(source, copy)
    (copy / "meta.json").unlink(missing_ok=True)
    (copy / "meta.json").mkdir() if kind == "folder" else os.mkfifo(copy / "meta.json")
    assert omnisim_main(["degrade", str(copy), "--out", str(tmp_path / "q"), "--no-progress"]) == 2
    shown = "a folder" if kind == "folder" else "no regular file (a FIFO, device, socket or broken link)"
    assert capsys.readouterr().err.strip() == (f"omnisim degrade: error: {copy / 'meta.json'}: is {shown}; "
                                               "expected the source dataset's meta.json file")
    assert not (tmp_path / "q").exists()


@pytest.mark.parametrize("kind", ["folder", "fifo", "broken link"])
def test_source_groundtruth_that_is_no_file_is_one_line(source, tmp_path, capsys, kind):
    """A folder, FIFO or dangling link named groundtruth.txt in the source was skipped: the copy
    had no ground truth, exit 0, and nothing said so."""
    import os

    if kind == "fifo" and not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this system")
    copy = tmp_path / "copy"
    shutil.copytree(source, copy)
    truth = copy / "groundtruth.txt"
    truth.unlink()
    if kind == "folder":
        truth.mkdir()
    elif kind == "fifo":
        os.mkfifo(truth)
    else:
        truth.symlink_to(tmp_path / "nowhere.txt")
    assert omnisim_main(["degrade", str(copy), "--out", str(tmp_path / "q"), "--no-progress"]) == 2
    shown = "a folder" if kind == "folder" else "no regular file (a FIFO, device, socket or broken link)"
    assert capsys.readouterr().err.strip() == (f"omnisim degrade: error: {truth}: is {shown}; "
                                               "expected the source dataset's trajectory file")
    assert not (tmp_path / "q").exists()


def test_cli_reports_a_missing_dataset_in_one_line(tmp_path, capsys):
    assert omnisim_main(["degrade", str(tmp_path / "none"), "--out", str(tmp_path / "q")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "none" in err


@pytest.mark.parametrize("field, value", [("noise_sigma", -1.0), ("exposure_stops", -0.5),
                                          ("exposure_step_stops", -0.1), ("jpeg_quality", -3)])
def test_each_out_of_range_setting_is_named(field, value):
    with pytest.raises(SettingError, match=f"{field}: expected"):
        EffectsSettings(**{field: value})


def test_negative_seed_is_refused(source, tmp_path):
    with pytest.raises(InputError, match="--seed: expected a non-negative integer, got -1"):
        degrade_dataset(source, tmp_path / "x", effects=EffectsSettings(), seed=-1, progress=False)


def test_skipped_file_in_the_source_is_one_warning_line(source, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(source, copy)
    (copy / "images" / "Thumbs.db").write_bytes(b"\0")
    assert omnisim_main(["degrade", str(copy), "--out", str(tmp_path / "out"),
                         "--noise-sigma", "1", "--no-progress"]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith("omnisim degrade: warning: ") and "Thumbs.db" in lines[0]


@pytest.mark.parametrize("target", ["missing", "self"])
def test_frame_that_is_a_broken_link_is_one_line_naming_it(source, tmp_path, capsys, target):
    import shutil

    broken = tmp_path / "src"
    shutil.copytree(source, broken)
    frame = sorted((broken / "images").glob("*.png"))[1]
    frame.unlink()
    frame.symlink_to(frame.name if target == "self" else tmp_path / "nowhere.png")
    assert omnisim_main(["degrade", str(broken), "--out", str(tmp_path / "q"), "--noise-sigma", "2"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(frame) in err and "cannot read the frame" in err
    assert not (tmp_path / "q").exists()


def test_vignetting_is_the_renderers_fall_off_normalised_to_the_images_largest_circle():
    from ifmi.geometry.camera import radius_from_pixels
    from omnisim.capture import vignetting_from_pixels
    from omnisim.degrade import vignetting_of_image

    model = example_omni_model(96)
    factor = vignetting_of_image(model, strength=0.8)
    height, width = model.size
    rows, cols = np.mgrid[0:height, 0:width]
    rho = radius_from_pixels(model, np.stack([rows, cols], axis=-1))
    border = (rows == 0) | (rows == height - 1) | (cols == 0) | (cols == width - 1)
    rho_max = rho[border].min()
    assert np.allclose(factor, (1.0 + (0.8 * rho / rho_max) ** 2) ** -2, rtol=1e-6)
    assert np.array_equal(factor, vignetting_from_pixels(model, strength=0.8, radius_max=rho_max))
    # 1 at the mirror centre, (1 + v^2)^-2 = 0.372 on the largest circle the image holds.
    assert factor.max() > 0.999 and abs(factor[border].max() - 1.64 ** -2) < 1e-6


def test_vignetting_multiplies_linear_intensity_before_the_exposure_gain():
    from omnisim.degrade import vignetting_of_image

    model = example_omni_model(96)
    factor = vignetting_of_image(model, strength=1.5)
    flat = np.full(model.size, 180, dtype=np.uint8)
    out = degrade_image(flat, EffectsSettings(), gain=0.7, seed=0, frame=0, vignetting=factor)
    expected = srgb_uint8_from_linear(linear_from_srgb_uint8(flat) * factor * 0.7)
    assert np.array_equal(out, expected)
    assert out.max() <= 180 and out.min() < 100  # darker toward the corners


def test_vignetted_copy_is_reproducible_and_off_keeps_the_folders_identity(source, tmp_path):
    effects = EffectsSettings(noise_sigma=2.0)
    degrade_dataset(source, tmp_path / "v", effects=effects, seed=1, vignetting=1.0, progress=False)
    degrade_dataset(source, tmp_path / "w", effects=effects, seed=1, vignetting=1.0, progress=False)
    assert all(np.array_equal(x, y) for x, y in zip(_images(tmp_path / "v"), _images(tmp_path / "w")))
    assert json.loads((tmp_path / "v" / "meta.json").read_text())["vignetting"] == 1.0
    degrade_dataset(source, tmp_path / "n", effects=effects, seed=1, progress=False)
    identity = json.loads((tmp_path / "n" / "meta.json").read_text())["identity"]
    assert "vignetting" not in identity  # folders degraded before the option existed still resume
    with pytest.raises(InputError, match="different"):
        degrade_dataset(source, tmp_path / "n", effects=effects, seed=1, vignetting=1.0, progress=False)


def test_cli_refuses_a_vignetting_past_what_8_bits_show(source, tmp_path, capsys):
    assert omnisim_main(["degrade", str(source), "--out", str(tmp_path / "q"), "--vignetting", "9"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("omnisim degrade: error: --vignetting: expected")
    assert not (tmp_path / "q").exists()


def test_vignetting_on_a_kalibr_calibration_is_one_line_naming_it(source, tmp_path):
    from camera_examples import EXAMPLES

    from ifmi.io.kalibr import write_kalibr

    kalibr = tmp_path / "kalibr"
    shutil.copytree(source, kalibr)
    (kalibr / "calib_results.txt").unlink()
    write_kalibr(kalibr / "camera.yaml", EXAMPLES["kb"].scaled(0.5))
    with pytest.raises(InputError, match="needs an OCamCalib calibration") as info:
        degrade_dataset(kalibr, tmp_path / "out", effects=EffectsSettings(), vignetting=0.5, progress=False)
    assert str(kalibr / "camera.yaml") in str(info.value) and not (tmp_path / "out").exists()
