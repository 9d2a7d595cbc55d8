"""Assertions for users' own test suites (pytest or any other runner).

Check an estimator's output against ground truth with a message that says
how far off it is, where, and by what bound::

    from ifmi.testing import assert_trajectory_close

    def test_my_estimator(dataset):
        est = run_my_estimator(dataset)            # a Trajectory, a TUM path or (N, 3, 3) R_0k
        assert_trajectory_close(dataset / "groundtruth.txt", est, rmse_rad=0.01)

Angles are radians; the error of a pose is the geodesic angle of
``R_gt^T R_est`` (as in ``ifmi evaluate``).
"""

from __future__ import annotations

import os

import numpy as np

from ifmi.evaluation.metrics import MIN_ASSOCIATED, EvaluationSummary, summary_from_errors, trajectory_errors
from ifmi.geometry.rotations import geodesic_angle
from ifmi.geometry.trajectory import Trajectory

__all__ = ["assert_rotation_close", "assert_trajectory_close"]

# Radians to degrees, for the second unit in failure messages.
_DEG = 180.0 / np.pi


def _rotations(value, name: str) -> np.ndarray:
    R = np.asarray(value, dtype=np.float64)
    if R.shape[-2:] != (3, 3) or R.ndim not in (2, 3):
        raise ValueError(f"expected {name} of shape (3, 3) or (N, 3, 3), got {R.shape}")
    return R


def assert_rotation_close(actual, desired, *, atol_rad: float = 1e-6, err_msg: str = "") -> None:
    """Assert that rotation matrices agree within a geodesic angle.

    Parameters
    ----------
    actual, desired : (3, 3) or (N, 3, 3) array_like
        Rotation matrices (broadcast against each other).
    atol_rad : float, keyword-only
        Largest accepted angle of ``desired^T actual``, radians.
    err_msg : str, keyword-only
        Prepended to the failure message.

    Raises
    ------
    AssertionError
        Naming how many rotations differ, the worst one's index and angle
        (radians and degrees) and the bound.
    """
    A, D = _rotations(actual, "actual"), _rotations(desired, "desired")
    angle = np.atleast_1d(geodesic_angle(D, A))
    bad = ~(angle <= atol_rad)  # NaN (a non-rotation) fails too
    if bad.any():
        worst = int(np.nanargmax(np.where(bad, np.nan_to_num(angle, nan=np.inf), -1.0)))
        where = f" at index {worst}" if angle.size > 1 else ""
        raise AssertionError(
            f"{err_msg + ': ' if err_msg else ''}{int(bad.sum())} of {angle.size} rotations differ "
            f"by more than {atol_rad:.3g} rad; worst{where}: {angle[worst]:.6g} rad "
            f"({angle[worst] * _DEG:.4g} deg)")


def _trajectory(value, name: str) -> Trajectory:
    if isinstance(value, Trajectory):
        return value
    if isinstance(value, (str, os.PathLike)):
        from ifmi.io.tum import read_tum

        return read_tum(value)
    R = _rotations(value, name)
    if R.ndim != 3:
        raise ValueError(f"expected {name} as (N, 3, 3) rotations R_0k, got {R.shape}")
    n = len(R)
    return Trajectory(np.arange(n, dtype=np.float64), np.zeros((n, 3)), R)


def assert_trajectory_close(gt, est, *, rmse_rad: float, max_rad: float | None = None,
                            min_matched: float = 1.0,
                            max_time_difference: float = 1e-3) -> EvaluationSummary:
    """Assert that an estimated trajectory's orientations are close to the ground truth's.

    Parameters
    ----------
    gt, est : Trajectory, path or (N, 3, 3) array_like
        A trajectory, a TUM file, or rotations ``R_0k`` (frame k at time k).
        Poses are associated by timestamp and compared from the first
        associated frame, as ``ifmi evaluate`` does
        (:func:`~ifmi.evaluation.metrics.trajectory_errors`).
    rmse_rad : float, keyword-only
        Largest accepted geodesic RMSE over the associated poses, radians.
    max_rad : float, optional, keyword-only
        Largest accepted geodesic error of any one pose, radians.
    min_matched : float, keyword-only
        Smallest fraction of the ground-truth poses that must have an
        estimate pose, and of the estimate poses that must have a
        ground-truth pose (default all of them); at least
        :data:`~ifmi.evaluation.metrics.MIN_ASSOCIATED` poses always.
    max_time_difference : float, keyword-only
        Largest timestamp difference of associated poses.

    Returns
    -------
    EvaluationSummary
        The statistics checked (for logging).

    Raises
    ------
    AssertionError
        Too few associated poses (of either trajectory), or an error over its bound; the message
        gives the measured value, the bound, and the worst pose's timestamp.
    """
    gt_t, est_t = _trajectory(gt, "gt"), _trajectory(est, "est")
    try:
        errors = trajectory_errors(gt_t, est_t, max_time_difference=max_time_difference)
    except ValueError as exc:
        raise AssertionError(f"trajectories do not overlap: {exc}") from None
    if len(errors) < min_matched * len(gt_t):
        raise AssertionError(f"only {len(errors)} of {len(gt_t)} ground-truth poses have an "
                             f"estimate pose (expected at least {min_matched:.0%})")
    if len(errors) < min_matched * len(est_t):
        raise AssertionError(f"only {len(errors)} of {len(est_t)} estimate poses have a "
                             f"ground-truth pose (expected at least {min_matched:.0%})")
    if len(errors) < MIN_ASSOCIATED:
        raise AssertionError(f"only {len(errors)} pose associated; expected at least {MIN_ASSOCIATED} "
                             "(an error over one pose measures nothing)")
    summary = summary_from_errors(errors, n_gt=len(gt_t), n_est=len(est_t))
    rmse, geodesic = summary.geodesic.rmse, errors.geodesic
    worst = int(np.nanargmax(geodesic)) if np.isfinite(geodesic).any() else 0
    detail = (f"over {len(errors)} poses; worst at timestamp {errors.timestamps[worst]:g}: "
              f"{geodesic[worst]:.6g} rad ({geodesic[worst] * _DEG:.4g} deg)")
    if not rmse <= rmse_rad:
        raise AssertionError(f"geodesic RMSE {rmse:.6g} rad ({rmse * _DEG:.4g} deg) > "
                             f"{rmse_rad:.6g} rad {detail}")
    if max_rad is not None and not summary.geodesic.max <= max_rad:
        raise AssertionError(f"largest geodesic error {summary.geodesic.max:.6g} rad > "
                             f"{max_rad:.6g} rad {detail}")
    return summary
