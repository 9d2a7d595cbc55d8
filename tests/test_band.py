"""Mirror band detection under dark objects: rims dark in every frame, calibration fallback."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model, radius_from_pixels
from ifmi.spectral.panorama import PanoramaConfig, radius_band

MODEL = paracatadioptric_model((240, 260), horizon_radius_px=70.0, center=(118.6, 133.2),
                               affine=(1.004, 0.006, -0.003))
INNER, OUTER = 40.0, 100.0
CONFIG = PanoramaConfig(min_radius_fraction=0.0)


def _polar():
    rows, cols = np.mgrid[0:MODEL.height, 0:MODEL.width]
    pixels = np.stack([rows, cols], axis=-1).astype(float)
    radius = radius_from_pixels(MODEL, pixels)
    azimuth = np.arctan2(cols - MODEL.center[1], rows - MODEL.center[0])
    return radius, azimuth


def _frame(seed, *, dark=None):
    """Lit band INNER..OUTER with texture; ``dark(radius, azimuth) -> bool mask`` painted black."""
    radius, azimuth = _polar()
    image = np.random.default_rng(seed).integers(110, 190, size=MODEL.size).astype(np.uint8)
    image[(radius < INNER) | (radius > OUTER)] = 0
    if dark is not None:
        image[dark(radius, azimuth)] = 3
    return image


def _check(band, tol=7.0):
    inner, outer = band
    assert INNER <= inner <= INNER + tol
    assert OUTER - tol <= outer <= OUTER


def test_dark_objects_crossing_the_ring_do_not_end_the_band():
    # Three dark objects (a third of the azimuths each time, at different places per frame)
    # cross the whole band, rim to centre; the old rule (first ring more than half dark) cut it.
    frames = []
    for k in range(5):
        centre = 2 * np.pi * k / 5

        def objects(radius, azimuth, centre=centre):
            delta = np.angle(np.exp(1j * (azimuth[..., None] - centre - np.array([0.0, 2.1, 4.2]))))
            return (np.abs(delta) < 0.6).any(axis=-1) & (radius > 30) & (radius < 110)

        frames.append(_frame(k, dark=objects))
    _check(radius_band(MODEL, frames[0], config=CONFIG, frames=frames[1:]))
    # One frame alone: two thirds of each ring dark, still not a rim.
    _check(radius_band(MODEL, frames[0], config=CONFIG))


def test_dark_clothed_operator_in_the_centre_does_not_end_the_band():
    # The operator fills the inner half of the band over 250 degrees of azimuth in every frame.
    def operator(radius, azimuth):
        return (radius < 75) & (np.abs(azimuth) < np.radians(125))

    frames = [_frame(k, dark=operator) for k in range(3)]
    _check(radius_band(MODEL, frames[0], config=CONFIG, frames=frames[1:]))


def test_an_all_dark_image_falls_back_to_the_calibration_band_with_a_warning():
    calib = radius_band(MODEL, config=CONFIG)
    with pytest.warns(UserWarning, match="calibration's band"):
        band = radius_band(MODEL, np.zeros(MODEL.size, np.uint8), config=CONFIG)
    assert band == pytest.approx(calib)
    # A thin lit ring is not trusted either.
    radius, _ = _polar()
    thin = np.where((radius > 60) & (radius < 66), 150, 0).astype(np.uint8)
    with pytest.warns(UserWarning, match="calibration's band"):
        assert radius_band(MODEL, thin, config=CONFIG) == pytest.approx(calib)


def test_a_clean_band_gives_no_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _check(radius_band(MODEL, _frame(0), config=CONFIG))


def test_given_radii_are_the_band_without_detection_or_warning():
    # Both radii fixed (e.g. decided from several frames): the frame is not judged again, so an
    # all-dark frame neither warns nor moves the band.
    fixed = PanoramaConfig(min_radius_fraction=0.0, radius_min_px=42.5, radius_max_px=97.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert radius_band(MODEL, np.zeros(MODEL.size, np.uint8), config=fixed) == (42.5, 97.0)
        assert radius_band(MODEL, _frame(0), config=fixed, frames=[_frame(1)]) == (42.5, 97.0)


def test_band_options_are_checked():
    with pytest.raises(ValueError, match="rim_lit_fraction"):
        PanoramaConfig(rim_lit_fraction=1.5)


def test_sequence_with_a_dark_operator_is_estimated_end_to_end():
    # The operator (dark clothing) covers the inner two thirds of the band over 260 degrees of
    # azimuth in every frame; the band must still span the mirror (the previous rule cut it to
    # 71..93 px) and every frame succeed.
    from ifmi.pipeline import estimate_sequence
    from ifmi.geometry.rotations import geodesic_angle
    from ifmi.synthetic import synthetic_sequence

    model = paracatadioptric_model((200, 200), horizon_radius_px=60.0)
    band = (20.0, 95.0)
    sequence = synthetic_sequence(model, 4, seed=3, max_step_rad=0.04, band_px=band)
    rows, cols = np.mgrid[0:200, 0:200]
    radius = radius_from_pixels(model, np.stack([rows, cols], axis=-1).astype(float))
    azimuth = np.arctan2(cols - model.center[1], rows - model.center[0])
    operator = (radius < 70) & (np.abs(azimuth) < np.radians(130))
    images = [np.where(operator, 2, image).astype(np.uint8) for image in sequence.images]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        inner, outer = radius_band(model, images[0], config=CONFIG)
    assert inner < band[0] + 5 and outer > band[1] - 5
    estimate = estimate_sequence(images, model, method="ifmi")
    assert all(r.success for r in estimate.frames)
    # Measured 0.79 degree at most (a third of the panorama is black).
    assert np.degrees(np.max(geodesic_angle(sequence.rotations, estimate.trajectory.rotations))) < 1.5


def test_dataset_band_is_decided_from_several_frames(tmp_path):
    # Frame 0 has a shadow over the outer band at every azimuth; judged alone it would end
    # the band at 70 px. Over five frames the median lit fraction keeps the whole band.
    import cv2

    from ifmi.pipeline import EstimateConfig, estimate_dataset
    from ifmi.synthetic import synthetic_sequence, write_synthetic_dataset

    model = paracatadioptric_model((160, 160), horizon_radius_px=50.0)
    band = (16.0, 75.0)
    sequence = synthetic_sequence(model, 6, seed=1, max_step_rad=0.03, band_px=band)
    root = write_synthetic_dataset(tmp_path / "ds", sequence)
    rows, cols = np.mgrid[0:160, 0:160]
    radius = radius_from_pixels(model, np.stack([rows, cols], axis=-1).astype(float))
    shadowed = np.where(radius > 55, 1, sequence.images[0]).astype(np.uint8)
    cv2.imwrite(str(root / "images" / "000000.png"), shadowed)
    alone = radius_band(model, shadowed, config=CONFIG)
    assert alone[1] < 56
    config = EstimateConfig()
    estimate = estimate_dataset(root, method="ifmi", config=config)
    panorama = estimate.config.ifmi.panorama
    assert panorama.radius_max_px > band[1] - 5
    assert estimate.config.relative_pose.ransac_threshold_rad is not None


def test_given_radii_read_no_frames_for_the_band(tmp_path, monkeypatch):
    # With both radii in the configuration no frame is read to decide the band (videos share
    # the same step, pipeline._config_with_band); the run keeps the given radii.
    from dataclasses import replace

    import ifmi.pipeline as pipeline
    from ifmi.synthetic import synthetic_sequence, write_synthetic_dataset

    model = paracatadioptric_model((160, 160), horizon_radius_px=50.0)
    sequence = synthetic_sequence(model, 4, seed=1, max_step_rad=0.03, band_px=(16.0, 75.0))
    root = write_synthetic_dataset(tmp_path / "ds", sequence)

    def refuse(*args, **kwargs):
        raise AssertionError("frames were read for a band that was given")

    monkeypatch.setattr(pipeline, "_dataset_band_frames", refuse)
    config = pipeline.EstimateConfig()
    panorama = replace(config.ifmi.panorama, radius_min_px=18.0, radius_max_px=74.0)
    config = replace(config, ifmi=replace(config.ifmi, panorama=panorama))
    estimate = pipeline.estimate_dataset(root, method="ifmi", config=config)
    given = estimate.config.ifmi.panorama
    assert (given.radius_min_px, given.radius_max_px) == (18.0, 74.0)
    with pytest.raises(AssertionError, match="band that was given"):
        pipeline.estimate_dataset(root, method="ifmi", config=pipeline.EstimateConfig())
