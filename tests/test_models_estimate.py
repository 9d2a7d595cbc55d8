"""The estimator on every camera model: panoramas along the model's rays, features lifted through it.

Synthetic frames (no Mitsuba): an equirectangular photo collage is seen by
each model at known orientations (:mod:`ifmi.synthetic`), pixels outside the
model's valid region are black, and every method must recover the rotations.
The rendered counterpart is tests/test_models_render.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from ifmi.geometry.camera import valid_mask
from ifmi.pipeline import estimate_sequence
from ifmi.geometry.rotations import geodesic_angle
from ifmi.synthetic import environment_texture, omni_from_environment, rotation_sequence
from ifmi.spectral.panorama import band_mask, omni_pixels_from_panorama_pixels, panorama_pixels_from_omni_pixels, panorama_mapping

from camera_examples import EXAMPLES

FRAMES = 4
# Images of about 250 px see ~0.005 rad per pixel. Tiles register to a few hundredths of
# a pixel on clean synthetic frames (measured ATE <= 5e-4 rad); ORB/AKAZE keypoints are
# localised to ~0.3 px (measured ATE up to 3e-3 rad over 5 frames).
ATE_TOLERANCE_RAD = {"ifmi": 0.002, "orb": 0.005, "akaze": 0.005}


def _small(name):
    model = EXAMPLES[name]
    return model.scaled(1.6) if name == "equirectangular" else model.scaled(0.5)


@pytest.fixture(scope="module")
def environment():
    return environment_texture(height=512, seed=1)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_panorama_maps_back_exactly(name):
    mapping = panorama_mapping(_small(name))
    rows, cols = np.mgrid[0:mapping.height:3, 0:mapping.width:5]
    pano = np.stack([rows, cols], axis=-1) + 0.25
    back = panorama_pixels_from_omni_pixels(mapping, omni_pixels_from_panorama_pixels(mapping, pano))
    diff = back - pano
    diff[..., 1] = np.mod(diff[..., 1] + mapping.width / 2, mapping.width) - mapping.width / 2
    assert np.abs(diff).max() < 1e-4
    # The band lies in the valid region.
    assert valid_mask(mapping.model)[band_mask(mapping)].all()


@pytest.mark.parametrize("name, fov_deg, bottom_deg", [
    ("pinhole-radtan", "below 180", (45.0, 70.0)),
    ("kb", "above 180", (-20.0, 20.0)),
    ("omni-wide", "above 180", (-10.0, 5.0)),
])
def test_band_follows_the_field_of_view(name, fov_deg, bottom_deg):
    """Looking along z, the panorama's lowest elevation is 90 deg minus the half-angle the image fits."""
    mapping = panorama_mapping(_small(name))
    bottom = np.degrees(mapping.elevation_top_rad - (mapping.height - 1) * mapping.elevation_step_rad)
    assert bottom_deg[0] < bottom < bottom_deg[1]
    assert (np.degrees(mapping.model.field_of_view_rad) > 180) == (fov_deg == "above 180")


@pytest.mark.slow
@pytest.mark.parametrize("method", ["ifmi", "orb", "akaze"])
@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_rotation_sequence_on_every_model(environment, name, method):
    model = _small(name)
    rotations = rotation_sequence(FRAMES, max_step_rad=0.03, seed=2)
    valid = valid_mask(model)
    images = []
    for rotation in rotations:
        image = omni_from_environment(environment, model, rotation)
        image[~valid] = 0
        images.append(image)
    est = estimate_sequence(images, model, method=method)
    assert all(r.success for r in est.frames)
    err = geodesic_angle(rotations, est.trajectory.rotations)
    assert np.sqrt(np.mean(err ** 2)) < ATE_TOLERANCE_RAD[method]


def test_equirectangular_panorama_interpolates_across_the_360_degree_seam():
    """An image that is sin(longitude): panorama samples within half a pixel of the seam
    (columns in [-0.5, 0) or (W - 1, W - 0.5]) interpolate between the last and the first column.

    Bilinear interpolation of sin errs by at most step^2 / 8 (step = 2 pi / W, 1.9e-5 at
    W = 512); repeating the edge column instead errs by up to half a step (6e-3) there.
    """
    from ifmi.spectral.panorama import panorama_image_from_omni_image

    model = _small("equirectangular")
    cols = np.arange(model.width)
    image = np.tile(np.sin((cols + 0.5) * (2 * np.pi / model.width) - np.pi), (model.height, 1)).astype(np.float32)
    mapping = panorama_mapping(model)
    pano = panorama_image_from_omni_image(mapping, image)
    expected = np.sin((mapping.map_cols.astype(np.float64) + 0.5) * (2 * np.pi / model.width) - np.pi)
    seam = (mapping.map_cols < 0) | (mapping.map_cols > model.width - 1)
    assert seam.sum() > 10
    step = 2 * np.pi / model.width
    # OpenCV's bilinear weights are quantised to 1/32 of a pixel: up to step / 64 more.
    assert np.abs(pano - expected)[seam].max() < step ** 2 / 8 + step / 64
    assert np.abs(pano - expected).max() < step ** 2 / 8 + step / 64
