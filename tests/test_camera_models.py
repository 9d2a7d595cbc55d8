"""Every camera model: exact round trips over its valid region, frames, fields of view, identities."""

from __future__ import annotations

import numpy as np
import pytest

from ifmi.geometry.camera import CameraModel, angles_from_axis, pixels_from_rays, rays_from_pixels, valid_mask
from ifmi.geometry.camera_models import (
    DoubleSphereModel,
    ExtendedUnifiedModel,
    KannalaBrandtModel,
    UnifiedModel,
    distort_radtan,
    undistort_radtan,
)

from camera_examples import EXAMPLES

# DESIGN.md: round trips far below anything an estimator resolves.
ROUND_TRIP_TOLERANCE_PX = 0.01
# Rays: 0.01 px at focal lengths of a few hundred px is ~3e-5 rad.
RAY_TOLERANCE_RAD = 1e-5


def _grid(model):
    rows, cols = np.mgrid[0:model.height, 0:model.width]
    return np.stack([rows, cols], axis=-1).astype(np.float64)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_pixel_ray_pixel_round_trip_over_valid_region(name):
    model = EXAMPLES[name]
    assert isinstance(model, CameraModel)
    grid = _grid(model)
    # Sub-pixel positions too, not only centres.
    grid = grid + np.random.default_rng(1).uniform(-0.5, 0.5, grid.shape)
    valid = model.valid_pixels(grid)
    assert valid.mean() > 0.4
    back = pixels_from_rays(model, rays_from_pixels(model, grid[valid]))
    err = np.hypot(*(back - grid[valid]).T)
    assert err.max() < ROUND_TRIP_TOLERANCE_PX, err.max()


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_ray_pixel_ray_round_trip_inside_field_of_view(name):
    """Random rays that land on valid pixels are lifted back to themselves."""
    model = EXAMPLES[name]
    rays = np.random.default_rng(2).normal(size=(20000, 3))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    pixels = model.pixels_from_rays(rays)
    seen = np.isfinite(pixels).all(axis=1)
    seen[seen] = model.valid_pixels(pixels[seen])
    assert seen.sum() > 1000
    back = model.rays_from_pixels(pixels[seen])
    angle = np.arccos(np.clip(np.sum(back * rays[seen], axis=1), -1, 1))
    assert angle.max() < RAY_TOLERANCE_RAD
    # Seen rays lie inside the stated field of view (to half a pixel's angle).
    off_axis = angles_from_axis(rays[seen], model.optical_axis)
    assert off_axis.max() <= model.field_of_view_rad / 2 + 0.01


@pytest.mark.parametrize("name", sorted(set(EXAMPLES) - {"equirectangular", "ocamcalib"}))
def test_kalibr_frame_x_along_columns_y_along_rows(name):
    model = EXAMPLES[name]
    pu, pv = model.principal_point
    np.testing.assert_allclose(model.rays_from_pixels([pv, pu]), [0, 0, 1], atol=1e-12)
    right, down = model.rays_from_pixels(np.array([[pv, pu + 20.0], [pv + 20.0, pu]]))
    assert right[0] > 0 and abs(right[1]) < 1e-3 * right[0]
    assert down[1] > 0 and abs(down[0]) < 1e-3 * down[1]


def test_equirectangular_layout():
    model = EXAMPLES["equirectangular"]
    h, w = model.size
    centre = model.rays_from_pixels([(h - 1) / 2, (w - 1) / 2])
    np.testing.assert_allclose(centre, [0, 0, 1], atol=1e-12)
    # The top edge is up (-y); a quarter turn right is +x; the left and right edges are behind.
    np.testing.assert_allclose(model.rays_from_pixels([-0.5, 10.0]), [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(model.rays_from_pixels([(h - 1) / 2, 0.75 * w - 0.5]), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(model.rays_from_pixels([(h - 1) / 2, -0.5]), [0, 0, -1], atol=1e-12)
    assert valid_mask(model).all()
    assert model.field_of_view_rad == pytest.approx(2 * np.pi)


def test_unified_eucm_double_sphere_identities():
    """Known equalities: UCM(xi, f) = EUCM(alpha = xi/(1+xi), beta = 1, f/(1+xi)) = DS(0, alpha, f/(1+xi))."""
    xi, f, pp, size = 0.8, 330.0, (321.0, 242.0), (480, 640)
    alpha, g = xi / (1 + xi), f / (1 + xi)
    ucm = UnifiedModel(xi, (f, f), pp, size)
    eucm = ExtendedUnifiedModel(alpha, 1.0, (g, g), pp, size)
    ds = DoubleSphereModel(0.0, alpha, (g, g), pp, size)
    rays = np.random.default_rng(3).normal(size=(500, 3))
    rays[:, 2] = np.abs(rays[:, 2])
    expected = ucm.pixels_from_rays(rays)
    np.testing.assert_allclose(eucm.pixels_from_rays(rays), expected, atol=1e-9)
    np.testing.assert_allclose(ds.pixels_from_rays(rays), expected, atol=1e-9)


def test_kannala_brandt_radius_is_focal_times_distorted_angle():
    model = EXAMPLES["kb"]
    theta = np.radians([0.0, 10.0, 45.0, 80.0, 95.0])
    rays = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=1)
    k1, k2, k3, k4 = model.distortion
    theta_d = theta * (1 + k1 * theta ** 2 + k2 * theta ** 4 + k3 * theta ** 6 + k4 * theta ** 8)
    cols = model.pixels_from_rays(rays)[:, 1]
    np.testing.assert_allclose(cols - model.principal_point[0], model.focal[0] * theta_d, atol=1e-9)


def test_fields_of_view_below_and_above_180_degrees():
    # Unified model with xi > 1 sees z > -|X| / xi: half-angle arccos(-1/xi) when the disc fits the image.
    # Pixel centres sample the rim, where one pixel spans about a degree (the rim compresses).
    wide = UnifiedModel(1.3, (150.0, 150.0), (319.5, 319.5), (640, 640))
    assert np.degrees(wide.field_of_view_rad) == pytest.approx(2 * np.degrees(np.arccos(-1 / 1.3)), abs=1.5)
    assert not valid_mask(wide).all()
    # Equidistant without distortion: the image corner is r / f radians off the axis.
    kb = KannalaBrandtModel((120.0, 120.0), (199.5, 199.5), (400, 400))
    assert kb.field_of_view_rad == pytest.approx(2 * np.hypot(200.0, 200.0) / 120.0, abs=0.02)
    assert kb.field_of_view_rad > np.pi
    assert np.degrees(EXAMPLES["pinhole-radtan"].field_of_view_rad) < 180


def test_radtan_undistortion_converges_to_far_below_a_thousandth_of_a_pixel():
    model = EXAMPLES["omni-radtan"]
    coeffs = model.distortion
    m = np.random.default_rng(4).uniform(-1.0, 1.0, size=(5000, 2))
    undistorted = undistort_radtan(distort_radtan(m, coeffs), coeffs)
    ok = np.isfinite(undistorted).all(axis=1)
    assert ok.mean() > 0.9
    err_px = np.abs(distort_radtan(undistorted[ok], coeffs) - distort_radtan(m[ok], coeffs)).max() * max(model.focal)
    assert err_px < 1e-3
    np.testing.assert_allclose(undistorted[ok], m[ok], atol=1e-6)


def test_rays_outside_the_domain_give_nan_pixels():
    behind = np.array([[0.0, 0.0, -1.0]])
    for name in ("pinhole-radtan", "eucm", "ds", "omni-radtan"):
        assert np.isnan(EXAMPLES[name].pixels_from_rays(behind)).all(), name


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_scaled_model_sees_the_same_rays(name):
    model = EXAMPLES[name]
    half = model.scaled(0.5)
    assert half.size == (model.height // 2, model.width // 2)
    rows, cols = np.mgrid[0:half.height:7, 0:half.width:7]
    pixels = np.stack([rows, cols], axis=-1).astype(np.float64)
    ok = half.valid_pixels(pixels)
    full = (pixels[ok] + 0.5) * 2.0 - 0.5
    angle = np.arccos(np.clip(np.sum(half.rays_from_pixels(pixels[ok]) * model.rays_from_pixels(full),
                                     axis=1), -1, 1))
    # The OCamCalib inverse polynomial is refitted only to 1e-4 px; the others are exact.
    assert angle.max() < 1e-6


def test_invalid_parameters_are_rejected():
    with pytest.raises(ValueError, match="focal"):
        UnifiedModel(0.5, (-1.0, 1.0), (0.0, 0.0), (10, 10))
    with pytest.raises(ValueError, match="alpha"):
        DoubleSphereModel(0.1, 1.5, (1.0, 1.0), (0.0, 0.0), (10, 10))
    with pytest.raises(ValueError, match="finite"):
        ExtendedUnifiedModel(0.5, float("nan"), (1.0, 1.0), (0.0, 0.0), (10, 10))
    with pytest.raises(ValueError, match="4 equidistant"):
        KannalaBrandtModel((1.0, 1.0), (0.0, 0.0), (10, 10), (0.1,))


@pytest.mark.slow
def test_radtan_fold_bounds_the_valid_region():
    """Past the radius where radial distortion turns back, pixels are outside the valid region.

    r_d = r (1 - 0.4 r^2 + 0.05 r^4) peaks at r^2 = (1.2 - sqrt(0.44)) / 0.5, r_d = 0.651:
    farther pixels would also be images of rays from the far branch.
    """
    from ifmi.geometry.camera_models import PinholeModel

    model = PinholeModel.create((200.0, 200.0), (319.5, 239.5), (480, 640), (-0.4, 0.05, 0.0, 0.0))
    r_fold = np.sqrt((1.2 - np.sqrt(0.44)) / 0.5)
    assert model.max_undistorted_radius == pytest.approx(r_fold, abs=1e-3)
    rows, cols = np.mgrid[0:480, 0:640]
    r_d = np.hypot(cols - 319.5, rows - 239.5) / 200.0
    valid = valid_mask(model)
    fold_d = r_fold * (1 - 0.4 * r_fold ** 2 + 0.05 * r_fold ** 4)
    assert valid[r_d < fold_d - 0.005].all() and not valid[r_d > fold_d + 0.005].any()
