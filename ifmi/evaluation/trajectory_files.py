"""Evaluate an estimate run against ground truth and save the result as files.

Reads the TUM files and the run's side files, computes the errors of
:mod:`ifmi.evaluation.metrics` and writes an evaluation folder
(:func:`ifmi.io.results.write_evaluation`).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ifmi.evaluation.dataset_names import display_name
from ifmi.errors import InputError, InputWarning, OutputError
from ifmi.io.dataset import dataset_meta, refuse_output_in_datasets
from ifmi.io.results import EstimateSideFiles, jsonable, read_estimate_side_files, write_evaluation
from ifmi.io.bag_poses import read_bag_trajectory
from ifmi.io.bags import is_bag_path
from ifmi.io.tum import read_tum
from ifmi.evaluation.metrics import (AXES, MAX_POSITION, MIN_ASSOCIATED, EvaluationSummary, TrajectoryErrors,
                                    summary_from_errors, trajectory_errors)
from ifmi.geometry.trajectory import Trajectory

__all__ = ["EvaluateOptions", "GateVerdict", "MIN_ASSOCIATED", "default_evaluation_dir",
           "evaluate_files", "evaluate_files_with_errors", "evaluate_trajectories",
           "read_and_evaluate", "format_summary_table", "dataset_label", "dataset_provenance",
           "gate_verdict", "summary_of"]


@dataclass(frozen=True)
class EvaluateOptions:
    """Options of an evaluation.

    Attributes
    ----------
    max_time_difference : float
        Largest timestamp difference (timestamp units, frames or seconds)
        for two poses to be associated; finite, >= 0.
    min_matched : float
        Smallest fraction of the ground-truth poses that must be associated
        with an estimate pose, and of the estimate poses that must be
        associated with a ground-truth pose; fewer is an error, not a
        summary of a few frames. In [0, 1]. Whatever it is, at least
        :data:`MIN_ASSOCIATED` poses must be associated.
    origin_tolerance_rad : float
        The trajectories are compared re-based to their first associated
        frame (:func:`~ifmi.evaluation.metrics.trajectory_errors`); a ground-truth
        pose there further than this from the identity (radians, > 0; the
        default allows quaternions written with five decimals) is reported
        with a warning, since it means the files do not start on the same
        frame.
    """

    max_time_difference: float = 1e-3
    min_matched: float = 0.5
    origin_tolerance_rad: float = 1e-5

    def __post_init__(self) -> None:
        if not 0 <= self.max_time_difference < np.inf:
            raise ValueError(f"expected max_time_difference finite and >= 0, got {self.max_time_difference}")
        if not 0 <= self.min_matched <= 1:
            raise ValueError(f"expected min_matched in [0, 1], got {self.min_matched}")
        if not self.origin_tolerance_rad > 0:
            raise ValueError(f"expected origin_tolerance_rad > 0, got {self.origin_tolerance_rad}")

    def to_dict(self) -> dict:
        return {"max_time_difference": self.max_time_difference, "min_matched": self.min_matched}


def default_evaluation_dir(estimate_path: str | os.PathLike) -> Path:
    """``DIR/NAME.eval`` for the estimate ``DIR/NAME.txt``."""
    p = Path(estimate_path)
    return p.with_name((p.stem if p.suffix else p.name) + ".eval")


def dataset_label(dataset_dir: str | os.PathLike | None) -> tuple[str, str]:
    """``(dataset, scene)`` names of a dataset folder.

    The dataset name is the folder name; the scene is the ``scene_name`` (or
    ``scene``: a string, or a mapping with ``name``) entry of its
    ``meta.json`` when present, otherwise the dataset name. Bytes of a
    folder name that are not UTF-8 show as U+FFFD
    (:func:`~ifmi.evaluation.dataset_names.display_name`).
    """
    if dataset_dir is None:
        return "unknown", "unknown"
    folder = Path(dataset_dir)
    name = folder.name or str(folder)
    scene = name
    meta = dataset_meta(folder) or {}
    value = meta.get("scene_name") or meta.get("scene")
    if isinstance(value, dict):
        value = value.get("name")
    if isinstance(value, str) and value:
        scene = Path(value).stem
    return display_name(name), display_name(scene)


# Entries of a dataset's meta.json carried into evaluations (provenance shown in reports).
DATASET_META_KEYS = ("scene_name", "frames", "resolution", "spp", "seed", "variant")
# Below this, the printed tables and the verdict line show an error with significant digits, not
# four decimals: a sharp 1024 px sequence's 1e-5 rad would read 0.0000.
_FIXED_DECIMALS_MIN = 1e-3


def dataset_provenance(dataset_dir: str | os.PathLike | None) -> dict:
    """Selected ``meta.json`` entries of a dataset folder (empty when unavailable)."""
    meta = None if dataset_dir is None else dataset_meta(dataset_dir)
    return {} if meta is None else {k: meta[k] for k in DATASET_META_KEYS if k in meta}


def _check_unique_timestamps(path: Path, trajectory: Trajectory) -> None:
    values, counts = np.unique(trajectory.timestamps, return_counts=True)
    if np.any(counts > 1):
        first = int(np.argmax(counts > 1))
        raise InputError(path, f"duplicate timestamp {values[first]:g} ({counts[first]} poses); "
                               "expected one pose per timestamp")


def _check_side_files(est_path: Path, est: Trajectory, side: EstimateSideFiles) -> None:
    """The side files must belong to this trajectory: one frames.csv row per pose and frame."""
    if side.frames is None:
        return
    if len(side.frames) != len(est):
        raise InputError(side.frames_path, f"{len(side.frames)} frames, but {est_path.name} has "
                                           f"{len(est)} poses; the estimate and its side files "
                                           "come from different runs")
    values, counts = np.unique(side.frames.frame, return_counts=True)
    if np.any(counts > 1):
        first = int(np.argmax(counts > 1))
        raise InputError(side.frames_path, f"frame {values[first]} on {counts[first]} rows; "
                                           "expected one row per frame (reference frames are "
                                           "found by frame number)")


def _reference_timestamps(est: Trajectory, side: EstimateSideFiles) -> np.ndarray | None:
    """Timestamp of the frame each pose was estimated against (NaN: none), from frames.csv."""
    frames = side.frames
    if frames is None or frames.reference_frame is None or len(frames) != len(est):
        return None
    # Row i of frames.csv is pose i of the estimate file; reference_frame holds
    # frame indices (file-name integers, which may have gaps), not row numbers.
    ref_frames = np.asarray(frames.reference_frame, dtype=np.float64)
    ok = np.isfinite(ref_frames) & (ref_frames >= 0)
    reference_t = np.full(len(est), np.nan)
    row_of_frame = {int(f): i for i, f in enumerate(frames.frame)}
    for i in np.flatnonzero(ok):
        j = row_of_frame.get(int(ref_frames[i]))
        if j is not None and j != i:
            reference_t[i] = est.timestamps[j]
    return reference_t


def _check_matched(gt_path: Path, est_path: Path, n_matched: int, n_gt: int, n_est: int,
                   options: EvaluateOptions) -> None:
    """Enough associated poses: ``min_matched`` of each file's, and :data:`MIN_ASSOCIATED`."""
    within = f"within {options.max_time_difference:g}"
    bar = f"(expected at least {options.min_matched:.0%}; --min-matched lowers the bar)"
    if n_matched < options.min_matched * n_gt:
        raise InputError(est_path, f"only {n_matched} of {n_gt} ground-truth poses have an "
                                   f"estimate pose {within} {bar}")
    if n_matched < options.min_matched * n_est:
        raise InputError(gt_path, f"only {n_matched} of {n_est} poses of {est_path.name} have a "
                                  f"ground-truth pose {within} {bar}")
    if n_matched < MIN_ASSOCIATED:
        # Name the file with fewer poses: that is the one that falls short.
        path, other = (gt_path, est_path) if n_gt < n_est else (est_path, gt_path)
        raise InputError(path, f"only {n_matched} pose associated with {other.name} ({within}); "
                               f"expected at least {MIN_ASSOCIATED} (an error over one pose "
                               "measures nothing)")


def _check_positions(path: Path, trajectory: Trajectory) -> None:
    """Refuse a position coordinate beyond :data:`~ifmi.evaluation.metrics.MAX_POSITION` (errors would overflow)."""
    largest = np.abs(trajectory.positions).max(axis=1)
    if largest.max() > MAX_POSITION:
        k = int(np.argmax(largest > MAX_POSITION))
        value = trajectory.positions[k][np.argmax(np.abs(trajectory.positions[k]))]
        raise InputError(path, f"pose at timestamp {trajectory.timestamps[k]:g}: position coordinate "
                               f"{value:g} out of range; expected at most {MAX_POSITION:.4g} in magnitude")


def _refuse_same_file(gt_path: Path, est_path: Path) -> None:
    """Refuse an estimate that is the ground-truth file itself (its errors would all be 0)."""
    try:
        same = os.path.samefile(gt_path, est_path)
    except OSError:  # both were just read; a file that went meanwhile is not the same
        same = False
    if same:
        raise InputError(est_path, f"is the ground-truth file {gt_path} itself (every error would be 0); "
                                   "expected an estimate")


def _warn_if_rebased(gt_path: Path, est_path: Path, errors, options: EvaluateOptions) -> None:
    """Warn when the ground truth is not the identity at the first associated frame (re-based there)."""
    if errors.gt_origin_angle <= options.origin_tolerance_rad:
        return
    warnings.warn(f"{gt_path}: the pose at {est_path.name}'s first associated timestamp "
                  f"{errors.timestamps[0]:g} is {errors.gt_origin_angle:.4g} rad from the identity, "
                  "so the two files do not start on the same frame; both are compared re-based to "
                  "that frame (right for an estimate that starts later, or ground truth in a world "
                  "frame; wrong if the estimate numbers its frames differently, e.g. from 1)",
                  InputWarning, stacklevel=3)


def _resolved_name(path: Path) -> str:
    """The absolute path of an input file; the name as given of one held in memory (no file)."""
    return str(path.resolve()) if path.exists() else str(path)


def _run_meta(gt_path: Path, est_path: Path, side: EstimateSideFiles, summary: EvaluationSummary,
              options: EvaluateOptions) -> dict:
    config = side.config or {}
    dataset_dir = config.get("dataset") or str(gt_path.parent)
    dataset, scene = dataset_label(dataset_dir)
    return {
        "summary": summary.to_dict(),
        "method": config.get("method", "unknown"),
        "dataset": dataset,
        "scene": scene,
        "dataset_path": str(dataset_dir),
        "dataset_meta": dataset_provenance(dataset_dir),
        "groundtruth_path": _resolved_name(gt_path),
        "estimate_path": _resolved_name(est_path),
        "options": options.to_dict(),
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }


def evaluate_files(gt_path: str | os.PathLike, est_path: str | os.PathLike, *,
                   out_dir: str | os.PathLike | None = None,
                   options: EvaluateOptions = EvaluateOptions(),
                   gt_topic: str | None = None, gt_frames: tuple[str, str] | None = None) -> dict:
    """Evaluate ``est_path`` against ``gt_path`` and write an evaluation folder.

    Only reads the trajectories and the estimate's side files; nothing is
    estimated again.

    Parameters
    ----------
    gt_path, est_path : path
        TUM trajectory files (``R_0k``, frame 0 the identity).
    out_dir : path, optional, keyword-only
        Output folder. Default: :func:`default_evaluation_dir` of
        ``est_path``, written if it can be; if not (a read-only folder, a
        file of that name), a warning says so and ``path`` is None.
    options : EvaluateOptions, keyword-only
    gt_topic : str, optional, keyword-only
        With a ROS bag as ``gt_path``: its pose, odometry or tf topic
        (:func:`ifmi.io.bag_poses.read_bag_trajectory`; default its only
        one). Such ground truth is in its own world frame, so its not
        starting at the identity is expected and not warned of.
    gt_frames : (str, str), optional, keyword-only
        ``(parent, child)`` of the pose read from a tf topic.

    Returns
    -------
    dict
        The content of ``evaluation.json`` (``summary`` holds the statistics,
        :func:`summary_of` reads them back typed) and ``path``.

    Raises
    ------
    InputError
        Missing or malformed input files, the estimate being the ground-truth
        file itself, a position coordinate beyond
        :data:`~ifmi.evaluation.metrics.MAX_POSITION`, duplicate timestamps, side files
        that do not belong to the estimate, fewer associated poses than
        ``options.min_matched`` of the ground truth's or of the estimate's,
        or fewer than :data:`MIN_ASSOCIATED`.
    OutputError
        The ``out_dir`` given cannot be written.
    """
    return evaluate_files_with_errors(gt_path, est_path, out_dir=out_dir, options=options,
                                      gt_topic=gt_topic, gt_frames=gt_frames)[0]


def evaluate_files_with_errors(gt_path: str | os.PathLike, est_path: str | os.PathLike, *,
                               out_dir: str | os.PathLike | None = None,
                               options: EvaluateOptions = EvaluateOptions(), gt_topic: str | None = None,
                               gt_frames: tuple[str, str] | None = None) -> tuple[dict, TrajectoryErrors]:
    """:func:`evaluate_files`'s result and the per-frame errors it wrote."""
    gt_path, est_path = Path(gt_path), Path(est_path)
    meta, errors, side = read_and_evaluate(gt_path, est_path, options=options, gt_topic=gt_topic,
                                           gt_frames=gt_frames)
    out = Path(out_dir) if out_dir is not None else default_evaluation_dir(est_path)
    _refuse_dataset_output(out, gt_path, side)
    try:
        write_evaluation(out, meta=meta, arrays=errors.arrays(), side_files=side)
    except OSError as exc:  # OutputError, or e.g. the folder cannot be made: a regular file in the way
        error = OutputError.from_os_error(out, exc)
        if out_dir is not None:
            raise error from None
        # The default folder is a convenience: the result still stands (and a gate's verdict with it).
        warnings.warn(f"{error}; the evaluation is not saved (--out chooses a folder)", InputWarning,
                      stacklevel=3)
        out = None
    meta = jsonable(meta)
    meta["path"] = None if out is None else str(out)
    return meta, errors


def read_and_evaluate(gt_path: str | os.PathLike, est_path: str | os.PathLike, *,
                      options: EvaluateOptions = EvaluateOptions(), gt_topic: str | None = None,
                      gt_frames: tuple[str, str] | None = None
                      ) -> tuple[dict, TrajectoryErrors, EstimateSideFiles]:
    """Read the ground truth (a TUM file or a ROS bag), the estimate's TUM file and side files, and
    evaluate them, writing nothing: ``(meta, errors, side files)``; raises as :func:`evaluate_files`."""
    gt_path, est_path = Path(gt_path), Path(est_path)
    from_bag = gt_topic is not None or gt_frames is not None or is_bag_path(gt_path)
    gt = read_bag_trajectory(gt_path, topic=gt_topic, frames=gt_frames) if from_bag else read_tum(gt_path)
    est = read_tum(est_path)
    _refuse_same_file(gt_path, est_path)
    side = read_estimate_side_files(est_path)
    meta, errors = evaluate_trajectories(gt, est, side=side, gt_path=gt_path, est_path=est_path,
                                         options=options, warn_if_rebased=not from_bag)
    return meta, errors, side


def evaluate_trajectories(gt: Trajectory, est: Trajectory, *, side: EstimateSideFiles, gt_path: Path,
                          est_path: Path, options: EvaluateOptions = EvaluateOptions(),
                          warn_if_rebased: bool = True) -> tuple[dict, TrajectoryErrors]:
    """The evaluation of two trajectories in memory: ``(meta, errors)``, nothing written.

    ``meta`` is what ``evaluation.json`` holds; ``gt_path`` and ``est_path``
    name the inputs in messages and in ``meta``; ``side`` holds the
    estimate's per-frame records (failures, time) and configuration. With
    ``warn_if_rebased``, ground truth that does not start at the identity is
    warned of (a bag's ground truth lies in its own world frame: no warning).

    Raises
    ------
    InputError
        As :func:`evaluate_files`, for the checks of the poses themselves.
    """
    _check_positions(gt_path, gt)
    _check_positions(est_path, est)
    _check_unique_timestamps(gt_path, gt)
    _check_unique_timestamps(est_path, est)
    _check_side_files(est_path, est, side)
    try:
        errors = trajectory_errors(gt, est, max_time_difference=options.max_time_difference,
                                   reference_timestamps=_reference_timestamps(est, side))
    except ValueError as exc:
        raise InputError(est_path, str(exc)) from None
    _check_matched(gt_path, est_path, len(errors), len(gt), len(est), options)
    if warn_if_rebased:
        _warn_if_rebased(gt_path, est_path, errors, options)
    frames = side.frames
    summary = summary_from_errors(errors, n_gt=len(gt), n_est=len(est),
                                  frame_success=None if frames is None else frames.success,
                                  frame_seconds=None if frames is None else frames.seconds)
    meta = _run_meta(gt_path, est_path, side, summary, options)
    meta["origin"] = {"timestamp": float(errors.timestamps[0]),
                      "groundtruth_angle_rad": errors.gt_origin_angle,
                      "estimate_angle_rad": errors.est_origin_angle}
    meta["per_frame_columns"] = list(errors.arrays())
    return meta, errors


def _refuse_dataset_output(out: Path, gt_path: Path, side: EstimateSideFiles) -> None:
    """The evaluation folder must not lie in a data folder (``images/``, ...) of the dataset the
    ground truth sits in or the estimate's config names: it would add entries to the frames."""
    named = (side.config or {}).get("dataset")
    refuse_output_in_datasets(out, [gt_path.parent, *([Path(named)] if isinstance(named, str) else [])])


def summary_of(meta: dict) -> EvaluationSummary:
    """The typed summary of an evaluation (``evaluate_files``'s result or ``evaluation.json``)."""
    return EvaluationSummary.from_dict(meta["summary"])


@dataclass(frozen=True)
class GateVerdict:
    """Outcome of a pass/fail check of an evaluation (``ifmi evaluate --max-rmse``).

    Attributes
    ----------
    passed : bool
    line : str
        One line, ``PASS: ...`` or ``FAIL: ...``, with the measured values and bounds.
    """

    passed: bool
    line: str


def gate_verdict(summary: EvaluationSummary, *, max_rmse_rad: float,
                 max_failed: int | None = None) -> GateVerdict:
    """Check the geodesic RMSE (and the failed-frame count) against bounds.

    Parameters
    ----------
    summary : EvaluationSummary
    max_rmse_rad : float, keyword-only
        Largest accepted geodesic RMSE (radians); a NaN RMSE fails.
    max_failed : int, optional, keyword-only
        Largest accepted number of failed frames; needs the run's
        ``frames.csv`` (``summary.failures``).

    Returns
    -------
    GateVerdict

    Raises
    ------
    ValueError
        ``max_failed`` given but the failed-frame count is unknown.
    """
    rmse = summary.geodesic.rmse
    rmse_ok = bool(np.isfinite(rmse) and rmse <= max_rmse_rad)
    parts = [f"geodesic RMSE {_gate_angle(rmse)} rad {'<=' if rmse_ok else '>'} {_gate_angle(max_rmse_rad)} rad"]
    failed_ok = True
    if max_failed is not None:
        if summary.failures is None:
            raise ValueError("the failed-frame count is unknown (no frames.csv beside the "
                             "estimate); expected one for --max-failed")
        failed_ok = summary.failures <= max_failed
        parts.append(f"{summary.failures} failed frames {'<=' if failed_ok else '>'} {max_failed}")
    elif summary.failures is not None:
        parts.append(f"{summary.failures} failed frames")
    passed = rmse_ok and failed_ok
    return GateVerdict(passed, ("PASS: " if passed else "FAIL: ") + ", ".join(parts))


def _gate_angle(value: float) -> str:
    """An angle of the verdict line: four decimals, or four significant digits below 1e-3 rad."""
    return f"{value:.4f}" if not abs(value) < _FIXED_DECIMALS_MIN else f"{value:.3e}"


def _fmt(v, scale: float = 1.0, digits: int = 4) -> str:
    if v is None or not np.isfinite(v):
        return "n/a"
    value = v * scale
    if 0 < abs(value) < _FIXED_DECIMALS_MIN:
        return f"{value:.2e}"  # fixed decimals would print 0.0000
    return f"{value:.{digits}f}"


def format_summary_table(meta: dict) -> str:
    """Readable plain-text table of an evaluation summary (radians and degrees)."""
    s = summary_of(meta)
    deg = 180.0 / np.pi
    lines = [f"method {meta.get('method')}  dataset {meta.get('dataset')}  "
             f"frames {s.frames_associated}/{s.frames_ground_truth} associated",
             f"{'error':<24}{'RMSE rad':>10}{'mean rad':>10}{'std rad':>10}{'max rad':>10}"
             f"{'RMSE deg':>10}"]

    def row(name, st):
        lines.append(f"{name:<24}{_fmt(st.rmse):>10}{_fmt(st.mean):>10}{_fmt(st.std):>10}"
                     f"{_fmt(st.max):>10}{_fmt(st.rmse, deg, 3):>10}")

    for axis in AXES:
        row(axis, s.axis(axis))
    lines.append(f"{'mean of roll/pitch/yaw':<24}{_fmt(s.mean_rmse):>10}")
    row("geodesic", s.geodesic)
    row("relative (per frame)", s.relative_geodesic)
    row("translation direction", s.translation_direction)
    if s.failures is not None:
        lines.append(f"failed frames: {s.failures} of {s.failure_frames}")
    lines += _time_lines(s)
    return "\n".join(lines)


def _time_lines(s: EvaluationSummary) -> list[str]:
    """The time-per-frame line of the table: the statistics, or unknown when frames.csv has none."""
    if s.time is None:
        return [] if s.failures is None else ["time per frame: unknown (the run's frames.csv "
                                              "records no time)"]
    line = (f"time per frame: {_fmt(s.time.mean_s, 1e3, 2)} ms mean, "
            f"{_fmt(s.time.median_s, 1e3, 2)} ms median")
    if s.failure_frames is not None and s.time.frames < s.failure_frames:
        line += f" (over the {s.time.frames} of {s.failure_frames} frames with a recorded time)"
    return [line]
