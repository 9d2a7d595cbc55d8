"""Richer ground truth: depth and normal AOVs, per-row poses, ground truth of timed captures."""

from __future__ import annotations

import hashlib
import importlib.util
import json

import numpy as np
import pytest

from ifmi.errors import InputError
from scene_files import write_scene

# Mitsuba must not be imported here: omnisim.llvm selects drjit's LLVM before the first import.
if importlib.util.find_spec("mitsuba") is None:
    pytest.skip("mitsuba is not installed (sim extra)", allow_module_level=True)

pytestmark = pytest.mark.render

ROOM = (6.0, 5.0, 3.0)
SIZE = 64
# A box room, 64x64 pixels, fast motion (up to 20 degrees of yaw and 10 cm per frame).
SCENE = """
[scene]
name = "box"
seed = 3

[render]
resolution = [{size}, {size}]
spp = 1
max_depth = 2

[camera]
pol = [-10.0, 0.0, 2.56e-2, -7.04e-5, 2.048e-6]
center = [32.35, 31.3]
affine = [1.0012, 0.0021, -0.0017]
size = [64, 64]
radius_min = 5.0
radius_max = 30.5

[trajectory]
frames = {frames}
position = [0.3, -0.2, 1.3]
max_yaw_step_deg = 20.0
max_tilt_step_deg = 5.0
smoothness_frames = 1.0
translation_step_m = 0.1
{tum}

[capture]
exposure = {exposure}
rolling_shutter = {rolling}

[materials.walls]
color = [0.6, 0.6, 0.6]
[materials.floor]
color = [0.4, 0.3, 0.2]
[materials.ceiling]
color = [0.8, 0.8, 0.8]

[[objects]]
generator = "room"
size = [6.0, 5.0, 3.0]

[[objects]]
generator = "ceiling_lights"
room = [6.0, 5.0, 3.0]
grid = [1, 2]
size = [1.0, 0.5]
"""


def _scene(tmp_path, *, frames=2, exposure=0.0, rolling=0.0, tum="", size=SIZE, name="box.toml"):
    text = SCENE.format(frames=frames, exposure=exposure, rolling=rolling, tum=tum, size=size)
    return write_scene(tmp_path, text, name)


def _pose_matrix(trajectory, k):
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = trajectory.rotations[k], trajectory.positions[k]
    return matrix


def _distance_to_room(points):
    """Distance of world points (N, 3) to the nearest face of the room, and that face's axis."""
    hx, hy, lz = ROOM[0] / 2, ROOM[1] / 2, ROOM[2]
    faces = np.stack([np.abs(np.abs(points[:, 0]) - hx), np.abs(np.abs(points[:, 1]) - hy),
                      np.abs(points[:, 2]), np.abs(points[:, 2] - lz)], axis=1)
    nearest = np.argmin(faces, axis=1)
    return faces[np.arange(len(points)), nearest], np.minimum(nearest, 2)


def _reprojection(out, k, row_poses):
    """World points and normals of frame k's depth/normal AOVs, each row carried by its pose (H, 4, 4)."""
    from ifmi.geometry.camera import rays_from_pixels
    from ifmi.io.calib import read_calib

    model = read_calib(out / "calib_results.txt")
    depth = np.load(out / "depth" / f"{k:06d}.npy")
    normal = np.load(out / "normal" / f"{k:06d}.npy")
    assert depth.dtype == np.float32 and depth.shape == model.size
    assert normal.dtype == np.float32 and normal.shape == model.size + (3,)
    rows, cols = np.nonzero(np.isfinite(depth))
    rays = rays_from_pixels(model, np.stack([rows, cols], axis=-1).astype(np.float64))
    poses = row_poses[rows]
    points = np.einsum("nij,nj->ni", poses[:, :3, :3], depth[rows, cols, None] * rays) + poses[:, :3, 3]
    normals = np.einsum("nij,nj->ni", poses[:, :3, :3], normal[rows, cols])
    return points, normals, np.isfinite(depth)


def _check_room(points, normals):
    distance, axis = _distance_to_room(points)
    along = np.abs(normals[np.arange(len(points)), axis])
    assert len(points) > 1000
    assert np.median(distance) < 1e-3, np.median(distance)
    assert np.median(along) > 0.9999, np.median(along)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)


@pytest.mark.parametrize("exposure", [0.0, 0.6])
def test_depth_and_normals_land_on_room_walls(tmp_path, exposure):
    """depth * rays_from_pixels, carried by the ground-truth pose, lies on the room's faces (median < 1 mm).

    The room's faces are the planes |x| = 3, |y| = 2.5, z = 0, z = 3 m; the
    normals, rotated to the world, are the faces' axes. Pixels outside the
    mirror band have no surface: NaN. With motion blur the AOV rays are traced
    at mid-exposure, so this also checks that the ground truth is exactly the
    pose the mid-exposure rays see.
    """
    from ifmi.io.tum import read_tum
    from omnisim.renderer import render_dataset

    scene = _scene(tmp_path, exposure=exposure)
    out = tmp_path / "out"
    render_dataset(scene, out, progress=False, aovs="depth,normal")
    world = read_tum(out / "poses_world.txt")
    for k in range(2):
        row_poses = np.broadcast_to(_pose_matrix(world, k), (SIZE, 4, 4))
        points, normals, hit = _reprojection(out, k, row_poses)
        _check_room(points, normals)
        assert not hit[0, 0] and not hit[32, 31]  # outside the band / the camera's own reflection
        assert np.isnan(np.load(out / "normal" / f"{k:06d}.npy")[0, 0]).all()
    meta = json.loads((out / "meta.json").read_text())
    for kind in ("images", "depth", "normal"):
        for name, sha in meta[kind].items():
            assert hashlib.sha256((out / kind / name).read_bytes()).hexdigest() == sha
    assert meta["complete"] and sorted(meta["depth"]) == ["000000.npy", "000001.npy"]


def test_rolling_shutter_row_poses_explain_the_depth(tmp_path):
    """With rolling shutter and blur, each row's exported pose carries its depth onto the walls.

    The AOV ray of row r is traced at the row's mid-exposure, the time of
    line r of rolling_shutter/NNNNNN.txt (T_0r in camera 0 of groundtruth.txt).
    The frame's single ground-truth pose does not explain the top and bottom
    rows: their points miss the walls by centimetres.
    """
    from ifmi.io.tum import read_tum
    from omnisim.renderer import render_dataset

    scene = _scene(tmp_path, exposure=0.3, rolling=0.6)
    out = tmp_path / "out"
    render_dataset(scene, out, progress=False, aovs=("depth", "normal"))
    world = read_tum(out / "poses_world.txt")
    origin = _pose_matrix(world, 0)
    meta = json.loads((out / "meta.json").read_text())
    assert sorted(meta["rolling_shutter"]) == ["000000.txt", "000001.txt"]
    for name, sha in meta["rolling_shutter"].items():
        assert hashlib.sha256((out / "rolling_shutter" / name).read_bytes()).hexdigest() == sha
    for k in range(2):
        rows = read_tum(out / "rolling_shutter" / f"{k:06d}.txt")
        assert len(rows) == SIZE
        np.testing.assert_allclose(rows.timestamps, k + 0.6 * np.arange(SIZE) / (SIZE - 1) + 0.15, atol=1e-6)
        row_poses = np.stack([origin @ _pose_matrix(rows, r) for r in range(SIZE)])
        points, normals, _ = _reprojection(out, k, row_poses)
        _check_room(points, normals)
        frame_pose = np.broadcast_to(_pose_matrix(world, k), (SIZE, 4, 4))
        points, _, _ = _reprojection(out, k, frame_pose)
        assert np.percentile(_distance_to_room(points)[0], 90) > 0.01


def test_ground_truth_is_the_pose_at_mid_exposure_of_the_middle_row(tmp_path):
    """groundtruth.txt of a timed capture = trajectory interpolated at k + (rs + e)/2.

    The trajectory of the timed render is the sharp render's (same seed), whose
    poses_world.txt holds the trajectory at the frame times.
    """
    from ifmi.io.tum import read_tum
    from omnisim.motion import WorldPoses, poses_at_times
    from omnisim.renderer import render_dataset

    render_dataset(_scene(tmp_path, frames=3, size=16), tmp_path / "sharp", progress=False)
    render_dataset(_scene(tmp_path, frames=4, size=16, name="next.toml"), tmp_path / "next", progress=False)
    timed = _scene(tmp_path, frames=3, exposure=0.2, rolling=0.5, size=16, name="timed.toml")
    render_dataset(timed, tmp_path / "timed", progress=False)
    samples = read_tum(tmp_path / "next" / "poses_world.txt")
    sharp = read_tum(tmp_path / "sharp" / "poses_world.txt")
    np.testing.assert_array_equal(samples.rotations[:3], sharp.rotations)  # prefix-stable trajectory
    expected = poses_at_times(WorldPoses(rotations=samples.rotations, positions=samples.positions),
                              np.arange(3) + 0.35)
    got = read_tum(tmp_path / "timed" / "poses_world.txt")
    np.testing.assert_allclose(got.rotations, expected.rotations, atol=1e-7)
    np.testing.assert_allclose(got.positions, expected.positions, atol=1e-7)
    gt = read_tum(tmp_path / "timed" / "groundtruth.txt")
    np.testing.assert_allclose(gt.rotations[2], expected.rotations[0].T @ expected.rotations[2], atol=1e-7)


def test_missing_aov_files_are_rendered_again_identically(tmp_path):
    from omnisim.renderer import render_dataset

    scene = _scene(tmp_path, size=32)
    out = tmp_path / "out"
    render_dataset(scene, out, progress=False, aovs="depth,normal")
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*.np[y]")}
    image = (out / "images" / "000000.png").read_bytes()
    (out / "depth" / "000001.npy").unlink()
    (out / "normal" / "000000.npy").write_bytes(b"broken")
    again = render_dataset(scene, out, progress=False, aovs="depth,normal")
    assert again.rendered == 2
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*.np[y]")} == before
    assert (out / "images" / "000000.png").read_bytes() == image
    assert render_dataset(scene, out, progress=False, aovs="depth,normal").rendered == 0


def test_unknown_aov_is_one_line_error(tmp_path):
    from omnisim.renderer import render_dataset

    with pytest.raises(InputError, match=r"--aov: expected AOV names from depth, normal, got albedo"):
        render_dataset(_scene(tmp_path), tmp_path / "out", progress=False, aovs="depth,albedo")


@pytest.mark.parametrize("aov, expected", [
    (",,", "expected comma-separated AOV names from depth, normal, got an empty name in ',,'"),
    ("depth,", "expected comma-separated AOV names from depth, normal, got an empty name in 'depth,'"),
    ("depth,depth", "expected each AOV name once, got depth more than once in 'depth,depth'"),
    ("normal, depth,normal", "expected each AOV name once, got normal more than once in 'normal, depth,normal'"),
])
def test_empty_or_repeated_aov_names_are_one_line_errors(tmp_path, capsys, aov, expected):
    """``--aov ,,`` rendered no AOVs and ``--aov depth,depth`` depth once, both with exit 0."""
    from omnisim.cli import main

    scene = _scene(tmp_path, frames=1, size=16)
    code = main(["render", str(scene), "--out", str(tmp_path / "out"), "--aov", aov, "--no-progress"])
    assert code == 2
    assert capsys.readouterr().err.strip() == f"omnisim render: error: {scene}: --aov: {expected}"
    assert not (tmp_path / "out").exists()


def test_no_aov_names_mean_no_aovs():
    from omnisim.aov import aov_names_from_text

    assert aov_names_from_text("") == aov_names_from_text(" ") == aov_names_from_text(()) == ()
    assert aov_names_from_text(" normal,depth ") == aov_names_from_text(["normal", "depth"]) == ("depth", "normal")


def test_timed_capture_needs_the_pose_after_the_last_frame(tmp_path):
    from omnisim.renderer import render_dataset

    (tmp_path / "path.txt").write_text("0 0 0 0 0 0 0 1\n1 0.1 0 0 0 0 0.0998 0.995\n")
    scene = _scene(tmp_path, frames=2, exposure=0.5, tum='tum = "path.txt"')
    with pytest.raises(InputError, match=r"path.txt: trajectory has 2 poses.*after the last frame"):
        render_dataset(scene, tmp_path / "out", progress=False)


def test_cli_writes_aovs_and_reports_bad_names_in_one_line(tmp_path, capsys):
    from omnisim.cli import main

    scene = _scene(tmp_path, frames=1, size=16)
    assert main(["render", str(scene), "--out", str(tmp_path / "out"), "--aov", "depth", "--no-progress"]) == 0
    assert (tmp_path / "out" / "depth" / "000000.npy").exists()
    assert not (tmp_path / "out" / "normal").exists()
    capsys.readouterr()
    code = main(["render", str(scene), "--out", str(tmp_path / "bad"), "--aov", "depth,speed", "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "box.toml" in err and "speed" in err
    code = main(["render", str(scene), "--out", str(tmp_path / "bad"), "--workers", "0", "--no-progress"])
    assert code == 2 and "--workers: expected >= 1 and at most" in capsys.readouterr().err




def _kalibr_points(out, k, model, translation_scale=1.0):
    """Frame k's surface points (depth * rays of camera.yaml's ``model``) in camera 0, carried by
    ``T_0k`` of groundtruth.txt with its translation times ``translation_scale``, (N, 3) metres."""
    from ifmi.io.tum import read_tum

    gt = read_tum(out / "groundtruth.txt")
    depth = np.load(out / "depth" / f"{k:06d}.npy").astype(np.float64)
    rows, cols = np.nonzero(np.isfinite(depth))
    points_k = depth[rows, cols, None] * model.rays_from_pixels(np.stack([rows, cols], axis=-1).astype(np.float64))
    return points_k @ gt.rotations[k].T + translation_scale * gt.positions[k]


def _depth_ratio_error(out, points_0, model):
    """``|distance of points_0 from camera 0 / frame 0's depth where they project - 1|``, (M,), over the
    points that project inside frame 0 between pixels that all hit a surface.

    Frame 0's inverse depth is interpolated bilinearly (on a plane it is nearly linear in the pixel
    position: at 96 px the interpolation errs by about 1e-4)."""
    from scipy.ndimage import map_coordinates

    pixels = model.pixels_from_rays(points_0)
    height, width = model.size
    inside = (np.all(np.isfinite(pixels), axis=1) & (pixels[:, 0] >= 0) & (pixels[:, 0] <= height - 1)
              & (pixels[:, 1] >= 0) & (pixels[:, 1] <= width - 1))
    inverse_depth = 1.0 / np.load(out / "depth" / "000000.npy").astype(np.float64)
    sampled = map_coordinates(inverse_depth, pixels[inside].T, order=1, mode="nearest")
    error = np.abs(np.linalg.norm(points_0[inside], axis=1) * sampled - 1.0)
    return error[np.isfinite(error)]


@pytest.mark.parametrize("name", ["ds", "kb", "omni-radtan"])
def test_translated_kalibr_set_ground_truth_carries_depth_between_frames(tmp_path, name):
    """A Kalibr camera 6 and 11 cm and 7 and 23 degrees away from frame 0: ``T_0k`` of groundtruth.txt
    carries frame k's surface points (depth * rays of the set's camera.yaml) onto what frame 0 sees.

    Exact geometry of a translated set: the renderer's rays are central and start at the camera
    centre the ground truth names, in the frame it names. Carried on into the world by frame 0's
    pose the points lie on the room's faces (measured median under 1e-5 m); they land where frame
    0's depth meets them (measured median ratio error 1e-4 to 2e-4, bilinear interpolation).
    Without the translation of ``T_0k`` the ratio errs by 6e-3 to 1e-2.
    """
    from camera_examples import EXAMPLES

    from ifmi.io.kalibr import read_kalibr
    from ifmi.io.tum import read_tum
    from omnisim.config import write_scene_with_kalibr_camera
    from omnisim.renderer import render_dataset

    calibration = EXAMPLES[name]
    scene = write_scene_with_kalibr_camera(_scene(tmp_path, frames=3), calibration, tmp_path / "kalibr")
    out = tmp_path / "out"
    render_dataset(scene, out, progress=False, aovs="depth",
                   resolution=calibration.scaled(96 / calibration.width).size)
    model = read_kalibr(out / "camera.yaml")
    world = read_tum(out / "poses_world.txt")
    for k in range(3):
        points_0 = _kalibr_points(out, k, model)
        distance, _ = _distance_to_room(points_0 @ world.rotations[0].T + world.positions[0])
        assert len(distance) > 0.3 * model.height * model.width
        assert np.median(distance) < 1e-4 and np.percentile(distance, 99) < 1e-3, distance
        ratio_error = _depth_ratio_error(out, points_0, model)
        assert len(ratio_error) > 0.3 * len(points_0)
        assert np.median(ratio_error) < 1e-3 and np.percentile(ratio_error, 90) < 3e-3, ratio_error
        if k > 0:
            unmoved = _depth_ratio_error(out, _kalibr_points(out, k, model, translation_scale=0.0), model)
            assert np.median(unmoved) > 3e-3, np.median(unmoved)
