"""omnisim export: a dataset folder as a ROS bag, read back by the bag readers and the estimate."""

from __future__ import annotations

import os
import shutil

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.cli import main as ifmi_main
from ifmi.io.bag_poses import read_bag_trajectory
from ifmi.io.bags import BagFrames, open_bag
from ifmi.io.calib import write_calib
from ifmi.io.dataset import read_dataset
from ifmi.io.tum import read_tum, write_tum
from ifmi.synthetic import environment_texture, omni_from_environment
from ifmi.geometry.trajectory import Trajectory
from omnisim.cli import main as omnisim_main

SIZE = 128
MODEL = paracatadioptric_model((SIZE, SIZE), horizon_radius_px=40.0)
BAND = (12.0, 60.0)
FRAMES = 5
# (format, storage, compressed, output name) of the bags written.
EXPORTS = (("ros2", "mcap", None, "raw_mcap"), ("ros2", "sqlite3", "png", "png_db3"),
           ("ros1", "mcap", None, "raw.bag"), ("ros1", "mcap", "jpeg", "jpeg.bag"))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A warped RGB sequence with a rolling shutter, and world poses as a render writes them."""
    from omnisim.warp import WarpSettings, warp_dataset

    root = tmp_path_factory.mktemp("export")
    image = omni_from_environment(environment_texture(height=256, seed=3), MODEL, np.eye(3), band_px=BAND)
    colour = np.stack([image, image // 2 + 60, 255 - image], axis=-1)
    cv2.imwrite(str(root / "photo.png"), colour)
    write_calib(root / "calib_results.txt", MODEL)
    out = root / "data"
    warp_dataset(root / "photo.png", root / "calib_results.txt", out, progress=False,
                 settings=WarpSettings(frames=FRAMES, seed=5, max_step_deg=4.0, max_tilt_deg=3.0,
                                       rolling_shutter=0.5))
    truth = read_tum(out / "groundtruth.txt")
    mount = Rotation.from_euler("xyz", [0.3, -0.1, 1.2]).as_matrix()
    write_tum(out / "poses_world.txt", Trajectory(truth.timestamps, truth.positions + [0.4, -0.3, 1.3],
                                                  mount @ truth.rotations))
    return out


def _export(dataset, out, bag_format, storage, compressed, *extra):
    args = ["export", str(dataset), "--out", str(out), "--format", bag_format, "--storage", storage,
            "--no-progress", *extra]
    assert omnisim_main(args + (["--compressed", compressed] if compressed else [])) == 0
    return out


@pytest.mark.slow
@pytest.mark.parametrize("bag_format, storage, compressed, name", EXPORTS)
def test_export_reads_back_as_the_dataset(dataset, tmp_path, bag_format, storage, compressed, name):
    bag = _export(dataset, tmp_path / name, bag_format, storage, compressed)
    folder = list(read_dataset(dataset).iter_images())
    frames = BagFrames(bag, size=MODEL.size)
    decoded = list(frames)
    assert frames.topic == "/camera/image_raw" and frames.timestamps == list(map(float, range(FRAMES)))
    if compressed == "jpeg":  # lossy: close to the folder's frame, and not to its neighbour
        errors = [np.abs(a.astype(float) - b.astype(float)).mean() for a, b in zip(decoded, folder)]
        neighbours = [np.abs(a.astype(float) - b.astype(float)).mean() for a, b in zip(decoded[1:], folder)]
        assert max(errors) < 2.0 and max(errors) * 2 < min(neighbours), (errors, neighbours)
    else:
        assert all(np.array_equal(a, b) for a, b in zip(decoded, folder))
    truth = read_tum(dataset / "groundtruth.txt")
    back = read_bag_trajectory(bag, topic="/groundtruth/pose")
    np.testing.assert_array_equal(back.timestamps, truth.timestamps)
    np.testing.assert_allclose(back.rotations, truth.rotations, rtol=0, atol=1e-15)
    world = read_tum(dataset / "poses_world.txt")
    on_tf = read_bag_trajectory(bag, topic="/tf", frames=("world", "camera"))
    np.testing.assert_allclose(on_tf.rotations, world.rotations, rtol=0, atol=1e-15)
    np.testing.assert_allclose(on_tf.positions, world.positions, rtol=0, atol=1e-15)


def test_rolling_shutter_rows_are_one_path_per_frame(dataset, tmp_path):
    bag = _export(dataset, tmp_path / "rows", "ros2", "mcap", None, "--start-time", "1700000000",
                  "--frame-interval", "0.04")
    with open_bag(bag) as reader:
        connections = [c for c in reader.connections if c.topic == "/groundtruth/row_poses"]
        paths = [(ns, reader.deserialize(data, c.msgtype)) for c, ns, data in reader.messages(connections)]
    assert len(paths) == FRAMES
    for k, (receive_ns, path) in enumerate(paths):
        rows = read_tum(dataset / "rolling_shutter" / f"{k:06d}.txt")
        assert len(path.poses) == SIZE and receive_ns == 1_700_000_000 * 10 ** 9 + k * 40_000_000
        stamps = [p.header.stamp.sec + p.header.stamp.nanosec / 1e9 for p in path.poses]
        np.testing.assert_allclose(stamps, 1_700_000_000 + rows.timestamps * 0.04, rtol=0, atol=2e-6)
        quaternion = path.poses[-1].pose.orientation
        np.testing.assert_allclose(Rotation.from_quat([quaternion.x, quaternion.y, quaternion.z, quaternion.w])
                                   .as_matrix(), rows.rotations[-1], atol=1e-12)


def test_the_estimate_from_an_export_equals_the_folder_estimate(dataset, tmp_path):
    def estimate(args, out):
        assert ifmi_main(["estimate", *map(str, args), "--out", str(out), "--no-progress"]) == 0
        return out.read_text().split("\n", 1)[1]

    folder = estimate([dataset], tmp_path / "folder.txt")
    for name, storage, compressed in (("raw", "mcap", None), ("png", "sqlite3", "png")):
        bag = _export(dataset, tmp_path / name, "ros2", storage, compressed)
        assert estimate([bag, "--calib", dataset / "calib_results.txt"], tmp_path / f"{name}.txt") == folder


def test_export_refuses_what_it_must_not_write(dataset, tmp_path, capsys):
    existing = _export(dataset, tmp_path / "bag", "ros2", "mcap", None)
    before = sorted(os.listdir(existing))
    cases = [(["--out", str(existing)], 1, "exists already"),
             (["--out", str(dataset / "bag")], 2, "is the source dataset or lies inside it"),
             (["--out", str(tmp_path / "x.bag")], 2, "a ROS 2 bag is a folder"),
             (["--out", str(tmp_path / "x"), "--format", "ros1"], 2, "a ROS 1 bag is a file ending in .bag"),
             (["--out", str(tmp_path / "y"), "--frame-interval", "0"], 2, "--frame-interval: expected a finite")]
    for args, status, expected in cases:
        capsys.readouterr()
        assert omnisim_main(["export", str(dataset), "--no-progress", *args]) == status
        err = capsys.readouterr().err
        assert expected in err and len(err.strip().splitlines()) == 1, err
    assert sorted(os.listdir(existing)) == before
    assert not (dataset / "bag").exists() and not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_a_failed_export_leaves_nothing(dataset, tmp_path, capsys):
    broken = tmp_path / "broken"
    shutil.copytree(dataset, broken)
    (broken / "images" / "000003.png").write_bytes(b"\x89PNG\r\n\x1a\n damaged")
    assert omnisim_main(["export", str(broken), "--out", str(tmp_path / "out.bag"), "--format", "ros1",
                         "--no-progress"]) == 2
    assert "000003.png" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken"]
