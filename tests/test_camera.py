"""OCamCalib camera model: exact round trips and calibration-file contracts."""

from __future__ import annotations

import numpy as np
import pytest

from ifmi.geometry.camera import (
    OcamModel,
    elevation_from_radius,
    fit_inverse_polynomial,
    model_from_direct_polynomial,
    paracatadioptric_model,
    pixels_from_rays,
    radius_from_pixels,
    rays_from_pixels,
)
from ifmi.errors import InputError
from ifmi.io.calib import format_calib, parse_calib, read_calib, write_calib

# The published calibration of a real 748x480 catadioptric camera quoted in DESIGN.md.
PUBLISHED_CALIB = """\
#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB). These are used by cam2world

5 -2.063866e+02 0.000000e+00 2.165610e-03 -4.495456e-06 1.810639e-08

#polynomial coefficients for the inverse mapping function (ocam_model.invpol in MATLAB). These are used by world2cam

12 293.052431 151.538629 -11.130942 27.892086 7.952091 -1.062672 10.373416 1.171771 -6.054173 0.762221 3.136665 0.865190

#center: "row" and "column", starting from 0 (C convention)

241.019976 385.783141

#affine parameters "c", "d", "e"

0.998881 -0.042038 0.045079

#image size: "height" and "width"

480 748
"""

# Round trips must be far below what any estimator can resolve; DESIGN.md fixes 0.01 px.
ROUND_TRIP_TOLERANCE_PX = 0.01


def _all_pixels(model: OcamModel) -> np.ndarray:
    rows, cols = np.mgrid[0:model.height, 0:model.width]
    return np.stack([rows, cols], axis=-1).astype(np.float64)


@pytest.fixture()
def published(tmp_path):
    path = tmp_path / "calib_results.txt"
    path.write_text(PUBLISHED_CALIB)
    return read_calib(path)


def test_read_published_calibration(published):
    assert published.size == (480, 748)
    assert published.center == pytest.approx((241.019976, 385.783141))
    assert published.affine == pytest.approx((0.998881, -0.042038, 0.045079))
    assert len(published.pol) == 5 and published.pol[0] == pytest.approx(-206.3866)
    assert len(published.invpol) == 12 and published.invpol[-1] == pytest.approx(0.865190)


def test_published_inverse_polynomial_matches_direct_on_mirror_band(published):
    """The toolbox's own invpol inverts pol to 0.01 px on the band the mirror images.

    The toolbox fitted it on the mirror's ring only; beyond the image's
    inscribed circle (corners the mirror never reaches) it drifts to 0.02 px.
    """
    pixels = _all_pixels(published)
    radius = radius_from_pixels(published, pixels)
    band = radius <= min(published.size) / 2.0
    back = pixels_from_rays(published, rays_from_pixels(published, pixels[band]))
    err = np.linalg.norm(back - pixels[band], axis=-1)
    assert err.max() < ROUND_TRIP_TOLERANCE_PX


def test_refitted_inverse_round_trip_whole_image(published):
    """Fitting invpol from pol alone (as OCamCalib does) inverts every pixel of the image."""
    model = model_from_direct_polynomial(published.pol, center=published.center,
                                         size=published.size, affine=published.affine)
    pixels = _all_pixels(model)
    back = pixels_from_rays(model, rays_from_pixels(model, pixels))
    assert np.linalg.norm(back - pixels, axis=-1).max() < ROUND_TRIP_TOLERANCE_PX


@pytest.mark.parametrize("affine", [(1.0, 0.0, 0.0), (1.003, -0.012, 0.008)])
@pytest.mark.parametrize("center", [None, (195.3, 211.7)])
def test_paracatadioptric_round_trip(affine, center):
    model = paracatadioptric_model((400, 420), horizon_radius_px=120.0, center=center, affine=affine)
    pixels = _all_pixels(model)
    back = pixels_from_rays(model, rays_from_pixels(model, pixels))
    assert np.linalg.norm(back - pixels, axis=-1).max() < ROUND_TRIP_TOLERANCE_PX


def test_ray_to_pixel_to_ray_round_trip():
    rng = np.random.default_rng(7)
    model = paracatadioptric_model((300, 300), horizon_radius_px=80.0, affine=(0.998, 0.01, -0.02))
    # Elevations the image covers: from straight down the axis to the corner radius.
    rho = rng.uniform(5.0, 140.0, 500)
    phi = rng.uniform(-np.pi, np.pi, 500)
    theta = elevation_from_radius(model.pol, rho)
    rays = np.stack([np.cos(theta) * np.cos(phi), np.cos(theta) * np.sin(phi), np.sin(theta)], -1)
    again = rays_from_pixels(model, pixels_from_rays(model, rays))
    angle = np.arccos(np.clip(np.sum(again * rays, axis=-1), -1.0, 1.0))
    assert angle.max() < 1e-6


def test_paracatadioptric_polynomial_is_the_paraboloid():
    """Rays of a paraboloid through its focus: horizon at r = h, straight down at r = 0."""
    h = 150.0
    model = paracatadioptric_model((512, 512), horizon_radius_px=h, center=(255.5, 255.5))
    ray_axis = rays_from_pixels(model, np.array([255.5, 255.5]))
    np.testing.assert_allclose(ray_axis, [0.0, 0.0, -1.0], atol=1e-12)
    ray_horizon = rays_from_pixels(model, np.array([255.5 + h, 255.5]))
    np.testing.assert_allclose(ray_horizon, [1.0, 0.0, 0.0], atol=1e-12)
    # Frame: x along rows, y along columns.
    ray_col = rays_from_pixels(model, np.array([255.5, 255.5 + h]))
    np.testing.assert_allclose(ray_col, [0.0, 1.0, 0.0], atol=1e-12)


def test_optical_axis_projects_to_centre(published):
    np.testing.assert_allclose(pixels_from_rays(published, np.array([0.0, 0.0, -1.0])),
                               published.center, atol=1e-12)


def test_scaled_model_matches_resampled_pixels():
    model = paracatadioptric_model((200, 240), horizon_radius_px=60.0, center=(97.2, 121.9))
    big = model.scaled(2.0)
    assert big.size == (400, 480)
    pixels = np.array([[10.0, 20.0], [150.0, 33.0], [97.2, 200.0]])
    # Pixel centre p at scale 1 sits at (p + 0.5) * 2 - 0.5 at scale 2.
    np.testing.assert_allclose(rays_from_pixels(big, (pixels + 0.5) * 2.0 - 0.5),
                               rays_from_pixels(model, pixels), atol=1e-5)


def test_fit_inverse_rejects_wrong_sign():
    with pytest.raises(ValueError, match="increase"):
        fit_inverse_polynomial([50.0, 0.0, -0.01], 100.0)


def test_model_validation_messages():
    with pytest.raises(ValueError, match="singular"):
        OcamModel(pol=(-1.0,), invpol=(1.0,), center=(0, 0), affine=(1.0, 1.0, 1.0), size=(10, 10))
    with pytest.raises(ValueError, match="positive"):
        OcamModel(pol=(-1.0,), invpol=(1.0,), center=(0, 0), size=(0, 10))
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        rays_from_pixels(paracatadioptric_model((10, 10), horizon_radius_px=3.0), np.zeros((4, 3)))


# --- calibration files ------------------------------------------------------

def test_calib_file_round_trip(tmp_path):
    model = paracatadioptric_model((321, 257), horizon_radius_px=90.5, center=(160.25, 127.75),
                                   affine=(1.002, -0.013, 0.021))
    path = tmp_path / "calib_results.txt"
    write_calib(path, model)
    assert read_calib(path) == model
    assert not list(tmp_path.glob("*.tmp"))


def test_published_text_round_trip(published):
    assert parse_calib(format_calib(published)) == published


def _broken(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new, 1)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("480 748\n", "", r"expected 5 data blocks, got 4 \(missing: image size"),
        ("5 -2.063866e+02", "6 -2.063866e+02", "direct polynomial: expected 6 coefficients, got 5"),
        ("12 293.052431", "11 293.052431", "inverse polynomial: expected 11 coefficients, got 12"),
        ("0.998881 -0.042038", "0.998881 abc", "affine.*non-numeric value 'abc'"),
        # Python's float() reads digit separators (12_8.45 as 128.45): a typing error in a file.
        ("241.019976 385.783141", "24_1.019976 385.783141", r"center.*non-numeric value '24_1.019976'"),
        ("241.019976 385.783141", "241.019976", r"center \(row col\): expected 2 values, got 1"),
        ("480 748", "480.5 748", "image size must be positive integers"),
        ("0.998881 -0.042038 0.045079", "1.0 1.0 1.0", "singular"),
    ],
)
def test_malformed_calib_files(tmp_path, old, new, message):
    path = tmp_path / "calib_results.txt"
    path.write_text(_broken(PUBLISHED_CALIB, old, new))
    with pytest.raises(InputError, match=message) as info:
        read_calib(path)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_calib_file(tmp_path):
    with pytest.raises(InputError, match="calibration file not found"):
        read_calib(tmp_path / "nope.txt")


def test_sensor_and_pixels_round_trip_through_the_affine_part():
    from ifmi.geometry.camera import pixel_offsets_from_sensor, pixels_from_sensor, sensor_from_pixels

    model = paracatadioptric_model((300, 320), horizon_radius_px=90.0, center=(151.3, 158.2),
                                   affine=(1.003, -0.012, 0.008))
    rng = np.random.default_rng(5)
    pixels = rng.uniform(0.0, 300.0, (50, 2))
    sensor = sensor_from_pixels(model, pixels)
    np.testing.assert_allclose(pixels_from_sensor(model, sensor), pixels, atol=1e-10)
    # Exact matrix form: (row, col) - centre = [[c, d], [e, 1]] (u, v).
    c, d, e = model.affine
    np.testing.assert_allclose(pixel_offsets_from_sensor(model, sensor),
                               sensor @ np.array([[c, d], [e, 1.0]]).T, atol=1e-10)
    np.testing.assert_allclose(np.hypot(sensor[:, 0], sensor[:, 1]), radius_from_pixels(model, pixels))
    # A ray at azimuth phi imaged at sensor radius rho lands on rho (cos phi, sin phi).
    rays = rays_from_pixels(model, pixels)
    phi = np.arctan2(rays[:, 1], rays[:, 0])
    np.testing.assert_allclose(np.arctan2(sensor[:, 1], sensor[:, 0]), phi, atol=1e-12)


def test_angular_pixel_size_of_a_paraboloid_at_its_horizon():
    from ifmi.geometry.camera import angular_pixel_size, pixels_from_sensor

    # pol(r) = -h/2 + r^2/(2h): at r = h the ray is horizontal and d(theta)/dr = 1/h,
    # and across the radius a pixel is 1/h of the horizon circle; both neighbours subtend 1/h rad.
    h = 120.0
    model = paracatadioptric_model((400, 400), horizon_radius_px=h)
    phi = np.linspace(0.0, 2 * np.pi, 12, endpoint=False)
    sensor = h * np.stack([np.cos(phi), np.sin(phi)], axis=-1)
    sizes = angular_pixel_size(model, pixels_from_sensor(model, sensor))
    assert sizes.shape == (12,)
    # One-pixel steps are finite differences: accurate to about 1 / (2 h) relative.
    np.testing.assert_allclose(sizes, 1.0 / h, rtol=1.0 / h)
