"""Panorama unwarp: exact pixel mapping both ways, band detection, rotation about z as a shift."""

from __future__ import annotations

import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model, radius_from_pixels
from ifmi.spectral.panorama import (PanoramaConfig, omni_pixels_from_panorama_pixels, panorama_image_from_omni_image,
                         panorama_pixels_from_omni_pixels, panorama_mapping, radius_band, rays_from_panorama_pixels)

# An off-centre, non-identity-affine paracatadioptric camera.
MODEL = paracatadioptric_model((240, 260), horizon_radius_px=70.0, center=(118.6, 133.2),
                               affine=(1.004, 0.006, -0.003))


def _band_image(model, inner, outer, level=150):
    rows, cols = np.mgrid[0:model.height, 0:model.width]
    radius = radius_from_pixels(model, np.stack([rows, cols], axis=-1).astype(float))
    rng = np.random.default_rng(0)
    image = rng.integers(level - 40, level + 40, size=model.size).astype(np.uint8)
    image[(radius < inner) | (radius > outer)] = 0
    return image


def test_panorama_omni_round_trip():
    mapping = panorama_mapping(MODEL, config=PanoramaConfig(width=256, radius_min_px=30, radius_max_px=110))
    rng = np.random.default_rng(1)
    pano = np.stack([rng.uniform(0, mapping.height - 1, 200), rng.uniform(0, mapping.width, 200)], axis=1)
    omni = omni_pixels_from_panorama_pixels(mapping, pano)
    back = panorama_pixels_from_omni_pixels(mapping, omni)
    col_err = np.abs(np.angle(np.exp(2j * np.pi * (back[:, 1] - pano[:, 1]) / mapping.width)))
    assert np.max(np.abs(back[:, 0] - pano[:, 0])) < 1e-3
    assert np.max(col_err) * mapping.width / (2 * np.pi) < 1e-3


@pytest.mark.parametrize("tile_size", [10, 80])
def test_prepared_panorama_repeats_the_columns_across_the_seam(tile_size):
    # The front end pads the panorama by two tiles on each side with copies of the columns
    # across the seam; 80 px tiles pad by more than the 128 columns, which repeat.
    from ifmi.spectral.ifmi_front_end import IfmiConfig, IfmiFrontEnd
    from ifmi.spectral.tiling import TilingConfig

    panorama = PanoramaConfig(width=128, height=96, radius_min_px=30, radius_max_px=110)
    image = _band_image(MODEL, 30, 110)
    # The front end resamples the image as float (no rounding to gray levels).
    pano = panorama_image_from_omni_image(panorama_mapping(MODEL, config=panorama), image.astype(np.float32))
    fe = IfmiFrontEnd(MODEL, IfmiConfig(panorama=panorama, tiling=TilingConfig(tile_size=tile_size)))
    padded = fe.prepare(image).padded_panorama
    pad = 2 * tile_size
    assert padded.shape == (pano.shape[0], 128 + 2 * pad)
    assert np.array_equal(padded[:, pad:pad + 128], pano)
    assert np.array_equal(padded, pano[:, (np.arange(padded.shape[1]) - pad) % 128])


def test_remap_maps_agree_with_pixel_mapping():
    mapping = panorama_mapping(MODEL, config=PanoramaConfig(width=128, radius_min_px=30, radius_max_px=110))
    rows, cols = np.mgrid[0:mapping.height, 0:mapping.width]
    omni = omni_pixels_from_panorama_pixels(mapping, np.stack([rows, cols], axis=-1).astype(float))
    assert np.allclose(mapping.map_rows, omni[..., 0], atol=1e-3)
    assert np.allclose(mapping.map_cols, omni[..., 1], atol=1e-3)
    radius = radius_from_pixels(MODEL, omni)
    assert radius.min() > 30 - 1e-3 and radius.max() < 110 + 1e-3


def test_rays_of_panorama_columns_are_azimuths():
    mapping = panorama_mapping(MODEL, config=PanoramaConfig(width=360, radius_min_px=30, radius_max_px=110))
    rays = rays_from_panorama_pixels(mapping, np.array([[0.0, 90.0], [mapping.height - 1.0, 0.0]]))
    assert np.allclose(np.linalg.norm(rays, axis=1), 1.0)
    assert np.isclose(np.arctan2(rays[0, 1], rays[0, 0]), np.pi / 2)
    assert np.isclose(np.arcsin(rays[0, 2]), mapping.elevation_top_rad)


def test_rotation_about_the_mirror_axis_is_a_column_shift():
    skimage = pytest.importorskip("skimage")
    from ifmi.synthetic import environment_texture, omni_from_environment

    del skimage
    env = environment_texture(height=256, seed=2)
    mapping = panorama_mapping(MODEL, config=PanoramaConfig(width=360, radius_min_px=35, radius_max_px=110))
    yaw = np.radians(10.0)
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    pano0 = panorama_image_from_omni_image(mapping, omni_from_environment(env, MODEL, np.eye(3)))
    pano1 = panorama_image_from_omni_image(mapping, omni_from_environment(env, MODEL, rz))
    # Camera turned by +10 deg: the world azimuth phi is seen at camera azimuth phi - 10 deg.
    shifted = np.roll(pano0, -10, axis=1)
    inner = slice(3, -3)
    diff = np.abs(shifted[inner] - pano1[inner])
    assert np.median(diff) < 3.0
    assert np.median(np.abs(pano0[inner] - pano1[inner])) > 4 * np.median(diff)


def test_band_detection_finds_ring_and_dark_centre():
    image = _band_image(MODEL, 40.0, 100.0)
    inner, outer = radius_band(MODEL, image, config=PanoramaConfig(min_radius_fraction=0.0))
    assert 40.0 <= inner <= 46.0
    assert 94.0 <= outer <= 100.0
    inner, _ = radius_band(MODEL, image, config=PanoramaConfig(min_radius_fraction=0.6))
    assert inner == pytest.approx(0.6 * outer)


def test_band_without_image_is_the_inscribed_circle():
    inner, outer = radius_band(MODEL, config=PanoramaConfig(min_radius_fraction=0.25))
    # The centre is 118.6 px from the top edge; the affine part changes it by < 1 %.
    assert 116.0 < outer < 119.6
    assert inner == pytest.approx(0.25 * outer)


def test_panorama_of_rgb_and_gray_agree():
    mapping = panorama_mapping(MODEL, config=PanoramaConfig(width=128))
    gray = _band_image(MODEL, 20.0, 110.0)
    rgb = np.repeat(gray[..., None], 3, axis=2)
    assert np.allclose(panorama_image_from_omni_image(mapping, gray),
                       panorama_image_from_omni_image(mapping, rgb), atol=1.0)


def test_wrong_image_size_is_rejected():
    mapping = panorama_mapping(MODEL, config=PanoramaConfig(width=64))
    with pytest.raises(ValueError, match="expected an image of size"):
        panorama_image_from_omni_image(mapping, np.zeros((10, 10), np.uint8))


def test_empty_band_is_rejected():
    with pytest.raises(ValueError, match="radius_min_px < radius_max_px"):
        PanoramaConfig(radius_min_px=50, radius_max_px=40)


def test_automatic_width_is_the_band_circumference():
    mapping = panorama_mapping(MODEL, config=PanoramaConfig(radius_min_px=30, radius_max_px=110))
    assert mapping.width == 64 * round(np.pi * 140 / 64)
    capped = panorama_mapping(MODEL, config=PanoramaConfig(radius_min_px=30, radius_max_px=110,
                                                           max_auto_width=256))
    assert capped.width == 256


def test_band_detection_is_robust_to_sensor_noise():
    # Strong noise puts bright pixels into the black disk and the black surround; a ring is
    # judged on the median-filtered image, so single pixels (the centre "ring" is one) cannot
    # make it look lit.
    clean = _band_image(MODEL, 40.0, 100.0)
    for seed in range(20):
        noisy = np.clip(np.round(clean + np.random.default_rng(seed).normal(0.0, 16.0, clean.shape)), 0, 255)
        inner, outer = radius_band(MODEL, noisy.astype(np.uint8), config=PanoramaConfig(min_radius_fraction=0.0))
        assert 40.0 <= inner <= 47.0
        assert 93.0 <= outer <= 100.0


def test_panorama_image_takes_the_mapping_first():
    mapping = panorama_mapping(MODEL)
    image = np.zeros(MODEL.size, np.uint8)
    with pytest.raises(TypeError, match="expected a PanoramaMapping as the first argument, got ndarray"):
        panorama_image_from_omni_image(image, mapping)


@pytest.mark.parametrize("field, value", [("dark_level", 300.0), ("dark_level", -1.0),
                                          ("margin_px", float("inf")), ("margin_px", -2.0)])
def test_band_options_out_of_range_are_rejected(field, value):
    with pytest.raises(ValueError, match=field):
        PanoramaConfig(**{field: value})
