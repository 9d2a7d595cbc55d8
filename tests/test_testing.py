"""ifmi.testing: the assertions pass on close data and fail with a useful message otherwise."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.io.tum import write_tum
from ifmi.geometry.rotations import matrix_from_rpy
from ifmi.testing import assert_rotation_close, assert_trajectory_close
from ifmi.geometry.trajectory import Trajectory


def _perturbed(R, angles, rng):
    """``R`` turned by ``angles`` (radians) about random axes."""
    axes = rng.normal(size=(len(R), 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return R @ Rotation.from_rotvec(axes * np.asarray(angles)[:, None]).as_matrix()


def test_rotation_close_passes_within_tolerance(rng, assert_rotation_close):
    R = Rotation.random(5, random_state=1).as_matrix()
    assert_rotation_close(_perturbed(R, np.full(5, 0.9e-3), rng), R, atol_rad=1e-3)
    assert_rotation_close(R[0], R[0])


def test_rotation_close_fails_naming_the_worst(rng):
    R = Rotation.random(5, random_state=2).as_matrix()
    angles = np.array([1e-4, 1e-4, 3e-3, 1e-4, 2e-3])
    with pytest.raises(AssertionError, match=r"^pose check: 2 of 5 rotations differ by more than "
                                             r"0.001 rad; worst at index 2: 0.003 rad \(0.1719 deg\)$"):
        assert_rotation_close(_perturbed(R, angles, rng), R, atol_rad=1e-3, err_msg="pose check")


def test_rotation_close_rejects_non_rotation_shapes():
    with pytest.raises(ValueError, match=r"expected actual of shape \(3, 3\) or \(N, 3, 3\), got \(4,\)"):
        assert_rotation_close(np.zeros(4), np.eye(3))


def test_rotation_close_fails_on_nan():
    with pytest.raises(AssertionError, match="1 of 1 rotations differ"):
        assert_rotation_close(np.full((3, 3), np.nan), np.eye(3))


def _trajectories(rng, n=20, error=0.002):
    rpy = np.column_stack([np.zeros(n), np.zeros(n), np.linspace(0, 0.5, n)])
    gt = Trajectory(np.arange(n, dtype=float), np.zeros((n, 3)), matrix_from_rpy(rpy))
    errors = np.full(n, error)
    errors[0] = 0.0  # both start at the identity on frame 0 (the file contract)
    est = Trajectory(gt.timestamps, gt.positions, _perturbed(gt.rotations, errors, rng))
    return gt, est


def test_trajectory_close_passes_for_objects_files_and_arrays(rng, tmp_path):
    gt, est = _trajectories(rng)
    summary = assert_trajectory_close(gt, est, rmse_rad=0.0021, max_rad=0.0021)
    assert summary.geodesic.rmse == pytest.approx(0.002 * np.sqrt(19 / 20), rel=1e-9)
    write_tum(tmp_path / "gt.txt", gt)
    assert_trajectory_close(tmp_path / "gt.txt", est.rotations, rmse_rad=0.0021)


def test_trajectory_close_fails_with_measured_value_and_worst_pose(rng):
    gt, est = _trajectories(rng)
    R = est.rotations.copy()
    R[7] = _perturbed(gt.rotations[7:8], [0.05], rng)[0]
    est = Trajectory(est.timestamps, est.positions, R)
    # RMSE = sqrt((18 * 0.002^2 + 0.05^2) / 20) = 0.01134 rad.
    with pytest.raises(AssertionError, match=r"geodesic RMSE 0.0113402 rad \(0.6497 deg\) > 0.01 rad "
                                             r"over 20 poses; worst at timestamp 7: 0.05 rad"):
        assert_trajectory_close(gt, est, rmse_rad=0.01)
    with pytest.raises(AssertionError, match=r"largest geodesic error 0.05 rad > 0.02 rad"):
        assert_trajectory_close(gt, est, rmse_rad=0.1, max_rad=0.02)


def test_trajectory_close_fails_on_missing_poses(rng):
    gt, est = _trajectories(rng)
    short = Trajectory(est.timestamps[:15], est.positions[:15], est.rotations[:15])
    with pytest.raises(AssertionError, match=r"only 15 of 20 ground-truth poses have an estimate"):
        assert_trajectory_close(gt, short, rmse_rad=0.01)
    assert_trajectory_close(gt, short, rmse_rad=0.01, min_matched=0.75)
    # An estimate with poses the ground truth does not have fails the same way.
    with pytest.raises(AssertionError, match=r"only 15 of 20 estimate poses have a ground-truth pose"):
        assert_trajectory_close(Trajectory(gt.timestamps[:15], gt.positions[:15], gt.rotations[:15]), est,
                                rmse_rad=0.01)
    one = Trajectory(gt.timestamps[:1], gt.positions[:1], gt.rotations[:1])
    with pytest.raises(AssertionError, match=r"only 1 pose associated; expected at least 2"):
        assert_trajectory_close(one, Trajectory(est.timestamps[:1], est.positions[:1], est.rotations[:1]),
                                rmse_rad=0.01)
    shifted = Trajectory(est.timestamps + 100, est.positions, est.rotations)
    with pytest.raises(AssertionError, match="trajectories do not overlap"):
        assert_trajectory_close(gt, shifted, rmse_rad=0.01)
