"""Realistic capture: motion blur, rolling shutter and vignetting against sharp renders and formulas."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from ifmi.errors import InputError

# Mitsuba must not be imported here: omnisim.llvm selects drjit's LLVM before the first import.
if importlib.util.find_spec("mitsuba") is None:
    pytest.skip("mitsuba is not installed (sim extra)", allow_module_level=True)

from ifmi.geometry.camera import model_from_direct_polynomial, radius_from_pixels
from ifmi.geometry.rotations import matrix_from_rpy
from omnisim.config import CaptureSettings
from omnisim.motion import WorldPoses, poses_at_times

pytestmark = pytest.mark.render

SIZE = 48
MODEL = model_from_direct_polynomial([-7.5, 0.0, 3.41e-2, -1.25e-4, 4.86e-6], center=(24.2, 23.7),
                                     size=(SIZE, SIZE), affine=(1.0012, 0.0021, -0.0017))
RADIUS_MIN, RADIUS_MAX = 3.0, 23.0
# Frame start and the pose one frame interval later: 30 degrees of yaw, some tilt, a translation.
POSES = WorldPoses(rotations=np.stack([matrix_from_rpy(np.radians([5.0, -3.0, 10.0])),
                                       matrix_from_rpy(np.radians([-4.0, 6.0, 40.0]))]),
                   positions=np.array([[0.1, 0.2, 0.0], [0.4, -0.1, 0.3]]))


@pytest.fixture(scope="module")
def mi():
    from omnisim.llvm import import_mitsuba
    from omnisim.sensor import register_omni_sensor

    module = import_mitsuba()
    register_omni_sensor(module)
    return module


def _sensor(mi, capture, *, spp, centre=False, mid_exposure=False):
    from omnisim.capture import sensor_timing_props
    from omnisim.sensor import sensor_dict

    sensor = sensor_dict(MODEL, to_world=np.eye(4), radius_min=RADIUS_MIN, radius_max=RADIUS_MAX, spp=spp,
                         sampler="stratified" if centre else "multijitter", mi=mi,
                         timing=sensor_timing_props(capture, mid_exposure=mid_exposure))
    if centre:  # one stratum per pixel, no jitter: the sample sits at the pixel centre
        sensor["sampler"]["jitter"] = False
    return sensor


def _position_scene(mi, capture, *, mid_exposure=False):
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "aov", "aovs": "pp:position"},
        "sensor": _sensor(mi, capture, spp=1, centre=True, mid_exposure=mid_exposure),
        "room": {"type": "cube", "flip_normals": True, "to_world": mi.ScalarTransform4f().scale([3.0, 4.0, 2.5])},
    })


def _checker_scene(mi, capture, *, spp):
    """A sphere around the camera emitting a checkerboard: radiance depends on the ray alone."""
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 1},
        "sensor": _sensor(mi, capture, spp=spp),
        "shell": {"type": "sphere", "radius": 10.0, "flip_normals": True, "bsdf": {"type": "diffuse"},
                  "emitter": {"type": "area", "radiance": {
                      "type": "checkerboard", "color0": 0.05, "color1": 1.0,
                      "to_uv": mi.ScalarTransform4f().scale([12.0, 6.0, 1.0])}}},
    })


def _pose(mi, scene, rotation, position, end=None):
    from omnisim.renderer import set_sensor_pose

    set_sensor_pose(mi, mi.traverse(scene), "sensor.", rotation, position, end=end)


def _render(mi, scene, seed=0):
    return np.array(mi.render(scene, seed=seed))


def _sharp_at(mi, scene, t, seed=0):
    pose = poses_at_times(POSES, [t])
    _pose(mi, scene, pose.rotations[0], pose.positions[0])
    return _render(mi, scene, seed)


def _band(margin):
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    radius = radius_from_pixels(MODEL, np.stack([rows, cols], axis=-1))
    return (radius >= RADIUS_MIN + margin) & (radius <= RADIUS_MAX - margin)


@pytest.mark.parametrize("capture", [CaptureSettings(rolling_shutter=0.6),
                                     CaptureSettings(rolling_shutter=0.3, exposure=0.5)])
def test_rolling_shutter_rows_match_sharp_renders_at_their_times(mi, capture):
    """Row r at its mid-exposure sees exactly what a sharp camera sees at time rs * r/(H-1) + e/2.

    The position AOV at pixel centres is a deterministic function of the ray,
    so each row must agree with the sharp render at the row's time to float32
    precision (the sensor slerps in float32), and differ from the sharp render
    at the frame time by centimetres or more.
    """
    from omnisim.capture import row_mid_times

    timed = _position_scene(mi, capture, mid_exposure=True)
    _pose(mi, timed, POSES.rotations[0], POSES.positions[0], end=(POSES.rotations[1], POSES.positions[1]))
    image = _render(mi, timed)[..., -3:]
    sharp = _position_scene(mi, CaptureSettings())
    at_start = _sharp_at(mi, sharp, 0.0)[..., -3:]
    times = row_mid_times(SIZE, capture)
    band = _band(0.5)
    for row in (2, 11, 24, 45):
        reference = _sharp_at(mi, sharp, times[row])[..., -3:]
        mask = band[row]
        assert np.abs(image[row, mask] - reference[row, mask]).max() < 1e-4
        assert np.abs(image[row, mask] - at_start[row, mask]).max() > 0.05


def _noise_check(blurred, other_seed, reference, control, mask):
    """RMS of blurred - reference must be at the level of pure Monte-Carlo noise; control far above it."""
    noise = np.sqrt(np.mean((blurred - other_seed)[mask] ** 2))
    error = np.sqrt(np.mean((blurred - reference)[mask] ** 2))
    bias = np.mean((blurred - reference)[mask])
    far = np.sqrt(np.mean((blurred - control)[mask] ** 2))
    # Two independent blurred renders differ by sqrt(2) sigma; the reference averages
    # many more samples, so blurred - reference is about one sigma.
    assert error < noise, (error, noise)
    assert abs(bias) < 4 * error / np.sqrt(mask.sum()), (bias, error)
    assert far > 3 * noise, (far, noise)


def test_motion_blur_matches_average_of_sharp_renders(mi):
    """A frame exposed for half the frame interval equals the mean of sharp frames over the exposure.

    The scene's radiance depends only on the ray (an emitting checkerboard,
    no light transport), so both images estimate the same integral over
    pixel area and time. 32 sharp renders at the midpoints of 32 equal
    sub-intervals, 64 spp each, form the reference.
    """
    capture = CaptureSettings(exposure=0.5)
    spp, steps = 64, 32
    blurred_scene = _checker_scene(mi, capture, spp=spp)
    _pose(mi, blurred_scene, POSES.rotations[0], POSES.positions[0], end=(POSES.rotations[1], POSES.positions[1]))
    blurred, other = _render(mi, blurred_scene, 1)[..., 0], _render(mi, blurred_scene, 2)[..., 0]
    sharp = _checker_scene(mi, CaptureSettings(), spp=spp)
    times = (np.arange(steps) + 0.5) / steps * capture.exposure
    reference = np.mean([_sharp_at(mi, sharp, t, seed=10 + j)[..., 0] for j, t in enumerate(times)], axis=0)
    control = _sharp_at(mi, sharp, 0.5 * capture.exposure, seed=3)[..., 0]
    _noise_check(blurred, other, reference, control, _band(1.0))


def test_blur_with_rolling_shutter_rows_match_their_exposure_windows(mi):
    """With both effects, row r averages the sharp frames over [rs r/(H-1), rs r/(H-1) + e]."""
    from omnisim.capture import row_start_times

    capture = CaptureSettings(exposure=0.4, rolling_shutter=0.5)
    spp, steps = 32, 16
    scene = _checker_scene(mi, capture, spp=spp)
    _pose(mi, scene, POSES.rotations[0], POSES.positions[0], end=(POSES.rotations[1], POSES.positions[1]))
    blurred, other = _render(mi, scene, 1)[..., 0], _render(mi, scene, 2)[..., 0]
    sharp = _checker_scene(mi, CaptureSettings(), spp=spp)
    starts = row_start_times(SIZE, capture)
    rows = (6, 24, 41)
    reference = np.zeros_like(blurred)
    for row in rows:
        times = starts[row] + (np.arange(steps) + 0.5) / steps * capture.exposure
        frames = [_sharp_at(mi, sharp, t, seed=10 + j)[..., 0] for j, t in enumerate(times)]
        reference[row] = np.mean(frames, axis=0)[row]
    # The control: the same blur without the row delay.
    global_shutter = _checker_scene(mi, CaptureSettings(exposure=capture.exposure), spp=spp)
    _pose(mi, global_shutter, POSES.rotations[0], POSES.positions[0],
          end=(POSES.rotations[1], POSES.positions[1]))
    control = _render(mi, global_shutter, 3)[..., 0]
    mask = _band(1.0) & np.isin(np.arange(SIZE), rows)[:, None]
    _noise_check(blurred, other, reference, control, mask)


def test_timed_sensor_reuses_compiled_kernel(mi):
    """New frame poses (start and end) are kernel parameters: every frame runs the same kernels.

    Kernels are compared by hash, since Dr.Jit's on-disk cache would report a
    hit even for a kernel recompiled per pose value.
    """
    import drjit as dr

    scene = _checker_scene(mi, CaptureSettings(exposure=0.5, rolling_shutter=0.3), spp=2)
    hashes = []
    for start, end in ((0, 1), (1, 0), (0, 0)):
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        try:
            dr.kernel_history()  # clear
            _pose(mi, scene, POSES.rotations[start], POSES.positions[start],
                  end=(POSES.rotations[end], POSES.positions[end]))
            image = _render(mi, scene, 5 + start)
            hashes.append([k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT])
        finally:
            dr.set_flag(dr.JitFlag.KernelHistory, False)
        assert image.sum() > 0
    assert hashes[0] and hashes[0] == hashes[1] == hashes[2]


def test_poses_at_times_slerps_and_lerps():
    """Interpolated poses: exact at the samples, constant angular speed, linear position."""
    from ifmi.geometry.rotations import geodesic_angle

    poses = poses_at_times(POSES, [0.0, 0.25, 0.5, 1.0])
    np.testing.assert_array_equal(poses.rotations[0], POSES.rotations[0])
    np.testing.assert_allclose(poses.rotations[3], POSES.rotations[1], atol=1e-12)
    total = geodesic_angle(POSES.rotations[0], POSES.rotations[1])
    for k, t in ((1, 0.25), (2, 0.5)):
        assert geodesic_angle(POSES.rotations[0], poses.rotations[k]) == pytest.approx(t * total, abs=1e-12)
        assert geodesic_angle(poses.rotations[k], POSES.rotations[1]) == pytest.approx((1 - t) * total, abs=1e-12)
    np.testing.assert_allclose(poses.positions[1], 0.75 * POSES.positions[0] + 0.25 * POSES.positions[1])
    with pytest.raises(ValueError, match="expected times within"):
        poses_at_times(POSES, [1.5])


def test_vignetting_follows_its_formula_on_a_uniform_scene(tmp_path):
    """Under a constant environment every ray sees radiance L, so pixel = L (1 + (v rho/rho_max)^2)^-2."""
    from omnisim.config import load_scene_config
    from omnisim.effects import srgb_uint8_from_linear
    from omnisim.renderer import FramePlan, FrameRenderer, render_dataset

    strength, radiance = 0.8, 0.5
    scene = tmp_path / "uniform.toml"
    scene.write_text(f"""
[render]
resolution = [{SIZE}, {SIZE}]
spp = 4
[camera]
pol = {list(MODEL.pol)}
center = {list(MODEL.center)}
affine = {list(MODEL.affine)}
size = [{SIZE}, {SIZE}]
radius_min = {RADIUS_MIN}
radius_max = {RADIUS_MAX}
[trajectory]
frames = 1
[capture]
vignetting = {strength}
[[lights]]
type = "constant"
radiance = [{radiance}, {radiance}, {radiance}]
""")
    config = load_scene_config(scene)
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    c, d, e = MODEL.affine
    dr_, dc_ = rows - MODEL.center[0], cols - MODEL.center[1]
    rho = np.hypot(dr_ - d * dc_, c * dc_ - e * dr_) / (c - d * e)
    expected = radiance * (1 + (strength * rho / RADIUS_MAX) ** 2) ** -2
    plan = FramePlan(config=config, seed=0, variant="", trajectory=POSES, gains=(1.0,))
    linear = FrameRenderer(plan).linear(0)
    inside = _band(1.0)
    np.testing.assert_allclose(linear[inside], np.repeat(expected[inside][:, None], 3, axis=1), rtol=1e-5)
    assert expected[inside].min() < 0.8 * radiance  # the fall-off is strong enough to matter
    render_dataset(scene, tmp_path / "out", progress=False)
    import cv2
    png = cv2.imread(str(tmp_path / "out" / "images" / "000000.png"))[..., ::-1]
    np.testing.assert_array_equal(png[inside], srgb_uint8_from_linear(linear)[inside])


@pytest.mark.parametrize("table, message", [
    ("exposure = 1.5", r"\[capture\] exposure: expected <= 1.0"),
    ("exposure = 0.7\nrolling_shutter = 0.5", r"\[capture\] exposure \+ rolling_shutter: expected <= 1"),
    ("vignetting = -1", r"\[capture\] vignetting: expected >= 0.0"),
    ("vignetting = 1e30", r"\[capture\] vignetting: expected <= 7.93\d*, got 1e\+30"),
    ("exposure = 'long'", r"\[capture\] exposure: expected a number"),
])
def test_bad_capture_values_are_one_line_errors(tmp_path, table, message):
    from omnisim.config import load_scene_config

    path = tmp_path / "cap.toml"
    path.write_text(f"[camera]\npol = [-20.0, 0.0, 0.01]\ncenter = [32, 32]\nsize = [64, 64]\n"
                    f"[render]\nresolution = 64\n[capture]\n{table}\n")
    with pytest.raises(InputError, match=message):
        load_scene_config(path)


def test_timed_capture_with_the_most_frames_is_one_line_error(tmp_path):
    """A timed capture needs the pose after the last frame: with [trajectory] frames at its bound
    that one pose more failed the bound inside the render and ended in a traceback (SettingError)."""
    from omnisim.config import MAX_FRAMES
    from omnisim.renderer import frame_plan

    path = tmp_path / "cap.toml"
    path.write_text(f"[camera]\npol = [-20.0, 0.0, 0.01]\ncenter = [32, 32]\nsize = [64, 64]\n"
                    f"[render]\nresolution = 64\n[trajectory]\nframes = {MAX_FRAMES}\n[capture]\nexposure = 0.5\n")
    with pytest.raises(InputError, match=rf"cap.toml: frames: expected at most {MAX_FRAMES - 1} with \[capture\] "
                                         rf"exposure or rolling_shutter .*, got {MAX_FRAMES}$"):
        frame_plan(path)
