"""Trajectory evaluation math: orientation and translation-direction errors.

Pure functions on :class:`ifmi.io.tum.Trajectory` objects and arrays; reading
and writing files lives in :mod:`ifmi.io.results`.

Conventions
-----------
* Both trajectories hold ``R_0k`` (camera k to camera 0); frame 0 is the
  identity in both, so no alignment is applied (as ``evo_ape`` without
  ``--align``).
* Per-axis error is the wrapped difference ``est - gt`` of roll, pitch and
  yaw (:func:`ifmi.geometry.rotations.rpy_from_matrix`), in radians.
* Geodesic error is the angle of ``R_gt^T R_est``; the relative error is the
  geodesic error of the motion between consecutive associated frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ifmi.geometry.trajectory import Trajectory
from ifmi.geometry.rotations import geodesic_angle, rpy_from_matrix, wrap_angle

__all__ = [
    "AXES",
    "MIN_ASSOCIATED",
    "MAX_POSITION",
    "ErrorStats",
    "TrajectoryErrors",
    "associate_timestamps",
    "error_stats",
    "trajectory_errors",
    "translation_direction_errors",
    "TimeStats",
    "EvaluationSummary",
    "summary_from_errors",
]

# Names of the per-axis angles, in the order rpy_from_matrix returns them.
AXES = ("roll", "pitch", "yaw")
# Fewest associated poses an evaluation accepts: one pose is a single sample, and when it is
# frame 0 (the identity in both trajectories) its errors are zero whatever the estimate.
MIN_ASSOCIATED = 2
# Largest position coordinate (any unit) the errors take: a quarter of the square root of the
# largest float, so that differences of positions, their squares and products of two such
# lengths (translation_direction_errors) stay finite.
MAX_POSITION = float(np.sqrt(np.finfo(np.float64).max)) / 4

# Translation lengths below this (in the ground truth's units) count as "no
# translation": the direction of such a motion is undefined.
MIN_TRANSLATION = 1e-9


@dataclass(frozen=True)
class ErrorStats:
    """Summary of a set of non-negative or signed errors (radians).

    Attributes
    ----------
    rmse : float
        Root mean square of the errors.
    mean : float
        Mean of the absolute errors.
    std : float
        Standard deviation of the absolute errors (population, ``ddof=0``).
    median : float
        Median of the absolute errors.
    max : float
        Largest absolute error.
    count : int
        Number of errors; all fields are NaN when it is zero.
    """

    rmse: float
    mean: float
    std: float
    median: float
    max: float
    count: int

    def to_dict(self) -> dict:
        return {"rmse": self.rmse, "mean": self.mean, "std": self.std,
                "median": self.median, "max": self.max, "count": self.count}


def error_stats(errors: np.ndarray) -> ErrorStats:
    """RMSE, mean, std, median and max of ``(N,)`` errors; NaN entries are ignored.

    Parameters
    ----------
    errors : (N,) array_like
        Signed or absolute errors in radians.

    Returns
    -------
    ErrorStats
    """
    e = np.asarray(errors, dtype=np.float64).ravel()
    e = e[np.isfinite(e)]
    if e.size == 0:
        nan = float("nan")
        return ErrorStats(nan, nan, nan, nan, nan, 0)
    a = np.abs(e)
    return ErrorStats(rmse=float(np.sqrt(np.mean(e * e))), mean=float(a.mean()),
                      std=float(a.std()), median=float(np.median(a)), max=float(a.max()),
                      count=int(e.size))


def associate_timestamps(t_gt: np.ndarray, t_est: np.ndarray, *,
                         max_difference: float) -> tuple[np.ndarray, np.ndarray]:
    """Pair each estimate timestamp with the nearest ground-truth timestamp.

    Parameters
    ----------
    t_gt : (M,) array_like
        Ground-truth timestamps (any order, unique).
    t_est : (N,) array_like
        Estimate timestamps.
    max_difference : float, keyword-only
        Largest accepted ``|t_gt - t_est|``, same unit as the timestamps.

    Returns
    -------
    index_gt, index_est : (K,) ndarray of int
        Indices of associated pairs, sorted by estimate time; every index
        appears at most once.
    """
    t_gt = np.asarray(t_gt, dtype=np.float64)
    t_est = np.asarray(t_est, dtype=np.float64)
    order = np.argsort(t_gt, kind="stable")
    sorted_gt = t_gt[order]
    pos = np.searchsorted(sorted_gt, t_est)
    lo = np.clip(pos - 1, 0, len(sorted_gt) - 1)
    hi = np.clip(pos, 0, len(sorted_gt) - 1)
    pick = np.where(np.abs(sorted_gt[lo] - t_est) <= np.abs(sorted_gt[hi] - t_est), lo, hi)
    diff = np.abs(sorted_gt[pick] - t_est)
    index_est = np.flatnonzero(diff <= max_difference)
    index_gt = order[pick[index_est]]
    # Keep the first estimate for a ground-truth pose matched twice.
    _, first = np.unique(index_gt, return_index=True)
    keep = np.sort(first)
    index_est = index_est[keep]
    index_gt = index_gt[keep]
    by_time = np.argsort(t_est[index_est], kind="stable")
    return index_gt[by_time], index_est[by_time]


def translation_direction_errors(gt: Trajectory, est: Trajectory,
                                 reference: np.ndarray) -> np.ndarray:
    """Angle between estimated and true translation direction of each frame pair.

    The motion of frame k is taken against frame ``reference[k]`` (the frame
    its relative pose was estimated against), expressed in the reference
    camera's coordinates: ``R_0r^T (p_k - p_r)``.

    Parameters
    ----------
    gt, est : Trajectory
        Associated trajectories of equal length N (row k of each is frame k).
    reference : (N,) array_like of int
        Row index of each frame's reference frame; negative or equal to k
        means "none".

    Returns
    -------
    (N,) ndarray
        Angles in radians; NaN where there is no reference, the true
        translation is shorter than ``MIN_TRANSLATION`` or the estimated
        translation is zero (unknown).
    """
    reference = np.asarray(reference, dtype=np.int64)
    n = len(gt)
    out = np.full(n, np.nan)
    k = np.flatnonzero((reference >= 0) & (reference < n) & (reference != np.arange(n)))
    if k.size == 0:
        return out
    r = reference[k]

    def local(traj: Trajectory) -> np.ndarray:
        d = traj.positions[k] - traj.positions[r]
        return np.einsum("nji,nj->ni", traj.rotations[r], d)

    t_gt = local(gt)
    t_est = local(est)
    n_gt = np.linalg.norm(t_gt, axis=1)
    n_est = np.linalg.norm(t_est, axis=1)
    scale = max(float(np.abs(gt.positions).max()), 1.0)
    valid = (n_gt > MIN_TRANSLATION * scale) & (n_est > 0)
    cos = np.einsum("ni,ni->n", t_gt[valid], t_est[valid]) / (n_gt[valid] * n_est[valid])
    sin = np.linalg.norm(np.cross(t_gt[valid], t_est[valid]), axis=1) / (n_gt[valid] * n_est[valid])
    out[k[valid]] = np.arctan2(sin, cos)
    return out


@dataclass(frozen=True)
class TrajectoryErrors:
    """Per-frame errors of an estimate against ground truth (radians).

    Attributes
    ----------
    timestamps : (N,) ndarray
        Estimate timestamps of the associated frames.
    gt_index, est_index : (N,) ndarray of int
        Rows of the associated poses in the input trajectories.
    rpy_gt, rpy_est : (N, 3) ndarray
        Roll, pitch, yaw of ground truth and estimate.
    rpy_error : (N, 3) ndarray
        Wrapped ``est - gt`` of roll, pitch, yaw.
    geodesic : (N,) ndarray
        Angle of ``R_gt^T R_est``.
    relative_geodesic : (N,) ndarray
        Error of the rotation from the previous associated frame to this
        one; NaN on the first frame.
    translation_direction : (N,) ndarray
        Translation-direction angle error against each frame's reference
        frame (see :func:`translation_direction_errors`); NaN where undefined.
    gt_origin_angle, est_origin_angle : float
        Angle (radians) of each trajectory's pose at the first associated
        frame from the identity, before both were re-based to that frame
        (see :func:`trajectory_errors`). Zero when both start at the first
        associated frame, as the file contract says.
    """

    timestamps: np.ndarray
    gt_index: np.ndarray
    est_index: np.ndarray
    rpy_gt: np.ndarray
    rpy_est: np.ndarray
    rpy_error: np.ndarray
    geodesic: np.ndarray
    relative_geodesic: np.ndarray
    translation_direction: np.ndarray
    gt_origin_angle: float = 0.0
    est_origin_angle: float = 0.0

    def __len__(self) -> int:
        return len(self.timestamps)

    def arrays(self) -> dict[str, np.ndarray]:
        """All per-frame arrays by name (the rpy arrays split per axis)."""
        out = {"timestamp": self.timestamps, "gt_index": self.gt_index,
               "est_index": self.est_index}
        for i, axis in enumerate(AXES):
            out[f"{axis}_gt"] = self.rpy_gt[:, i]
            out[f"{axis}_est"] = self.rpy_est[:, i]
            out[f"{axis}_error"] = self.rpy_error[:, i]
        out["geodesic_error"] = self.geodesic
        out["relative_geodesic_error"] = self.relative_geodesic
        out["translation_direction_error"] = self.translation_direction
        return out


def _reference_rows(reference_t: np.ndarray, timestamps: np.ndarray,
                   max_time_difference: float) -> np.ndarray:
    """Row of ``timestamps`` (sorted) at each reference time; -1 where none is within reach."""
    reference = np.full(len(reference_t), -1)
    finite = np.isfinite(reference_t)
    if finite.any():
        pos = np.clip(np.searchsorted(timestamps, reference_t[finite]), 0, len(timestamps) - 1)
        hit = np.abs(timestamps[pos] - reference_t[finite]) <= max_time_difference
        reference[np.flatnonzero(finite)[hit]] = pos[hit]
    return reference


def trajectory_errors(gt: Trajectory, est: Trajectory, *, max_time_difference: float = 1e-3,
                      reference_timestamps: np.ndarray | None = None) -> TrajectoryErrors:
    """Associate ``est`` with ``gt`` by timestamp and compute per-frame errors.

    Both trajectories are first re-based to their first associated frame f
    (``R_fk = R_0f^T R_0k``, positions likewise), so that an estimate that
    starts later than the ground truth (its first frames dropped) or ground
    truth given in a world frame is compared in one frame. With both files
    starting at the identity on the same frame, as the file contract says,
    this changes nothing; :attr:`TrajectoryErrors.gt_origin_angle` tells
    how far from it the ground truth was. Frame-to-frame and
    translation-direction errors do not depend on it.

    Parameters
    ----------
    gt, est : Trajectory
        Ground truth and estimate, ``R_0k`` (frame 0 the identity) or any
        common world frame.
    max_time_difference : float, keyword-only
        Largest timestamp difference accepted when associating frames.
    reference_timestamps : (len(est),) array_like, optional, keyword-only
        Timestamp of the frame each estimate pose's relative pose was
        estimated against (NaN for none); default: the previous frame.

    Returns
    -------
    TrajectoryErrors

    Raises
    ------
    ValueError
        When no frame associates.
    """
    gi, ei = associate_timestamps(gt.timestamps, est.timestamps,
                                  max_difference=max_time_difference)
    if gi.size == 0:
        raise ValueError(
            f"no estimate timestamp is within {max_time_difference} of a ground-truth timestamp "
            f"(ground truth {gt.timestamps.min():g}..{gt.timestamps.max():g}, "
            f"estimate {est.timestamps.min():g}..{est.timestamps.max():g})"
        )
    sub_gt = _rebased(Trajectory(gt.timestamps[gi], gt.positions[gi], gt.rotations[gi]))
    sub_est = _rebased(Trajectory(est.timestamps[ei], est.positions[ei], est.rotations[ei]))
    R_gt, R_est = sub_gt.rotations, sub_est.rotations
    rpy_gt = rpy_from_matrix(R_gt)
    rpy_est = rpy_from_matrix(R_est)
    rpy_error = wrap_angle(rpy_est - rpy_gt)
    geodesic = geodesic_angle(R_gt, R_est)
    relative = np.full(len(gi), np.nan)
    if len(gi) > 1:
        rel_gt = np.swapaxes(R_gt[:-1], -1, -2) @ R_gt[1:]
        rel_est = np.swapaxes(R_est[:-1], -1, -2) @ R_est[1:]
        relative[1:] = geodesic_angle(rel_gt, rel_est)
    if reference_timestamps is None:
        reference = np.arange(len(gi)) - 1
    else:
        reference = _reference_rows(np.asarray(reference_timestamps, dtype=np.float64)[ei],
                                    sub_est.timestamps, max_time_difference)
    translation = translation_direction_errors(sub_gt, sub_est, reference)
    return TrajectoryErrors(timestamps=est.timestamps[ei], gt_index=gi, est_index=ei,
                            rpy_gt=rpy_gt, rpy_est=rpy_est, rpy_error=rpy_error,
                            geodesic=geodesic, relative_geodesic=relative,
                            translation_direction=translation,
                            gt_origin_angle=float(geodesic_angle(gt.rotations[gi[0]], np.eye(3))),
                            est_origin_angle=float(geodesic_angle(est.rotations[ei[0]], np.eye(3))))


def _rebased(trajectory: Trajectory) -> Trajectory:
    """``trajectory`` expressed in the frame of its first pose: ``R_0^T R_k`` and ``R_0^T (p_k - p_0)``."""
    r0_inv = trajectory.rotations[0].T
    return Trajectory(trajectory.timestamps, (trajectory.positions - trajectory.positions[0]) @ r0_inv.T,
                      r0_inv @ trajectory.rotations)


@dataclass(frozen=True)
class TimeStats:
    """Wall time per frame of an estimate run (seconds).

    Only the frames whose time was recorded count: a run that records no
    time has no ``TimeStats`` (None, "unknown"), and one that records it for
    some frames has the statistics of those (``frames`` of them).

    Attributes
    ----------
    mean_s, median_s, total_s : float
        Over the frames with a recorded time.
    frames : int
        Frames with a recorded (finite) time, at least 1.
    """

    mean_s: float
    median_s: float
    total_s: float
    frames: int

    def to_dict(self) -> dict:
        return {"mean_s": self.mean_s, "median_s": self.median_s, "total_s": self.total_s,
                "frames": self.frames}


def _float_or_nan(value) -> float:
    """A number of a summary dict; JSON null (a NaN written out) reads as NaN."""
    return float("nan") if value is None else float(value)


def _stats_from_dict(data: dict) -> ErrorStats:
    numbers = (_float_or_nan(data.get(k)) for k in ("rmse", "mean", "std", "median", "max"))
    return ErrorStats(*numbers, count=int(data.get("count") or 0))


@dataclass(frozen=True)
class EvaluationSummary:
    """Summary statistics of an evaluation (Table-1 style), all angles in radians.

    Stored nested in ``evaluation.json`` (:meth:`to_dict`,
    :meth:`from_dict`); :meth:`flat` gives the one set of flat column names
    that sweep tables and report tables use.

    Attributes
    ----------
    roll, pitch, yaw : ErrorStats
        Per-axis errors (wrapped ``est - gt``).
    geodesic, relative_geodesic, translation_direction : ErrorStats
    frames_ground_truth, frames_estimate, frames_associated : int
        Poses in the ground-truth file, in the estimate file, and associated.
    failures : int or None
        Failed frames of the run (from its ``frames.csv``), None if unknown.
    failure_frames : int or None
        Frames of the run's ``frames.csv``.
    time : TimeStats or None
        Time per frame; None (unknown) without a ``frames.csv`` or when it
        records no time.
    """

    roll: ErrorStats
    pitch: ErrorStats
    yaw: ErrorStats
    geodesic: ErrorStats
    relative_geodesic: ErrorStats
    translation_direction: ErrorStats
    frames_ground_truth: int
    frames_estimate: int
    frames_associated: int
    failures: int | None = None
    failure_frames: int | None = None
    time: TimeStats | None = None

    @property
    def mean_rmse(self) -> float:
        """Mean of the roll, pitch and yaw RMSEs (radians)."""
        return float(np.mean([self.roll.rmse, self.pitch.rmse, self.yaw.rmse]))

    def axis(self, name: str) -> ErrorStats:
        """Errors of the axis ``name`` (one of :data:`AXES`)."""
        if name not in AXES:
            raise ValueError(f"expected an axis of {AXES}, got {name!r}")
        return getattr(self, name)

    def to_dict(self) -> dict:
        """Nested JSON-ready dict (the ``summary`` of ``evaluation.json``)."""
        return {
            "axes": {a: self.axis(a).to_dict() for a in AXES},
            "mean_rmse": self.mean_rmse,
            "geodesic": self.geodesic.to_dict(),
            "relative_geodesic": self.relative_geodesic.to_dict(),
            "translation_direction": self.translation_direction.to_dict(),
            "frames": {"ground_truth": self.frames_ground_truth, "estimate": self.frames_estimate,
                       "associated": self.frames_associated},
            "failures": None if self.failures is None else {"count": self.failures,
                                                            "frames": self.failure_frames},
            "time": None if self.time is None else self.time.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: dict) -> "EvaluationSummary":
        """Inverse of :meth:`to_dict` (JSON nulls read as NaN).

        A ``time`` without a mean (an unknown time stored as NaN before
        unknown times were stored as null) reads as None, unknown.
        """
        failures, time = data.get("failures"), data.get("time")
        frames = data["frames"]
        return cls(
            **{a: _stats_from_dict(data["axes"][a]) for a in AXES},
            geodesic=_stats_from_dict(data["geodesic"]),
            relative_geodesic=_stats_from_dict(data["relative_geodesic"]),
            translation_direction=_stats_from_dict(data["translation_direction"]),
            frames_ground_truth=int(frames["ground_truth"]), frames_estimate=int(frames["estimate"]),
            frames_associated=int(frames["associated"]),
            failures=None if failures is None else int(failures["count"]),
            failure_frames=None if failures is None else int(failures["frames"]),
            time=None if time is None or time.get("mean_s") is None else TimeStats(
                *(_float_or_nan(time.get(k)) for k in ("mean_s", "median_s", "total_s")),
                frames=int(time["frames"])),
        )

    def flat(self) -> dict:
        """One row of named scalars; the column names of sweep and report tables.

        Returns
        -------
        dict
            ``rmse_<axis>_rad``, ``mean_<axis>_rad``, ``std_<axis>_rad`` per
            axis, ``rmse_mean_rad``, ``rmse_geodesic_rad``,
            ``max_geodesic_rad``, ``rmse_relative_rad``,
            ``mean_translation_direction_rad``, ``time_per_frame_s`` (None if
            unknown), ``failures`` (None if unknown), ``frames`` (poses in
            the estimate) and ``associated``.
        """
        row = {}
        for a in AXES:
            stats = self.axis(a)
            row.update({f"rmse_{a}_rad": stats.rmse, f"mean_{a}_rad": stats.mean,
                        f"std_{a}_rad": stats.std})
        row.update({
            "rmse_mean_rad": self.mean_rmse,
            "rmse_geodesic_rad": self.geodesic.rmse,
            "max_geodesic_rad": self.geodesic.max,
            "rmse_relative_rad": self.relative_geodesic.rmse,
            "mean_translation_direction_rad": self.translation_direction.mean,
            "time_per_frame_s": None if self.time is None else self.time.mean_s,
            "failures": self.failures,
            "frames": self.frames_estimate,
            "associated": self.frames_associated,
        })
        return row


def summary_from_errors(errors: TrajectoryErrors, *, n_gt: int, n_est: int,
                        frame_success: np.ndarray | None = None,
                        frame_seconds: np.ndarray | None = None) -> EvaluationSummary:
    """Summary statistics of per-frame errors (Table-1 style).

    Parameters
    ----------
    errors : TrajectoryErrors
    n_gt, n_est : int, keyword-only
        Number of poses in the ground-truth and estimate files.
    frame_success : (F,) array_like of bool, optional, keyword-only
        Per-frame success flags of the estimate run.
    frame_seconds : (F,) array_like, optional, keyword-only
        Per-frame wall time of the estimate run (seconds); NaN where it was
        not recorded. The time statistics are over the recorded frames, and
        ``time`` is None (unknown) when no frame has one.

    Returns
    -------
    EvaluationSummary
    """
    failures = failure_frames = time = None
    if frame_success is not None:
        ok = np.asarray(frame_success, dtype=bool)
        failures, failure_frames = int((~ok).sum()), int(ok.size)
    seconds = np.asarray([] if frame_seconds is None else frame_seconds, dtype=np.float64)
    s = seconds[np.isfinite(seconds)]
    if s.size > 0:
        time = TimeStats(mean_s=float(s.mean()), median_s=float(np.median(s)),
                         total_s=float(s.sum()), frames=int(s.size))
    return EvaluationSummary(
        **{axis: error_stats(errors.rpy_error[:, i]) for i, axis in enumerate(AXES)},
        geodesic=error_stats(errors.geodesic),
        relative_geodesic=error_stats(errors.relative_geodesic),
        translation_direction=error_stats(errors.translation_direction),
        frames_ground_truth=int(n_gt), frames_estimate=int(n_est),
        frames_associated=int(len(errors)), failures=failures, failure_frames=failure_frames,
        time=time)
