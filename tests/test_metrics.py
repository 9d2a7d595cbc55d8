"""Evaluation math against exact synthetic trajectories and against evo."""

from __future__ import annotations

import numpy as np
import pytest

from ifmi.io.tum import Trajectory, write_tum
from ifmi.evaluation.metrics import (associate_timestamps, error_stats, summary_from_errors,
                          trajectory_errors, translation_direction_errors)
from ifmi.geometry.rotations import matrix_from_rpy


def _axis_rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.asarray(angle, dtype=float)[..., None, None]
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * (K @ K)


def _gt(n: int = 40, seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    rpy = np.cumsum(rng.normal(scale=0.03, size=(n, 3)), axis=0)
    rpy[0] = 0.0
    positions = np.cumsum(rng.normal(scale=0.1, size=(n, 3)), axis=0)
    positions[0] = 0.0
    return Trajectory(np.arange(n, dtype=float), positions, matrix_from_rpy(rpy))


def test_error_stats_exact_values():
    st = error_stats(np.array([3.0, -4.0, np.nan]))
    assert st.count == 2
    assert st.rmse == pytest.approx(np.sqrt(12.5))
    assert st.mean == pytest.approx(3.5)
    assert st.std == pytest.approx(0.5)
    assert st.max == pytest.approx(4.0)
    empty = error_stats(np.array([]))
    assert empty.count == 0 and np.isnan(empty.rmse)


def test_per_axis_errors_are_the_applied_offsets():
    gt = _gt()
    rpy_gt = np.array([[0.0, 0.0, 0.0]] + [[0.1 * k, -0.05 * k, 0.2 * k] for k in range(1, 40)])
    rpy_gt = np.clip(rpy_gt, -1.2, 1.2)
    gt = Trajectory(gt.timestamps, gt.positions, matrix_from_rpy(rpy_gt))
    rng = np.random.default_rng(1)
    offset = rng.uniform(-0.05, 0.05, size=(40, 3))
    offset[0] = 0.0  # both trajectories start at the identity (the file contract)
    est = Trajectory(gt.timestamps, gt.positions, matrix_from_rpy(rpy_gt + offset))
    err = trajectory_errors(gt, est)
    np.testing.assert_allclose(err.rpy_error, offset, atol=1e-12)
    summary = summary_from_errors(err, n_gt=40, n_est=40).to_dict()
    for i, axis in enumerate(("roll", "pitch", "yaw")):
        assert summary["axes"][axis]["rmse"] == pytest.approx(np.sqrt(np.mean(offset[:, i] ** 2)))
        assert summary["axes"][axis]["mean"] == pytest.approx(np.mean(np.abs(offset[:, i])))
        assert summary["axes"][axis]["std"] == pytest.approx(np.std(np.abs(offset[:, i])))


def test_yaw_error_wraps_across_pi():
    rpy_gt = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, np.pi - 0.01]])
    rpy_est = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -np.pi + 0.02]])
    gt = Trajectory(np.arange(2.0), np.zeros((2, 3)), matrix_from_rpy(rpy_gt))
    est = Trajectory(np.arange(2.0), np.zeros((2, 3)), matrix_from_rpy(rpy_est))
    err = trajectory_errors(gt, est)
    assert err.rpy_error[1, 2] == pytest.approx(0.03, abs=1e-12)
    assert err.geodesic[1] == pytest.approx(0.03, abs=1e-12)


def test_geodesic_and_relative_errors():
    gt = _gt()
    angles = np.zeros(40)
    angles[10:] = 0.02  # one frame-to-frame error at frame 10, carried on after
    angles[25:] = 0.05  # another of 0.03 at frame 25
    est_R = _axis_rotation([0.3, -0.2, 0.9], angles) @ gt.rotations  # error in the world frame
    est = Trajectory(gt.timestamps, gt.positions, est_R)
    err = trajectory_errors(gt, est)
    np.testing.assert_allclose(err.geodesic, angles, atol=1e-12)
    expected_rel = np.zeros(40)
    expected_rel[10], expected_rel[25] = 0.02, 0.03
    assert np.isnan(err.relative_geodesic[0])
    np.testing.assert_allclose(err.relative_geodesic[1:], expected_rel[1:], atol=1e-9)


def test_ground_truth_in_a_world_frame_is_rebased_to_the_first_frame():
    gt = _gt()
    world_from_0 = _axis_rotation([0.2, 0.9, -0.4], 2.5)
    p0 = np.array([3.0, -1.0, 1.6])
    gt_world = Trajectory(gt.timestamps, p0 + gt.positions @ world_from_0.T, world_from_0 @ gt.rotations)
    angles = np.linspace(0.0, 0.04, 40)
    est = Trajectory(gt.timestamps, gt.positions, _axis_rotation([0.3, -0.2, 0.9], angles) @ gt.rotations)
    err = trajectory_errors(gt_world, est)
    np.testing.assert_allclose(err.geodesic, angles, atol=1e-12)
    np.testing.assert_allclose(err.rpy_error, trajectory_errors(gt, est).rpy_error, atol=1e-12)
    assert err.gt_origin_angle == pytest.approx(2.5, abs=1e-12)
    assert err.est_origin_angle == 0.0


def test_estimate_starting_later_is_compared_from_its_first_frame():
    gt = _gt()
    first = 12
    later = Trajectory(gt.timestamps[first:], gt.positions[first:], gt.rotations[first].T @ gt.rotations[first:])
    err = trajectory_errors(gt, later)
    assert err.gt_origin_angle > 0.05
    np.testing.assert_allclose(err.geodesic, 0.0, atol=1e-12)
    np.testing.assert_allclose(err.relative_geodesic[1:], 0.0, atol=1e-12)


def test_association_by_timestamp_drops_unmatched_and_reorders():
    t_gt = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    t_est = np.array([4.0, 1.0005, 2.5, 0.0])
    gi, ei = associate_timestamps(t_gt, t_est, max_difference=1e-3)
    np.testing.assert_array_equal(gi, [0, 1, 4])
    np.testing.assert_array_equal(ei, [3, 1, 0])


def test_no_common_timestamps_is_an_error():
    gt = _gt(5)
    est = Trajectory(gt.timestamps + 100.0, gt.positions, gt.rotations)
    with pytest.raises(ValueError, match="no estimate timestamp"):
        trajectory_errors(gt, est)


def test_translation_direction_error_known_angle():
    n = 6
    gt_pos = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0]], float)
    R = matrix_from_rpy(np.tile([0.0, 0.0, 0.3], (n, 1)))
    R[0] = np.eye(3)
    gt = Trajectory(np.arange(n, dtype=float), gt_pos, R)
    # Estimate: same rotations, each step's direction rotated by 0.1 rad about
    # the reference camera's z axis, scale arbitrary.
    est_pos = np.zeros((n, 3))
    rot = _axis_rotation([0, 0, 1], 0.1)
    for k in range(1, n):
        step_local = R[k - 1].T @ (gt_pos[k] - gt_pos[k - 1])
        est_pos[k] = est_pos[k - 1] + 2.5 * (R[k - 1] @ (rot @ step_local))
    est = Trajectory(gt.timestamps, est_pos, R)
    err = translation_direction_errors(gt, est, np.arange(n) - 1)
    assert np.isnan(err[0])
    assert np.isnan(err[3])  # no true motion from frame 2 to 3
    np.testing.assert_allclose(err[[1, 2, 4, 5]], 0.1, atol=1e-12)


def test_geodesic_matches_evo_ape(tmp_path):
    evo_metrics = pytest.importorskip("evo.core.metrics")
    from evo.core import sync
    from evo.tools import file_interface

    gt = _gt(60, seed=3)
    rng = np.random.default_rng(4)
    noise = np.cumsum(rng.normal(scale=0.01, size=60))
    axes = rng.normal(size=(60, 3))
    # The estimate's first pose is off too: both are compared from their first frame, which is evo's
    # APE after align_origin.
    est_R = np.stack([gt.rotations[k] @ _axis_rotation(axes[k], noise[k]) for k in range(60)])
    # Same files for both: small timestamp jitter and two frames missing from the estimate.
    keep = np.setdiff1d(np.arange(60), [7, 31])
    est = Trajectory(gt.timestamps[keep] + 1e-5, gt.positions[keep], est_R[keep])
    write_tum(tmp_path / "gt.txt", gt)
    write_tum(tmp_path / "est.txt", est)
    from ifmi.io.tum import read_tum

    ours = trajectory_errors(read_tum(tmp_path / "gt.txt"), read_tum(tmp_path / "est.txt"))
    assert len(ours) == 58
    summary = summary_from_errors(ours, n_gt=60, n_est=58).to_dict()

    traj_ref = file_interface.read_tum_trajectory_file(str(tmp_path / "gt.txt"))
    traj_est = file_interface.read_tum_trajectory_file(str(tmp_path / "est.txt"))
    traj_ref, traj_est = sync.associate_trajectories(traj_ref, traj_est, max_diff=1e-3)
    traj_est.align_origin(traj_ref)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.rotation_angle_rad)
    ape.process_data((traj_ref, traj_est))
    stats = ape.get_all_statistics()
    assert summary["geodesic"]["rmse"] == pytest.approx(stats["rmse"], abs=1e-9)
    assert summary["geodesic"]["mean"] == pytest.approx(stats["mean"], abs=1e-9)
    assert summary["geodesic"]["max"] == pytest.approx(stats["max"], abs=1e-9)
    assert summary["geodesic"]["std"] == pytest.approx(stats["std"], abs=1e-9)
    # Frame-to-frame rotation error against evo's RPE (delta of one associated frame).
    rpe = evo_metrics.RPE(evo_metrics.PoseRelation.rotation_angle_rad, delta=1,
                          delta_unit=evo_metrics.Unit.frames, all_pairs=False)
    rpe.process_data((traj_ref, traj_est))
    rpe_stats = rpe.get_all_statistics()
    assert summary["relative_geodesic"]["rmse"] == pytest.approx(rpe_stats["rmse"], abs=1e-9)
    assert summary["relative_geodesic"]["max"] == pytest.approx(rpe_stats["max"], abs=1e-9)
