"""The omni sensor against the exact camera model (renders at 128x128, few spp)."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

# Mitsuba must not be imported here: omnisim.llvm selects drjit's LLVM before the first import.
if importlib.util.find_spec("mitsuba") is None:
    pytest.skip("mitsuba is not installed (sim extra)", allow_module_level=True)

from ifmi.geometry.camera import model_from_direct_polynomial, pixels_from_rays, radius_from_pixels
from ifmi.geometry.rotations import matrix_from_rpy

pytestmark = pytest.mark.render

SIZE = 128
# A catadioptric calibration with the centre off the image centre and a non-identity affine part.
MODEL = model_from_direct_polynomial([-20.0, 0.0, 1.28e-2, -1.76e-5, 2.56e-7], center=(64.35, 63.3),
                                     size=(SIZE, SIZE), affine=(1.0012, 0.0021, -0.0017))
RADIUS_MIN, RADIUS_MAX = 10.0, 61.5
# A pose that is neither identity nor axis-aligned, to exercise to_world fully.
ROTATION = matrix_from_rpy(np.radians([12.0, -7.0, 33.0]))
POSITION = np.array([0.3, -0.4, 0.2])


@pytest.fixture(scope="module")
def mi():
    from omnisim.llvm import import_mitsuba
    from omnisim.sensor import register_omni_sensor

    module = import_mitsuba()
    register_omni_sensor(module)
    return module


def _position_scene(mi, *, radius_min=RADIUS_MIN, radius_max=RADIUS_MAX, crop=None):
    from omnisim.sensor import sensor_dict

    sensor = sensor_dict(MODEL, to_world=np.eye(4), radius_min=radius_min, radius_max=radius_max,
                         spp=1, sampler="stratified", mi=mi)
    # One stratum per pixel without jitter: the single sample sits exactly at the pixel centre.
    sensor["sampler"]["jitter"] = False
    if crop is not None:
        (row, col), (height, width) = crop
        sensor["film"].update({"crop_offset_x": col, "crop_offset_y": row,
                               "crop_width": width, "crop_height": height})
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "aov", "aovs": "pp:position"},
        "sensor": sensor,
        # A closed box around the camera: every pixel's ray hits geometry.
        "room": {"type": "cube", "flip_normals": True,
                 "to_world": mi.ScalarTransform4f().scale([3.0, 4.0, 2.5])},
    })


def _set_pose(mi, scene, rotation, position):
    from omnisim.sensor import to_world_matrix

    params = mi.traverse(scene)
    params["sensor.to_world"] = mi.Transform4f(to_world_matrix(rotation, position).astype(np.float32))
    params.update()


def _band_mask(margin=0.0):
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    radius = radius_from_pixels(MODEL, np.stack([rows, cols], axis=-1))
    return (radius >= RADIUS_MIN + margin) & (radius <= RADIUS_MAX - margin), rows, cols


def test_position_aov_reprojects_to_pixel_centres(mi):
    """Every hit point re-projects through world2cam onto its own pixel centre.

    Design: with the stratified sampler at 1 spp and jitter off, each pixel's
    only sample lies at the pixel centre, and the box filter makes the pixel
    value that sample's value. The position AOV thus holds the world point hit
    by the ray through the pixel centre (row, col) -- exactly the point that
    pixels_from_rays must map back to (row, col). The pose is set through
    traverse/update after loading, which is how sequences are rendered.
    Errors come only from float32 ray tracing and the fitted inverse polynomial.
    """
    scene = _position_scene(mi)
    _set_pose(mi, scene, ROTATION, POSITION)
    position = np.array(mi.render(scene))[..., -3:]
    band, rows, cols = _band_mask(margin=0.5)
    points_world = position[band].astype(np.float64)
    rays_camera = (points_world - POSITION) @ ROTATION  # R^T (p - t), row-vector form
    pixels = pixels_from_rays(MODEL, rays_camera)
    err = np.hypot(pixels[:, 0] - rows[band], pixels[:, 1] - cols[band])
    assert band.sum() > 0.5 * SIZE * SIZE
    assert np.median(err) < 0.01, np.median(err)
    assert np.percentile(err, 90) < 0.05, np.percentile(err, 90)


def test_pixels_outside_mirror_band_are_black(mi):
    scene = _position_scene(mi)
    position = np.array(mi.render(scene))[..., -3:]
    band, _, _ = _band_mask()
    outside_margin, _, _ = _band_mask(margin=-1.0)
    assert np.all(position[~outside_margin] == 0.0)
    assert np.all(np.linalg.norm(position[band], axis=-1) > 0.5)


def test_crop_window_matches_full_render(mi):
    full = np.array(mi.render(_position_scene(mi)))[..., -3:]
    crop = ((20, 70), (40, 33))
    part = np.array(mi.render(_position_scene(mi, crop=crop)))[..., -3:]
    (row, col), (height, width) = crop
    assert part.shape[:2] == (height, width)
    np.testing.assert_allclose(part, full[row:row + height, col:col + width], atol=1e-5)


def test_optical_axis_lands_on_calib_centre(mi):
    """A sample at the calibration centre travels along the camera's z axis.

    The centre pixel (xc, yc) sits at film position (yc + 0.5, xc + 0.5); its
    ray must be the mirror axis, here -z since pol(0) < 0, carried by to_world.
    """
    scene = _position_scene(mi, radius_min=0.0)
    _set_pose(mi, scene, ROTATION, POSITION)
    sensor = scene.sensors()[0]
    row, col = MODEL.center
    sample = mi.Point2f((col + 0.5) / SIZE, (row + 0.5) / SIZE)
    ray, weight = sensor.sample_ray(0.0, 0.5, sample, mi.Point2f(0.5, 0.5))
    direction = np.array(ray.d).ravel()
    origin = np.array(ray.o).ravel()
    np.testing.assert_allclose(direction, -ROTATION[:, 2], atol=2e-6)
    np.testing.assert_allclose(origin, POSITION, atol=1e-6)
    assert np.array(weight).ravel()[0] == pytest.approx(1.0)


def test_axis_marker_image_is_centred_on_calib_centre(mi):
    """A bright sphere on the mirror axis images as a blob whose centroid is the calib centre.

    The sphere is symmetric about the axis and the model maps symmetric ray
    sets to point-symmetric pixel sets about the centre, so the coverage-weighted
    centroid equals (xc, yc) up to sampling noise (64 spp).
    """
    from omnisim.sensor import sensor_dict

    sensor = sensor_dict(MODEL, to_world=np.eye(4), radius_min=0.0, radius_max=RADIUS_MAX, spp=64,
                         sampler="multijitter", mi=mi)
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 1},
        "sensor": sensor,
        "marker": {"type": "sphere", "center": [0.0, 0.0, -3.0], "radius": 0.6,
                   "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}},
    })
    coverage = np.array(mi.render(scene, seed=3))[..., 0]
    assert 20 < coverage.sum() < 0.2 * SIZE * SIZE
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    centroid = np.array([(coverage * rows).sum(), (coverage * cols).sum()]) / coverage.sum()
    np.testing.assert_allclose(centroid, MODEL.center, atol=0.05)


def test_new_calibration_and_pose_reuse_compiled_kernel(mi):
    """Changing coefficients, centre and pose through traverse compiles no new kernel."""
    import drjit as dr

    scene = _position_scene(mi)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        mi.render(scene)
        dr.kernel_history()  # clear
        params = mi.traverse(scene)
        pol = np.array(params["sensor.pol"]) * np.array([1.1, 1, 0.9, 1, 1, 1, 1, 1])
        params["sensor.pol"] = mi.Float(pol.astype(np.float32))
        params["sensor.center"] = mi.Point2f(60.0, 66.0)
        params.update()
        _set_pose(mi, scene, ROTATION, POSITION)
        image = np.array(mi.render(scene))
        history = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert history, "no kernel ran"
    assert all(k.get("cache_hit") for k in history)
    assert np.abs(image).sum() > 0
