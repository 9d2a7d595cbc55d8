"""The mirror rim against the calibration's centre: exact circles, dark objects, no rim, the run's warning."""

from __future__ import annotations

import re
import shutil
from dataclasses import replace
import warnings

import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model, pixel_offsets_from_sensor, sensor_from_pixels
from ifmi.spectral.mirror_rim import rim_circle_from_frames

SIZE = (256, 256)
MODEL = paracatadioptric_model(SIZE, horizon_radius_px=80.0, center=(127.2, 129.7), affine=(1.004, 0.003, -0.002))
DARK = 12.0


def _rim_frame(centre_sensor, radius, *, seed=0, dark_wedge_deg=None):
    """(H, W) uint8: lit texture (40-240) inside the sensor-plane circle, black outside.

    ``dark_wedge_deg=(start, stop)``: azimuths (sensor plane, about the calibration's centre)
    where the ring from 0.8 of the radius outwards is black, like a dark-clothed operator.
    """
    rows, cols = np.mgrid[0:SIZE[0], 0:SIZE[1]]
    sensor = sensor_from_pixels(MODEL, np.stack([rows, cols], axis=-1).astype(float))
    lit = np.linalg.norm(sensor - centre_sensor, axis=-1) < radius
    if dark_wedge_deg is not None:
        azimuth = np.degrees(np.arctan2(sensor[..., 1], sensor[..., 0])) % 360
        wedge = (azimuth >= dark_wedge_deg[0]) & (azimuth < dark_wedge_deg[1])
        lit &= ~(wedge & (np.linalg.norm(sensor, axis=-1) > 0.8 * radius))
    texture = np.random.default_rng(seed).integers(40, 241, SIZE)
    return np.where(lit, texture, 0).astype(np.uint8)


@pytest.mark.parametrize("centre", [(0.0, 0.0), (3.0, -2.0), (-6.5, 4.25)])
def test_rim_centre_is_found_to_a_fifth_of_a_pixel(centre):
    centre = np.asarray(centre)
    rim = rim_circle_from_frames(MODEL, [_rim_frame(centre, 110.0, seed=k) for k in range(3)], dark_level=DARK)
    expected = pixel_offsets_from_sensor(MODEL, centre)
    np.testing.assert_allclose(rim.centre_offset_px, expected, atol=0.2)
    assert abs(rim.radius_px - 110.0) < 0.5 and rim.rms_px < 0.5
    assert rim.offset_px == pytest.approx(float(np.hypot(*expected)), abs=0.2)


def test_dark_objects_at_the_rim_do_not_move_it():
    centre = np.array([2.0, 1.0])
    frames = [_rim_frame(centre, 110.0, seed=k) for k in range(5)]
    # A dark object across the rim in one frame of five, and an operator's quarter dark in all.
    frames[2] = _rim_frame(centre, 110.0, seed=2, dark_wedge_deg=(30, 150))
    frames = [np.where(_rim_frame(centre, 110.0, dark_wedge_deg=(200, 290)) > 0, f, 0).astype(np.uint8)
              for f in frames]
    rim = rim_circle_from_frames(MODEL, frames, dark_level=DARK)
    np.testing.assert_allclose(rim.centre_offset_px, pixel_offsets_from_sensor(MODEL, centre), atol=0.2)
    assert rim.n_kept < 300  # the quarter held no rim


def test_an_image_lit_to_its_border_has_no_rim():
    frame = np.random.default_rng(0).integers(40, 241, SIZE).astype(np.uint8)
    assert rim_circle_from_frames(MODEL, [frame], dark_level=DARK) is None
    assert rim_circle_from_frames(MODEL, [], dark_level=DARK) is None


def test_a_lit_region_that_is_no_circle_gives_no_rim():
    frame = np.zeros(SIZE, np.uint8)
    frame[40:200, 30:230] = 128  # a rectangle about the centre
    assert rim_circle_from_frames(MODEL, [frame], dark_level=DARK) is None


@pytest.mark.slow
def test_estimate_warns_once_about_a_calibration_centre_off_the_rim(tmp_path, capsys):
    pytest.importorskip("skimage")
    from ifmi.cli import main
    from ifmi.io.calib import read_calib, write_calib
    from ifmi.synthetic import synthetic_sequence, write_synthetic_dataset

    model = paracatadioptric_model(SIZE, horizon_radius_px=80.0, center=(127.2, 129.7))
    sequence = synthetic_sequence(model, 4, seed=3, band_px=(30.0, 120.0), noise_std=1.0)
    root = write_synthetic_dataset(tmp_path / "data", sequence)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["estimate", str(root), "--out", str(tmp_path / "a.txt"), "--no-progress"]) == 0
    assert "rim" not in capsys.readouterr().err
    moved = tmp_path / "moved"
    shutil.copytree(root, moved)
    calib = read_calib(moved / "calib_results.txt")
    write_calib(moved / "calib_results.txt", replace(calib, center=(127.2, 135.7)))
    assert main(["estimate", str(moved), "--out", str(tmp_path / "b.txt"), "--no-progress"]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if "rim" in line]
    assert len(lines) == 1, lines
    found = re.fullmatch(r"ifmi estimate: warning: (.*): the mirror rim in the images is centred ([0-9.]+) px "
                         r"from the calibration's centre \(row ([-+0-9.]+), col ([-+0-9.]+) px; rim radius "
                         r"([0-9]+) px\): the calibration may be from another mounting of the mirror or lens, "
                         r"and the rotations will be biased; recalibrate, or check the centre in the "
                         r"calibration file", lines[0])
    assert found and found[1] == str(moved / "calib_results.txt")
    # The calibration's centre moved 6 px along the columns; the rim stayed where it was.
    np.testing.assert_allclose([float(v) for v in found.groups()[1:5]], [6.0, 0.0, -6.0, 120.0], atol=0.2)


def test_a_frame_of_another_size_is_refused():
    with pytest.raises(ValueError, match=r"frames\[1\]: expected 256x256 pixels \(the calibration's size\), "
                                         r"got shape \(128, 256\)"):
        rim_circle_from_frames(MODEL, [np.zeros(SIZE, np.uint8), np.zeros((128, 256), np.uint8)], dark_level=DARK)


def test_a_kalibr_image_circle_clipped_by_the_image_sides_is_found_about_the_principal_point():
    # An image circle of radius 380 px on a 480 x 752 sensor: only four arcs near the corners show.
    from ifmi.geometry.camera_models import ExtendedUnifiedModel

    model = ExtendedUnifiedModel(0.63, 1.04, (380.0, 380.0), (376.0, 240.0), (480, 752))
    rows, cols = np.mgrid[0:480, 0:752]
    for moved in ((0.0, 0.0), (-4.0, 3.0)):  # (row, col) of the circle's centre minus (pv, pu)
        lit = np.hypot(rows - 240.0 - moved[0], cols - 376.0 - moved[1]) < 380.0
        frame = np.where(lit, np.random.default_rng(1).integers(40, 241, lit.shape), 0).astype(np.uint8)
        rim = rim_circle_from_frames(model, [frame], dark_level=DARK)
        np.testing.assert_allclose(rim.centre_offset_px, moved, atol=0.25)
        assert rim.n_rays < 180  # most rays leave the image before the rim


def test_an_equirectangular_model_has_no_rim():
    from ifmi.geometry.camera_models import EquirectangularModel
    from ifmi.spectral.mirror_rim import model_images_a_rim

    model = EquirectangularModel((128, 256))
    assert not model_images_a_rim(model)
    assert rim_circle_from_frames(model, [np.zeros((128, 256), np.uint8)], dark_level=DARK) is None
