"""Ground truth from ROS bags: every pose message type, tf chains, evaluate --gt BAG, convert-gt."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.cli import main
from ifmi.errors import InputError
from ifmi.evaluation.trajectory_files import summary_of
from ifmi.io.bag_poses import read_bag_trajectory
from ifmi.io.bag_writer import BagWriter
from ifmi.io.tum import read_tum, write_tum
from ifmi.geometry.trajectory import Trajectory

SECOND_NS = 10 ** 9
POSE_TYPES = ("PoseStamped", "PoseWithCovarianceStamped", "TransformStamped", "Odometry")


def _trajectory(n: int, *, seed: int = 3, start: float = 100.0, step: float = 0.1) -> Trajectory:
    rng = np.random.default_rng(seed)
    rotations = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)).as_matrix()
    return Trajectory(timestamps=start + step * np.arange(n), positions=np.cumsum(rng.normal(0, 0.1, (n, 3)), 0),
                      rotations=rotations)


def _message(writer: BagWriter, kind: str, rotation, position, stamp_ns: int):
    """A message of ``kind`` holding the pose, in frame ``world`` (child ``camera``)."""
    if kind == "TransformStamped":
        return writer.transform_stamped(rotation, position, stamp_ns=stamp_ns, parent="world", child="camera")
    stamped = writer.pose_stamped(rotation, position, stamp_ns=stamp_ns, frame_id="world")
    if kind == "PoseStamped":
        return stamped
    types = writer.typestore.types
    with_covariance = types["geometry_msgs/msg/PoseWithCovariance"](pose=stamped.pose, covariance=np.zeros(36))
    if kind == "PoseWithCovarianceStamped":
        return types["geometry_msgs/msg/PoseWithCovarianceStamped"](header=stamped.header, pose=with_covariance)
    twist = types["geometry_msgs/msg/TwistWithCovariance"](
        twist=types["geometry_msgs/msg/Twist"](linear=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                               angular=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
        covariance=np.zeros(36))
    return types["nav_msgs/msg/Odometry"](header=stamped.header, child_frame_id="camera", pose=with_covariance,
                                          twist=twist)


def _write_poses(path, trajectory: Trajectory, *, kind="PoseStamped", bag_format="ros2", topic="/gt"):
    with BagWriter(path, bag_format=bag_format) as writer:
        for t, p, r in zip(trajectory.timestamps, trajectory.positions, trajectory.rotations):
            ns = int(round(t * SECOND_NS))
            writer.write(topic, _message(writer, kind, r, p, ns), ns)
    return path


def _assert_same(a: Trajectory, b: Trajectory) -> None:
    np.testing.assert_allclose(a.timestamps, b.timestamps, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.positions, b.positions, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.rotations, b.rotations, rtol=0, atol=1e-12)


@pytest.mark.parametrize("bag_format", ["ros1", "ros2"])
@pytest.mark.parametrize("kind", POSE_TYPES)
def test_every_pose_type_reads_back(tmp_path, kind, bag_format):
    truth = _trajectory(8)
    bag = _write_poses(tmp_path / ("gt.bag" if bag_format == "ros1" else "gt"), truth, kind=kind,
                       bag_format=bag_format)
    _assert_same(read_bag_trajectory(bag), truth)  # the only pose topic


def _write_tf_tree(path, truth: Trajectory, *, mount_rotation, mount_position):
    """world -> base on /tf at the truth's times (the camera's pose ``truth`` once the static
    base -> camera mount is applied), and world -> odom at other times, every 0.05 s."""
    with BagWriter(path, bag_format="ros2") as writer:
        mount = writer.transform_stamped(mount_rotation, mount_position, stamp_ns=0, parent="base", child="camera")
        writer.write("/tf_static", writer.tf_message([mount]), 1)
        for t, p, r in zip(truth.timestamps, truth.positions, truth.rotations):
            ns = int(round(t * SECOND_NS))
            base_rotation = r @ mount_rotation.T
            base_position = p - base_rotation @ mount_position
            transform = writer.transform_stamped(base_rotation, base_position, stamp_ns=ns, parent="world",
                                                 child="base")
            writer.write("/tf", writer.tf_message([transform]), ns)
        for t in np.arange(truth.timestamps[0] - 0.5, truth.timestamps[-1] + 0.5, 0.05):
            ns = int(round(t * SECOND_NS))
            odom = writer.transform_stamped(np.eye(3), np.array([1.0, 2.0, 3.0]), stamp_ns=ns, parent="world",
                                            child="odom")
            writer.write("/tf", writer.tf_message([odom]), ns)
    return path


def test_tf_chains_are_composed_and_inverted(tmp_path):
    truth = _trajectory(6)
    mount_rotation = Rotation.from_euler("xyz", [0.5, -0.2, 0.1]).as_matrix()
    bag = _write_tf_tree(tmp_path / "tf", truth, mount_rotation=mount_rotation, mount_position=np.array([0.1, 0, 0.2]))
    _assert_same(read_bag_trajectory(bag, topic="/tf", frames=("world", "camera")), truth)
    # The camera in odom crosses world: odom <- world (inverted) then world -> base -> camera.
    in_odom = read_bag_trajectory(bag, topic="/tf", frames=("odom", "camera"))
    np.testing.assert_allclose(in_odom.positions, truth.positions - [1.0, 2.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(in_odom.rotations, truth.rotations, atol=1e-12)
    inverse = read_bag_trajectory(bag, topic="/tf", frames=("camera", "world"))
    np.testing.assert_allclose(inverse.rotations, np.transpose(truth.rotations, (0, 2, 1)), atol=1e-12)


def test_tf_problems_are_one_line(tmp_path):
    truth = _trajectory(4)
    bag = _write_tf_tree(tmp_path / "tf", truth, mount_rotation=np.eye(3), mount_position=np.zeros(3))
    with pytest.raises(InputError, match="has 2 pose topics; choose one with --gt-topic"):
        read_bag_trajectory(bag)
    with pytest.raises(InputError, match="name the pose wanted with --gt-frames PARENT CHILD"):
        read_bag_trajectory(bag, topic="/tf")
    with pytest.raises(InputError, match=r"frame cam is not in the transforms \(frames: base, camera, odom, world\)"):
        read_bag_trajectory(bag, topic="/tf", frames=("world", "cam"))
    with pytest.raises(InputError, match="never change"):
        read_bag_trajectory(bag, topic="/tf", frames=("base", "camera"))
    poses = _write_poses(tmp_path / "poses", truth)
    with pytest.raises(InputError, match="--gt-frames is for a tf topic"):
        read_bag_trajectory(poses, frames=("world", "camera"))
    with pytest.raises(InputError, match="has no topic /odom"):
        read_bag_trajectory(poses, topic="/odom")


def _write_estimate(path, truth: Trajectory, *, seed: int = 9) -> None:
    """An estimate of ``truth`` re-based to its first pose, with small rotation errors."""
    rng = np.random.default_rng(seed)
    noise = Rotation.from_rotvec(rng.normal(0, 0.002, (len(truth), 3))).as_matrix()
    first = truth.rotations[0].T
    write_tum(path, Trajectory(timestamps=truth.timestamps, positions=np.zeros((len(truth), 3)),
                               rotations=first @ truth.rotations @ noise))


def _evaluate(args, capsys) -> dict:
    """The evaluation's summary as a flat ``{name: number or None}``."""
    assert main(["evaluate", *map(str, args), "--json"]) == 0
    return summary_of(json.loads(capsys.readouterr().out)).flat()


def test_evaluate_reads_bag_ground_truth_as_it_reads_a_tum_file(tmp_path, capsys):
    truth = _trajectory(10)
    write_tum(tmp_path / "gt.txt", truth)
    bag = _write_poses(tmp_path / "gt.bag", truth, kind="Odometry", bag_format="ros1", topic="/odom")
    _write_estimate(tmp_path / "est.txt", truth)
    from_tum = _evaluate(["--gt", tmp_path / "gt.txt", "--est", tmp_path / "est.txt", "--out", tmp_path / "a"],
                         capsys)
    from_bag = _evaluate(["--gt", bag, "--gt-topic", "/odom", "--est", tmp_path / "est.txt", "--out", tmp_path / "b"],
                         capsys)
    assert from_bag.keys() == from_tum.keys() and from_tum["rmse_geodesic_rad"] > 0
    for name, value in from_tum.items():  # the TUM file rounds poses to 12 decimals, the bag does not
        expected = None if value is None else pytest.approx(value, rel=1e-8, abs=1e-12, nan_ok=True)
        assert from_bag[name] == expected, name


def test_evaluate_refuses_too_few_matches_as_for_tum_files(tmp_path, capsys):
    truth = _trajectory(10)
    bag = _write_poses(tmp_path / "gt", Trajectory(truth.timestamps[:3], truth.positions[:3], truth.rotations[:3]))
    write_tum(tmp_path / "gt.txt", Trajectory(truth.timestamps[:3], truth.positions[:3], truth.rotations[:3]))
    _write_estimate(tmp_path / "est.txt", truth)
    errors = []
    for gt in (tmp_path / "gt.txt", bag):
        assert main(["evaluate", "--gt", str(gt), "--est", str(tmp_path / "est.txt"),
                     "--out", str(tmp_path / "e")]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1
        errors.append(err.replace(str(gt), "GT"))
    assert errors[0] == errors[1]


def test_gt_options_need_a_bag(tmp_path, capsys):
    truth = _trajectory(4)
    write_tum(tmp_path / "gt.txt", truth)
    assert main(["evaluate", "--gt", str(tmp_path / "gt.txt"), "--gt-topic", "/x", "--est",
                 str(tmp_path / "gt.txt")]) == 2
    assert "--gt-topic and --gt-frames are for a ROS bag" in capsys.readouterr().err


def test_convert_gt_writes_tum_and_refuses_to_replace(tmp_path, capsys):
    truth = _trajectory(7)
    bag = _write_poses(tmp_path / "gt", truth, kind="PoseWithCovarianceStamped")
    out = tmp_path / "gt.txt"
    assert main(["convert-gt", str(bag), "--out", str(out)]) == 0
    written = read_tum(out)  # TUM text: microsecond times, 9 decimals of position, 12 of quaternion
    np.testing.assert_allclose(written.timestamps, truth.timestamps, rtol=0, atol=1e-6)
    np.testing.assert_allclose(written.positions, truth.positions, rtol=0, atol=1e-9)
    np.testing.assert_allclose(written.rotations, truth.rotations, rtol=0, atol=1e-11)
    capsys.readouterr()
    assert main(["convert-gt", str(bag), "--out", str(out)]) == 1
    assert "exists already; --force replaces it" in capsys.readouterr().err
    assert main(["convert-gt", str(bag), "--out", str(out), "--force"]) == 0
    assert main(["convert-gt", str(bag), "--out", str(bag / "gt.txt")]) == 1
    assert "lies in it" in capsys.readouterr().err and not (bag / "gt.txt").exists()
    assert main(["convert-gt", str(bag), "--topic", "/tf", "--out", str(tmp_path / "x.txt")]) == 2
    assert "has no topic /tf" in capsys.readouterr().err
