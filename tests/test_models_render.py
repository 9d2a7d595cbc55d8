"""The omni sensor renders every camera model exactly (renders of about 128 px, 1 spp)."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

# Mitsuba must not be imported here: omnisim.llvm selects drjit's LLVM before the first import.
if importlib.util.find_spec("mitsuba") is None:
    pytest.skip("mitsuba is not installed (sim extra)", allow_module_level=True)

from ifmi.geometry.camera import valid_mask
from ifmi.geometry.rotations import matrix_from_rpy

from camera_examples import EXAMPLES


def _drawn_by_table(table, pixels) -> np.ndarray:
    """``(...,)`` bool: whether the renderer's undistortion ``table`` draws ``(row, col)`` film positions
    ``(..., 2)``: all four nodes of the cell holding each position are drawn (the table's first node sits
    at pixel (-1, -1))."""
    t = (np.asarray(pixels, dtype=np.float64) + 1.0) / table.spacing_px
    nodes = table.rendered_nodes
    first = np.clip(np.floor(t).astype(int), 0, np.array(nodes.shape) - 2)
    r, c = first[..., 0], first[..., 1]
    return nodes[r, c] & nodes[r, c + 1] & nodes[r + 1, c] & nodes[r + 1, c + 1]

pytestmark = pytest.mark.render

KALIBR_NAMES = sorted(set(EXAMPLES) - {"ocamcalib"})
ROTATION = matrix_from_rpy(np.radians([12.0, -7.0, 33.0]))
POSITION = np.array([0.3, -0.4, 0.2])


def _small(name):
    model = EXAMPLES[name]
    return model.scaled(128 / model.width)


@pytest.fixture(scope="module")
def mi():
    from omnisim.llvm import import_mitsuba
    from omnisim.sensor import register_omni_sensor

    module = import_mitsuba()
    register_omni_sensor(module)
    return module


def _position_scene(mi, model):
    from omnisim.sensor import sensor_dict, to_world_matrix

    sensor = sensor_dict(model, to_world=to_world_matrix(ROTATION, POSITION), radius_min=0.0,
                         radius_max=float("inf"), spp=1, sampler="stratified", mi=mi)
    # One stratum per pixel without jitter: the single sample sits exactly at the pixel centre.
    sensor["sampler"]["jitter"] = False
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "aov", "aovs": "pp:position"},
        "sensor": sensor,
        "room": {"type": "cube", "flip_normals": True,
                 "to_world": mi.ScalarTransform4f().scale([3.0, 4.0, 2.5])},
    })


def _eroded(mask, pixels=1):
    import cv2

    return cv2.erode(mask.astype(np.uint8), np.ones((2 * pixels + 1, 2 * pixels + 1), np.uint8)) > 0


@pytest.mark.parametrize("name", KALIBR_NAMES)
def test_position_aov_reprojects_to_pixel_centres(mi, name):
    """As tests/test_omnisim_sensor.py for OCamCalib: each hit point projects back onto its pixel.

    The ground truth is in the model's own frame: the pose maps model-frame
    rays to the world, and pixels_from_rays of the model closes the loop.
    """
    model = _small(name)
    position = np.array(mi.render(_position_scene(mi, model)))[..., -3:]
    valid = _eroded(valid_mask(model))
    rows, cols = np.mgrid[0:model.height, 0:model.width]
    rays = (position[valid].astype(np.float64) - POSITION) @ ROTATION
    pixels = model.pixels_from_rays(rays)
    err = np.hypot(pixels[:, 0] - rows[valid], pixels[:, 1] - cols[valid])
    assert valid.sum() > 0.3 * model.height * model.width
    assert np.median(err) < 0.01, np.median(err)
    assert np.percentile(err, 90) < 0.05, np.percentile(err, 90)


def _strong_tangential():
    from ifmi.geometry.camera_models import PinholeModel

    # Tangential terms five times those of the examples: the radial table's start is farther off.
    return PinholeModel.create((500.0, 500.0), (319.5, 239.5), (480, 640), (-0.3, 0.1, 5e-3, -4e-3))


@pytest.mark.parametrize("name", KALIBR_NAMES + ["strong-tangential"])
def test_sensor_rays_match_the_model_at_every_valid_pixel(mi, name):
    """The sensor's ray of every valid pixel centre (full calibration size) projects back onto it.

    Float32 ray code (radtan: the interpolated undistortion table) against
    the float64 numpy model: measured max 5e-4 px.
    """
    from omnisim.sensor import sensor_dict

    model = _strong_tangential() if name == "strong-tangential" else EXAMPLES[name]
    sensor = mi.load_dict(sensor_dict(model, to_world=np.eye(4), radius_min=0.0, radius_max=float("inf"),
                                      spp=1, mi=mi))
    rows, cols = np.nonzero(valid_mask(model))
    sample = mi.Point2f(((cols + 0.5) / model.width).astype(np.float32),
                        ((rows + 0.5) / model.height).astype(np.float32))
    ray, weight = sensor.sample_ray(0.0, 0.5, sample, mi.Point2f(0.5, 0.5))
    pixels = model.pixels_from_rays(np.array(ray.d).T.astype(np.float64))
    assert np.all(np.array(weight)[0] > 0)
    assert np.max(np.hypot(pixels[:, 0] - rows, pixels[:, 1] - cols)) < 0.01


def _fold():
    from ifmi.geometry.camera_models import PinholeModel

    # Radial distortion that turns back inside the image (r_d peaks at 0.651, 26 px off centre).
    return PinholeModel.create((40.0, 40.0), (63.5, 47.5), (96, 128), (-0.4, 0.05, 0.0, 0.0))


@pytest.mark.parametrize("name", ["omni-wide", "pinhole-radtan", "omni-radtan", "kb", "fold"])
def test_pixels_outside_the_valid_region_are_black(mi, name):
    from omnisim.camera_rays import undistortion_table

    model = _fold() if name == "fold" else _small(name)
    position = np.array(mi.render(_position_scene(mi, model)))[..., -3:]
    valid = valid_mask(model)
    drawn = valid
    if name == "fold":  # inside the fold a band of cells that no table interpolates exactly is black
        pixels = np.stack(np.mgrid[0:model.height, 0:model.width], axis=-1)
        drawn = valid & _drawn_by_table(undistortion_table(model), pixels)
        assert 0.8 * valid.sum() < drawn.sum() < valid.sum()
    hit = np.linalg.norm(position, axis=-1) > 0
    assert hit[_eroded(drawn)].all()
    assert not hit[~valid & _eroded(~valid)].any()
    if name == "omni-wide":  # a disc inside the image, beyond 180 degrees
        assert (~valid).sum() > 0.01 * valid.size and np.degrees(model.field_of_view_rad) > 180


# Float32 allowance (px) of the sensor's rays over the table's interpolation bound: table
# coordinates of up to ~2600 carry an ulp of 2.4e-4 nodes (<= 6e-5 px at a quarter-pixel
# spacing), the sample position's own rounding is 3e-5 px, and float32 directions and
# undistorted coordinates (relative 6e-8) are worth ~3e-5 px at these focal lengths.
FLOAT32_ALLOWANCE_PX = 2e-4


@pytest.mark.parametrize("name,width", [("omni-radtan", 384), ("omni-radtan", 128), ("pinhole-radtan", 640),
                                        ("pinhole-radtan", 128), ("strong-tangential", 640), ("fold", 128)])
def test_radtan_rays_at_any_film_position_stay_within_the_table_bound(mi, name, width):
    """Random sub-pixel positions (not only pixel centres, where the table's nodes sit).

    The sensor's ray reprojects within the undistortion table's interpolation
    bound (plus float32 rounding), that bound is below the models' round-trip
    tolerance (1e-3 px; near a fold: below the cell tolerance, 0.01 px), and
    exactly the positions the table draws are lit -- all inside the valid
    region; near a fold the black band is at most 2.5 px wide.
    """
    from omnisim.camera_rays import CELL_TOLERANCE_PX, TABLE_ERROR_TARGET_PX, undistortion_table
    from omnisim.sensor import sensor_dict

    base = {"strong-tangential": _strong_tangential(), "fold": _fold()}.get(name) or EXAMPLES[name]
    model = base.scaled(width / base.width)
    table = undistortion_table(model)
    sensor = mi.load_dict(sensor_dict(model, to_world=np.eye(4), radius_min=0.0, radius_max=float("inf"),
                                      spp=1, mi=mi))
    samples = np.random.default_rng(7).random((2, 50_000)).astype(np.float32)
    pixels = np.stack([samples[1] * np.float64(model.height), samples[0] * np.float64(model.width)], -1) - 0.5
    ray, weight = sensor.sample_ray(0.0, 0.5, mi.Point2f(samples[0], samples[1]), mi.Point2f(0.5, 0.5))
    lit = np.array(weight)[0] > 0
    np.testing.assert_array_equal(lit, _drawn_by_table(table, pixels))
    assert not (lit & ~model.valid_pixels(pixels)).any()
    back = model.pixels_from_rays(np.array(ray.d).T[lit].astype(np.float64))
    err = np.linalg.norm(back - pixels[lit], axis=-1)
    assert err.max() <= table.rendered_error_bound_px + FLOAT32_ALLOWANCE_PX, (err.max(), table)
    if name == "fold":
        assert table.rendered_error_bound_px <= CELL_TOLERANCE_PX
        radius = np.hypot(*(pixels - np.array(model.principal_point)[::-1]).T)
        valid = model.valid_pixels(pixels)
        assert radius[valid].max() - radius[valid & ~lit].min() < 2.5
    else:
        assert lit.all() and table.error_bound_px <= TABLE_ERROR_TARGET_PX


def test_table_bound_holds_for_float64_interpolation():
    """The analytic bound against bilinear interpolation of the same nodes in float64 (no rounding)."""
    from ifmi.geometry.camera_models import distort_radtan
    from omnisim.camera_rays import undistortion_table

    model = EXAMPLES["omni-radtan"].scaled(0.5)
    table = undistortion_table(model, target_px=np.inf)  # a pixel spacing: the largest errors
    rng = np.random.default_rng(3)
    pixels = rng.uniform(-0.5, 1.0, (100_000, 2)) * np.array(model.size) - np.array([0.0, 0.0])
    pixels = np.clip(pixels, -0.5, np.array(model.size) - 0.5)
    t = (pixels + 1.0) / table.spacing_px
    first = np.floor(t).astype(int)
    f = (t - first)[..., None]
    v = table.values
    r, c = first[:, 0], first[:, 1]
    top = v[r, c] * (1 - f[:, 1]) + v[r, c + 1] * f[:, 1]
    bottom = v[r + 1, c] * (1 - f[:, 1]) + v[r + 1, c + 1] * f[:, 1]
    m = top * (1 - f[:, 0]) + bottom * f[:, 0]
    (fu, fv), (pu, pv) = model.focal, model.principal_point
    distorted = distort_radtan(m, model.distortion)
    back = np.stack([fv * distorted[:, 1] + pv, fu * distorted[:, 0] + pu], -1)
    err = np.linalg.norm(back - pixels, axis=-1)
    assert table.spacing_px == 1.0
    assert 0.5 * table.error_bound_px < err.max() <= table.error_bound_px


def _kernel_reuse_figures(name):
    """Render, set another calibration through traverse, render again; return what the second compiled.

    Runs in a process of its own (:func:`test_new_calibration_reuses_the_compiled_kernel`):
    which kernels a render compiles depends on what the process ran before, and
    one full-suite run of six compiled the render's kernel anew after the
    earlier tests (248 operations instead of 258), a state no user's render
    process is in.
    """
    from omnisim.camera_rays import ray_parameters
    from omnisim.llvm import import_mitsuba
    from omnisim.sensor import register_omni_sensor

    mi = import_mitsuba()
    import drjit as dr  # after import_mitsuba, which chooses drjit's LLVM
    register_omni_sensor(mi)
    model = _small(name)
    scene = _position_scene(mi, model)
    other = replace(model, focal=tuple(1.07 * f for f in model.focal),
                    principal_point=(model.principal_point[0] + 2.5, model.principal_point[1] - 1.5))
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    # Read the first image back like the second, so that both renders run the same kernels
    # (the read-back has its own): only the calibration differs between them.
    np.array(mi.render(scene))
    dr.eval()
    dr.sync_thread()
    dr.kernel_history()  # clear
    params = mi.traverse(scene)
    params["sensor.params"] = mi.Float(np.array(ray_parameters(other), dtype=np.float32))
    params.update()
    position = np.array(mi.render(scene))[..., -3:]
    history = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    # The render's kernel runs one lane per film pixel and is the one that reads the calibration.
    pixels = model.height * model.width
    valid = _eroded(valid_mask(other))
    rows, cols = np.mgrid[0:other.height, 0:other.width]
    back = other.pixels_from_rays((position[valid].astype(np.float64) - POSITION) @ ROTATION)
    return {
        "sizes": [int(k["size"]) for k in history],
        "render": [{"hash": str(k.get("hash")), "operations": int(k.get("operation_count", -1)),
                    "cache_hit": bool(k.get("cache_hit"))} for k in history if k["size"] == pixels],
        "median_px": float(np.median(np.hypot(back[:, 0] - rows[valid], back[:, 1] - cols[valid]))),
    }


@pytest.mark.parametrize("name", ["ds", "kb", "omni-radtan"])
def test_new_calibration_reuses_the_compiled_kernel(name):
    """Another calibration of the same model, set through traverse, compiles nothing and renders exactly."""
    tests = Path(__file__).resolve().parent
    script = (f"import json, sys; sys.path[:0] = [{str(tests)!r}]; import {Path(__file__).stem} as t; "
              f"print(json.dumps(t._kernel_reuse_figures({name!r})))")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         cwd=tests.parent, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    figures = json.loads(run.stdout.strip().splitlines()[-1])
    assert figures["render"], f"expected the render's kernel among sizes {figures['sizes']}"
    missed = [k for k in figures["render"] if not k["cache_hit"]]
    assert not missed, f"compiled anew: {missed}"
    assert figures["median_px"] < 0.01


# Rendered pure-rotation sequences: the longest tests of this file (about 5 s per model on
# 2 cores). At 256 px and 16 spp every model's ATE is measured <= 4e-3 rad; at 4 spp the
# narrow (about 130 degree) models lose their tiles in the noise, hence 16 spp.
SEQUENCE_WIDTH_PX = 256
SEQUENCE_SPP = 16
SEQUENCE_FRAMES = 5
SEQUENCE_ATE_RAD = 0.01
SCENE = Path(__file__).resolve().parents[1] / "scenes" / "urban.toml"


@pytest.mark.parametrize("name", KALIBR_NAMES)
def test_rendered_rotation_sequence_is_estimated(tmp_path, name):
    """omnisim render (camera.yaml) -> ifmi estimate -> geodesic ATE against the model-frame ground truth."""
    from ifmi.io.kalibr import read_kalibr
    from ifmi.io.tum import read_tum
    from ifmi.pipeline import estimate_dataset
    from ifmi.geometry.rotations import geodesic_angle
    from omnisim.config import write_scene_with_kalibr_camera
    from omnisim.renderer import render_dataset

    model = EXAMPLES[name].scaled(SEQUENCE_WIDTH_PX / EXAMPLES[name].width)
    scene = write_scene_with_kalibr_camera(SCENE, EXAMPLES[name], tmp_path)
    out = tmp_path / "dataset"
    render_dataset(scene, out, frames=SEQUENCE_FRAMES, spp=SEQUENCE_SPP, resolution=model.size,
                   progress=False)
    assert read_kalibr(out / "camera.yaml") == model
    assert not (out / "calib_results.txt").exists()
    est = estimate_dataset(out, method="ifmi")
    gt = read_tum(out / "groundtruth.txt")
    assert all(r.success for r in est.frames)
    err = geodesic_angle(gt.rotations, est.trajectory.rotations)
    assert np.sqrt(np.mean(err ** 2)) < SEQUENCE_ATE_RAD
