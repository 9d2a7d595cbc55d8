"""The Python API: estimate a sequence, evaluate it, read a calibration.

Everything here is re-exported by :mod:`ifmi` (``ifmi.estimate``,
``ifmi.evaluate``, ...) and is what ``ifmi estimate`` and ``ifmi evaluate``
call, so a notebook and the command line run the same code::

    import ifmi
    result = ifmi.estimate("data/office")                 # a dataset folder
    result.write("office_ifmi.txt")                       # as ``ifmi estimate --out`` writes it
    errors = ifmi.evaluate("data/office/groundtruth.txt", result)
    print(errors.ate_rad)
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ifmi.errors import InputError
from ifmi.evaluation.trajectory_files import EvaluateOptions, evaluate_files_with_errors, evaluate_trajectories, read_and_evaluate
from ifmi.io.camera_file import read_camera
from ifmi.io.results import EstimateSideFiles, FrameTable, write_estimate_run
from ifmi.io.tum import read_tum
from ifmi.evaluation.metrics import AXES, ErrorStats, EvaluationSummary
from ifmi.pipeline import EstimateConfig, SequenceEstimate, estimate_bag, estimate_dataset, estimate_sequence, estimate_video
from ifmi.geometry.trajectory import Trajectory

__all__ = ["Estimate", "Evaluation", "estimate", "evaluate", "read_calibration"]


def read_calibration(path: str | os.PathLike):
    """Camera model of a calibration file.

    Parameters
    ----------
    path : path
        OCamCalib ``calib_results.txt`` (any name not ending in ``.yaml``)
        or a Kalibr camchain ``camera.yaml`` (``.yaml``/``.yml``; the
        ``omni``, ``eucm``, ``ds`` and ``pinhole`` models).

    Returns
    -------
    OcamModel or a Kalibr camera model
        Maps pixels (row, col) to unit rays and back
        (:func:`ifmi.geometry.camera.rays_from_pixels`).

    Raises
    ------
    InputError
        A missing or malformed file, naming it and the problem.
    """
    return read_camera(Path(path))


@dataclass(frozen=True)
class Estimate:
    """The orientation of every frame of a sequence, as :func:`estimate` returns it.

    Attributes
    ----------
    timestamps : (N,) ndarray
        Frame indices of a dataset folder or a list of images; seconds from
        the first frame of a video.
    rotations : (N, 3, 3) ndarray
        ``R_0k``: maps camera-k directions to camera-0 directions; frame 0
        is the identity.
    positions : (N, 3) ndarray
        Camera-k origin in camera-0 coordinates, up to scale (zero for a
        rotation-only model).
    frames : tuple of ifmi.tracking.odometry.FrameRecord
        One record per frame (the rows of ``frames.csv``).
    method : str
        Front end that produced it.
    config : EstimateConfig
        The configuration used, with the values derived from the camera
        and frames filled in.
    dataset : Path or None
        The dataset folder it came from, None for a video or a list of
        images.
    sources : dict
        Inputs recorded in ``NAME.config.json`` when written (``video``,
        ``calib`` of a video run).
    """

    timestamps: np.ndarray
    rotations: np.ndarray
    positions: np.ndarray
    frames: tuple
    method: str
    config: EstimateConfig
    dataset: Path | None = None
    sources: dict = field(default_factory=dict)

    @property
    def trajectory(self) -> Trajectory:
        """The poses as a :class:`~ifmi.geometry.trajectory.Trajectory`."""
        return Trajectory(timestamps=self.timestamps, positions=self.positions, rotations=self.rotations)

    @property
    def failed(self) -> int:
        """Number of frames that failed (each keeps the previous orientation)."""
        return sum(not record.success for record in self.frames)

    def least_certain_frame(self) -> tuple[int, float] | None:
        """``(frame, rotation_sigma_rad)`` of the frame whose rotation the fit predicts least
        accurately (radians), or None (:meth:`ifmi.pipeline.SequenceEstimate.least_certain_frame`)."""
        return self.sequence_estimate().least_certain_frame()

    def table(self):
        """The per-frame table (the columns of ``frames.csv``) as a :class:`pandas.DataFrame`."""
        import pandas as pd

        return pd.DataFrame([record.to_row() for record in self.frames])

    def sequence_estimate(self) -> SequenceEstimate:
        """The same result as the pipeline's :class:`~ifmi.pipeline.SequenceEstimate`."""
        return SequenceEstimate(trajectory=self.trajectory, frames=self.frames, config=self.config,
                                method=self.method)

    def write(self, path: str | os.PathLike, *, extra: dict | None = None, input_files: tuple = (),
              overwrite: bool = False) -> Path:
        """Write ``path`` (TUM) with ``NAME.frames.csv`` and ``NAME.config.json`` beside it,
        exactly as ``ifmi estimate --out path`` does, as one set.

        Parameters
        ----------
        path : path
            The TUM file to write.
        extra : dict, optional, keyword-only
            More entries for ``NAME.config.json``.
        input_files : tuple of path, keyword-only
            Files no output may replace (the dataset's own files are always protected).
        overwrite : bool, keyword-only
            Also replace existing files at those paths that no estimate wrote.

        Returns
        -------
        Path
            ``path``.

        Raises
        ------
        OutputError
            An output would replace an input or a file no estimate wrote, or
            could not be written.
        """
        return write_estimate_run(path, self.sequence_estimate(), dataset_dir=self.dataset,
                                  extra={**self.sources, **(extra or {})}, input_files=input_files,
                                  overwrite=overwrite)


def _from_sequence(result: SequenceEstimate, *, dataset=None, sources=None) -> Estimate:
    trajectory = result.trajectory
    return Estimate(timestamps=trajectory.timestamps, rotations=trajectory.rotations,
                    positions=trajectory.positions, frames=result.frames, method=result.method,
                    config=result.config, dataset=dataset, sources=dict(sources or {}))


def _estimate_from_bag(bag, calib, *, topic, method: str, config: EstimateConfig, progress: bool) -> Estimate:
    """:func:`estimate` of one image topic of a ROS bag (the topic checked before the calibration)."""
    from ifmi.io.bags import BagFrames

    if calib is None:
        raise InputError(bag, "a ROS bag needs calib (calib_results.txt or camera.yaml)")
    topic = BagFrames(bag, topic=topic).topic
    result = estimate_bag(bag, calib, topic=topic, method=method, config=config, progress=progress)
    sources = {"bag": str(Path(bag).resolve()), "topic": topic, "calib": str(Path(calib).resolve())}
    return _from_sequence(result, sources=sources)


def _images_from(items: Sequence, model) -> list:
    """Arrays as given; paths read at the calibration's size (gray)."""
    from ifmi.io.dataset import read_image

    return [item if isinstance(item, np.ndarray) else read_image(Path(item), size=model.size)
            for item in items]


def estimate(dataset, method: str = "ifmi", config: EstimateConfig | None = None, *,
             calib=None, topic: str | None = None, progress: bool = False) -> Estimate:
    """Estimate the camera orientation of every frame of a sequence.

    Parameters
    ----------
    dataset : path or sequence
        A dataset folder (``calib_results.txt`` or ``camera.yaml``, and
        ``images/``), a video file (``.mp4``, ``.avi``, ...; needs
        ``calib``), a ROS bag (a ROS 1 ``.bag``, a ROS 2 bag folder or a
        ``.mcap`` file; needs ``calib``), or a sequence of images ((H, W) or
        (H, W, 3) uint8 arrays, or image paths) in frame order (needs ``calib``).
    method : str
        A front end that ``ifmi methods`` lists (``"ifmi"``, ``"orb"``,
        ``"akaze"``, plugins) or ``"package.module:factory"``.
    config : EstimateConfig, optional
        Every option of the run; default :class:`~ifmi.pipeline.EstimateConfig`'s.
    calib : path or camera model, keyword-only
        Calibration of a video, a bag or a list of images. A dataset folder
        uses its own.
    topic : str, optional, keyword-only
        The image topic of a bag; default its only image topic.
    progress : bool, keyword-only
        Show a progress bar on stderr.

    Returns
    -------
    Estimate

    Raises
    ------
    InputError
        A missing or malformed dataset, video, calibration or image, or a
        configuration the camera cannot take; one line naming the file.
    """
    from ifmi.io.bags import is_bag_path
    from ifmi.io.video import is_video_path

    config = EstimateConfig() if config is None else config
    if topic is not None and not (isinstance(dataset, (str, os.PathLike)) and is_bag_path(dataset)):
        raise InputError(topic, "topic is for a ROS bag; the input is not one")
    if isinstance(dataset, (str, os.PathLike)):
        if is_bag_path(dataset):
            return _estimate_from_bag(dataset, calib, topic=topic, method=method, config=config,
                                      progress=progress)
        if is_video_path(dataset):
            if calib is None:
                raise InputError(dataset, "a video needs calib (calib_results.txt or camera.yaml)")
            result = estimate_video(dataset, calib, method=method, config=config, progress=progress)
            sources = {"video": str(Path(dataset).resolve()), "calib": str(Path(calib).resolve())}
            return _from_sequence(result, sources=sources)
        if calib is not None:
            raise InputError(calib, "a dataset folder is estimated with its own calibration; drop calib")
        result = estimate_dataset(dataset, method=method, config=config, progress=progress)
        return _from_sequence(result, dataset=Path(dataset))
    if calib is None:
        raise InputError("images", "a list of images needs calib (a path or a camera model)")
    model = read_calibration(calib) if isinstance(calib, (str, os.PathLike)) else calib
    images = _images_from(list(dataset), model)
    if len(images) < 2:
        raise InputError("images", f"expected at least 2 images, got {len(images)}")
    result = estimate_sequence(images, model, method=method, config=config, progress=progress)
    return _from_sequence(result)


@dataclass(frozen=True)
class Evaluation:
    """Errors of an estimate against ground truth, as :func:`evaluate` returns them.

    Attributes
    ----------
    summary : ifmi.evaluation.metrics.EvaluationSummary
        Every statistic ``ifmi evaluate`` prints (radians).
    per_frame : dict of str -> (N,) ndarray
        Per associated frame: ``timestamp``, ``roll_error``, ``pitch_error``,
        ``yaw_error``, ``geodesic_error``, ... (radians; the columns of
        ``per_frame.csv``).
    meta : dict
        The content of ``evaluation.json``.
    path : Path or None
        The evaluation folder written, None when none was.
    """

    summary: EvaluationSummary
    per_frame: dict
    meta: dict
    path: Path | None = None

    @property
    def ate_rad(self) -> float:
        """Geodesic absolute trajectory error, RMSE over the associated frames (radians)."""
        return self.summary.geodesic.rmse

    @property
    def rmse_rad(self) -> dict:
        """Per-axis RMSE, ``{"roll": ..., "pitch": ..., "yaw": ...}`` (radians)."""
        return {axis: self.summary.axis(axis).rmse for axis in AXES}

    def axis(self, name: str) -> ErrorStats:
        """RMSE, mean, std and max of one axis (``"roll"``, ``"pitch"`` or ``"yaw"``; radians)."""
        return self.summary.axis(name)

    def table(self) -> str:
        """The plain-text table ``ifmi evaluate`` prints."""
        from ifmi.evaluation.trajectory_files import format_summary_table

        return format_summary_table(self.meta)


def _trajectory_of(value, what: str) -> tuple[Trajectory, Any]:
    """``(trajectory, frames)`` of an :class:`Estimate`, a trajectory or a sequence with one."""
    if isinstance(value, Estimate):
        return value.trajectory, value.frames
    if isinstance(value, Trajectory):
        return value, None
    trajectory = getattr(value, "trajectory", None)
    if isinstance(trajectory, Trajectory):
        return trajectory, getattr(value, "frames", None)
    raise InputError(what, f"expected a TUM file path, an Estimate or a Trajectory, got {type(value).__name__}")


def _frame_table(records) -> FrameTable | None:
    """The frames.csv columns of ``records`` (as :func:`ifmi.io.results.read_frames_csv` reads them)."""
    if not records:
        return None
    rows = [record.to_row() for record in records]
    columns = {}
    for name in rows[0]:
        values = [row.get(name) for row in rows]
        if name == "success":
            columns[name] = np.asarray(values, dtype=bool)
        elif all(isinstance(v, (int, float, np.number)) and not isinstance(v, bool) for v in values):
            columns[name] = np.asarray(values, dtype=np.float64)
        else:
            columns[name] = np.asarray(values, dtype=object)
    return FrameTable(columns=columns)


def evaluate(ground_truth, estimate, *, out=None, options: EvaluateOptions | None = None,
             gt_topic: str | None = None, gt_frames: tuple[str, str] | None = None) -> Evaluation:
    """Errors of an estimate against ground truth (what ``ifmi evaluate`` prints and saves).

    Poses are associated by timestamp and both trajectories re-based to the
    first associated frame; then the per-axis roll/pitch/yaw errors, the
    geodesic error of every frame and of every frame-to-frame step, and the
    translation-direction error are summarised.

    Parameters
    ----------
    ground_truth : path or Trajectory
        A TUM file (``groundtruth.txt`` of a dataset), a ROS bag with a pose,
        odometry or tf topic, or a trajectory.
    estimate : path, Estimate or Trajectory
        A TUM file written by ``ifmi estimate`` (its ``frames.csv`` adds
        failures and time per frame), an :class:`Estimate`, or a trajectory.
    out : path or True, optional, keyword-only
        Write the evaluation folder (``evaluation.json``, ``per_frame.csv``,
        ...) here; ``True`` writes ``NAME.eval/`` beside an estimate file.
        Default: nothing is written. Needs both inputs to be files.
    options : EvaluateOptions, optional, keyword-only
        Association tolerance and the fraction of poses that must match.
    gt_topic : str, optional, keyword-only
        The ground-truth topic of a bag (default its only pose topic).
    gt_frames : (str, str), optional, keyword-only
        ``(parent, child)`` frames of the pose read from a bag's ``/tf``.

    Returns
    -------
    Evaluation

    Raises
    ------
    InputError
        Missing or malformed files, too few associated poses.
    OutputError
        ``out`` cannot be written.
    """
    options = EvaluateOptions() if options is None else options
    files = all(isinstance(v, (str, os.PathLike)) for v in (ground_truth, estimate))
    if out is not None:
        if not files:
            raise InputError("out", "writing an evaluation folder needs the ground truth and the "
                                    "estimate as files (Estimate.write saves an estimate)")
        meta, errors = evaluate_files_with_errors(ground_truth, estimate, options=options,
                                                  out_dir=None if out is True else out,
                                                  gt_topic=gt_topic, gt_frames=gt_frames)
        return _evaluation(meta, errors)
    if files:
        meta, errors, _ = read_and_evaluate(ground_truth, estimate, options=options, gt_topic=gt_topic,
                                            gt_frames=gt_frames)
        return _evaluation(meta, errors)
    gt, gt_name, from_bag = _ground_truth_input(ground_truth, topic=gt_topic, frames=gt_frames)
    est, est_name, side = _estimate_input(estimate)
    meta, errors = evaluate_trajectories(gt, est, side=side, gt_path=gt_name, est_path=est_name,
                                         options=options, warn_if_rebased=not from_bag)
    return _evaluation(meta, errors)


def _evaluation(meta: dict, errors) -> Evaluation:
    path = meta.get("path")
    return Evaluation(summary=EvaluationSummary.from_dict(meta["summary"]), per_frame=errors.arrays(),
                      meta=meta, path=None if path is None else Path(path))


def _ground_truth_input(ground_truth, *, topic: str | None, frames) -> tuple[Trajectory, Path, bool]:
    """``(trajectory, name in messages, read from a bag)`` of a TUM file, a bag or a trajectory."""
    from ifmi.io.bag_poses import read_bag_trajectory
    from ifmi.io.bags import is_bag_path

    if isinstance(ground_truth, (str, os.PathLike)):
        if topic is not None or frames is not None or is_bag_path(ground_truth):
            return read_bag_trajectory(ground_truth, topic=topic, frames=frames), Path(ground_truth), True
        return read_tum(ground_truth), Path(ground_truth), False
    if topic is not None or frames is not None:
        raise InputError("ground truth", "gt_topic and gt_frames are for a bag; the ground truth is a trajectory")
    return _trajectory_of(ground_truth, "ground truth")[0], Path("ground truth"), False


def _estimate_input(estimate) -> tuple[Trajectory, Path, EstimateSideFiles]:
    """``(trajectory, name in messages, side files)`` of a TUM file, an Estimate or a trajectory."""
    from ifmi.io.results import read_estimate_side_files

    if isinstance(estimate, (str, os.PathLike)):
        return read_tum(estimate), Path(estimate), read_estimate_side_files(estimate)
    est, records = _trajectory_of(estimate, "estimate")
    dataset = getattr(estimate, "dataset", None)
    config = {"method": getattr(estimate, "method", "unknown"),
              "dataset": None if dataset is None else str(dataset)}
    side = EstimateSideFiles(frames=_frame_table(records), config=config,
                             frames_path=Path("estimate frames"), config_path=Path("estimate config"))
    return est, Path("estimate"), side
