"""Estimation pipeline: a sequence, dataset folder, video or bag in, an estimate out, for any method.

A method's front end (:mod:`ifmi.front_end`) turns images into ray
correspondences; the relative-pose back end (:mod:`ifmi.backend.relative_pose`) and
the trajectory chaining (:mod:`ifmi.tracking.odometry`) are shared by every method, so
comparisons isolate the front end. Methods are found by name
(:mod:`ifmi.tracking.methods`: built in, installed plugins, or
``package.module:factory``); a factory receives the camera model and the
whole :class:`EstimateConfig` and reads the part that concerns it
(``config.ifmi`` for ``"ifmi"``, ``config.features`` for the feature
baselines).
"""

from __future__ import annotations

import os
import sys
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from tqdm import tqdm

from ifmi.geometry.camera import OcamModel
from ifmi.spectral.config_limits import check_config_for_model
from ifmi.errors import CalibrationFitError, InputError, InputWarning
from ifmi.front_end import Correspondences, FrontEnd
from ifmi.config import EstimateConfig
from ifmi.tracking.methods import create_front_end, method_names
from ifmi.geometry.trajectory import Trajectory
from ifmi.tracking.odometry import FrameRecord, track_sequence
from ifmi.runtime.blas_threads import single_blas_thread
from ifmi.spectral.panorama import angular_pixel_size_in_band

__all__ = [
    "Correspondences",
    "FrontEnd",
    "EstimateConfig",
    "SequenceEstimate",
    "FrameRecord",
    "method_names",
    "create_front_end",
    "estimate_sequence",
    "estimate_dataset",
    "estimate_video",
    "estimate_bag",
    "resolved_config",
    "check_config_for_model",
]


@dataclass(frozen=True)
class SequenceEstimate:
    """Result of :func:`estimate_sequence`.

    Attributes
    ----------
    trajectory : Trajectory
        ``R_0k`` per frame (translation up to scale), frame 0 the identity.
    frames : tuple of FrameRecord
        One record per frame (frame 0 included, as the reference of itself).
    config : EstimateConfig
    method : str
    """

    trajectory: Trajectory
    frames: tuple
    config: EstimateConfig
    method: str

    def least_certain_frame(self) -> tuple[int, float] | None:
        """``(frame, rotation_sigma_rad)`` of the successful frame whose rotation the fit predicts
        least accurately (:attr:`ifmi.tracking.odometry.FrameRecord.rotation_sigma_rad`, radians), or None
        when no frame has a finite prediction. ``frame`` is the record's frame index."""
        known = [(r.rotation_sigma_rad, r.frame) for r in self.frames
                 if r.success and np.isfinite(r.rotation_sigma_rad)]
        if not known:
            return None
        sigma, frame = max(known)
        return frame, sigma




def resolved_config(config: EstimateConfig, model: OcamModel) -> EstimateConfig:
    """``config`` with the relative-pose threshold in radians for ``model``.

    An explicit ``relative_pose.ransac_threshold_rad`` is kept; otherwise
    ``relative_pose.ransac_threshold_px`` is converted with
    :func:`ifmi.spectral.panorama.angular_pixel_size_in_band` of the calibration (band from
    ``config.ifmi.panorama``), so the same pixel threshold serves every
    image resolution and every method.
    """
    pose = config.relative_pose
    if pose.ransac_threshold_rad is not None:
        return config
    pixel = angular_pixel_size_in_band(model, config=config.ifmi.panorama)
    return replace(config, relative_pose=pose.resolved(pixel))


def estimate_sequence(images: Iterable[np.ndarray], model: OcamModel, *, method: str,
                      config: EstimateConfig = EstimateConfig(), progress: bool = False,
                      total: int | None = None,
                      timestamps: Sequence[float] | None = None) -> SequenceEstimate:
    """Estimate the orientation of every frame of a sequence.

    Parameters
    ----------
    images : iterable of (H, W) or (H, W, 3) uint8 ndarray
        Frames in order; may be lazy (each frame's ``seconds`` then includes
        producing it, e.g. reading the file).
    model : OcamModel
        Calibration of every frame.
    method : str, keyword-only
        A name of :func:`method_names`, or ``package.module:factory``
        (:func:`ifmi.tracking.methods.load_factory`).
    config : EstimateConfig, keyword-only
        A relative-pose threshold given in pixels is converted to radians for
        ``model`` (:func:`resolved_config`); the result's ``config`` holds the
        converted one.
    progress : bool, keyword-only
        Show a progress bar on stderr.
    total : int, optional, keyword-only
        Frame count for the progress bar when ``images`` has no length.
    timestamps : (N,) sequence, optional, keyword-only
        Timestamps of the trajectory; default the frame indices.

    Returns
    -------
    SequenceEstimate

    Notes
    -----
    BLAS runs on one thread while the sequence is tracked
    (:func:`ifmi.runtime.blas_threads.single_blas_thread`): the matrices are
    small, and a BLAS thread pool would only compete with OpenCV's threads.
    """
    check_config_for_model(config, model, method=method)
    config = resolved_config(config, model)
    front_end = create_front_end(method, model, config)
    if total is None and hasattr(images, "__len__"):
        total = len(images)
    with tqdm(total=total, disable=not progress, file=sys.stderr, unit="frame", desc="estimate") as bar, \
            single_blas_thread():
        trajectory, records = track_sequence(images, front_end, pose_options=config.relative_pose,
                                             keyframe=config.keyframe, timestamps=timestamps,
                                             rolling_shutter=config.rolling_shutter,
                                             bundle_adjustment=config.bundle_adjustment,
                                             plane_twin=config.plane_twin,
                                             on_frame=lambda record: bar.update(1))
    return SequenceEstimate(trajectory=trajectory, frames=tuple(records), config=config,
                            method=method)


def estimate_dataset(dataset_dir: str | os.PathLike, *, method: str,
                     config: EstimateConfig = EstimateConfig(),
                     progress: bool = False, prefetch: bool = True) -> SequenceEstimate:
    """Estimate a DATASET folder (calib_results.txt + images/), read lazily frame by frame.

    With ``prefetch`` the next image is decoded in a background thread while
    the current one is estimated; a frame's ``seconds`` then holds the wait
    for its image instead of the whole decoding time.

    The mirror band is decided from up to five frames spread over the
    sequence (:func:`ifmi.spectral.panorama.panorama_config_with_band`), so a dark
    object in the first frame does not narrow it; the result's ``config``
    holds the radii. Sizes are checked against the camera before any work
    and the tiles again against the decided band
    (:func:`ifmi.spectral.config_limits.check_config_for_model`).

    The trajectory's timestamps and the records' ``frame`` and
    ``reference_frame`` are the dataset's frame indices (the integers in the
    image file names), so a missing image leaves a gap.

    Raises
    ------
    InputError
        Missing calibration or images, or a first image that is unreadable
        or whose size differs from the calibration's. Such a later image is
        flagged as a failed frame (the pose is held) and the sequence goes on.
        Also a calibration too small for the method (e.g. iFMI tiles larger
        than its panorama), naming the calibration file.
    """
    from ifmi.io.dataset import read_dataset

    dataset = read_dataset(Path(dataset_dir))
    try:
        check_config_for_model(config, dataset.model, method=method, calib_path=dataset.calib_path)
    except InputError:
        _check_first_frame_size(dataset)  # frames of another size than the calibration's explain it better
        raise
    # The RANSAC threshold is resolved on the calibration's band first, as for any sequence; the
    # band the panorama uses is then decided from several frames (saved with the configuration).
    config = _config_with_band(resolved_config(config, dataset.model), dataset.model,
                               lambda: _dataset_band_frames(dataset), dataset.calib_path)
    images = dataset.iter_images(prefetch=prefetch, skip_unreadable=True)
    try:
        estimate = estimate_sequence(images, dataset.model, method=method, config=config,
                                     progress=progress, total=len(dataset.image_paths),
                                     timestamps=dataset.frame_indices)
    except CalibrationFitError as exc:
        raise exc.for_file(dataset.calib_path) from None
    # Records count frames by position; the dataset's frames are named by index (gaps allowed).
    index = dataset.frame_indices
    frames = tuple(replace(r, frame=index[r.frame], reference_frame=index[r.reference_frame])
                   for r in estimate.frames)
    return replace(estimate, frames=frames)


def _check_first_frame_size(dataset) -> None:
    """Raise the size error of the dataset's first frame when its header names another size than
    the calibration's."""
    from ifmi.io.images import image_header_size, size_problem

    if not dataset.image_paths:
        return
    path = dataset.image_paths[0]
    try:
        found = image_header_size(path.read_bytes())
    except OSError:
        return
    problem = None if found is None else size_problem(*found, dataset.model.size)
    if problem:
        raise InputError(path, problem)


# Frames, spread evenly over a dataset or a video, that decide the mirror band together.
_BAND_FRAMES = 5


def _dataset_band_frames(dataset) -> list:
    """Up to ``_BAND_FRAMES`` readable frames spread evenly over a dataset."""
    from ifmi.io.dataset import read_image

    paths = dataset.image_paths
    index = np.unique(np.linspace(0, len(paths) - 1, min(_BAND_FRAMES, len(paths))).round().astype(int))
    frames = []
    for k in index:
        try:
            frames.append(read_image(paths[k], size=dataset.model.size))
        except InputError:
            continue  # an unreadable frame is flagged when the sequence reaches it
    return frames


def _config_with_band(config: EstimateConfig, model, read_frames, calib_path) -> EstimateConfig:
    """``config`` with the panorama's band decided from the frames ``read_frames()`` returns
    (saved with the run), and the mirror rim in those frames checked against the calibration's
    centre (:func:`_warn_if_rim_off_centre`).

    Frames are read when the band needs them (OCamCalib with a radius left open) and, for the
    check alone, for a Kalibr model with a centre; an OCamCalib run with both radii given reads
    none and is not checked."""
    from ifmi.spectral.mirror_rim import model_images_a_rim
    from ifmi.spectral.panorama import band_needs_frames, panorama_config_with_band

    needs_band = band_needs_frames(model, config=config.ifmi.panorama)
    if not needs_band and (isinstance(model, OcamModel) or not model_images_a_rim(model)):
        return config
    frames = read_frames()
    _warn_if_rim_off_centre(model, frames, calib_path, dark_level=config.ifmi.panorama.dark_level)
    if not needs_band:
        return config
    panorama = panorama_config_with_band(model, frames, config=config.ifmi.panorama)
    return replace(config, ifmi=replace(config.ifmi, panorama=panorama))


# A run warns when the mirror rim's centre lies more than this fraction of the rim's radius from
# the calibration's centre. 31 renders with their own calibration (OCamCalib and a Kalibr eucm)
# measure at most 0.0012 (0.19 px); the demo office with the centre moved 5 px (0.04 of its
# 123 px rim) gave a geodesic ATE of 0.031 rad instead of 0.0005.
_RIM_OFFSET_WARNING = 0.02


def _warn_if_rim_off_centre(model, frames, calib_path, *, dark_level: float) -> None:
    """One :class:`~ifmi.errors.InputWarning` naming ``calib_path`` when the mirror rim in
    ``frames`` is off the calibration's centre (:func:`ifmi.spectral.mirror_rim.rim_circle_from_frames`)."""
    from ifmi.spectral.mirror_rim import rim_circle_from_frames

    rim = rim_circle_from_frames(model, frames, dark_level=dark_level)
    if rim is None or rim.offset_px <= _RIM_OFFSET_WARNING * rim.radius_px:
        return
    row, col = rim.centre_offset_px
    warnings.warn(f"{calib_path}: the mirror rim in the images is centred {rim.offset_px:.1f} px from the "
                  f"calibration's centre (row {row:+.1f}, col {col:+.1f} px; rim radius {rim.radius_px:.0f} px): "
                  "the calibration may be from another mounting of the mirror or lens, and the rotations "
                  "will be biased; recalibrate, or check the centre in the calibration file",
                  InputWarning, stacklevel=2)


def estimate_video(video_path: str | os.PathLike, calib_path: str | os.PathLike, *, method: str,
                   config: EstimateConfig = EstimateConfig(), progress: bool = False) -> SequenceEstimate:
    """Estimate a video file's frames (decoded in order by OpenCV) with one calibration.

    The trajectory's timestamps are the frames' presentation times in
    seconds from the first frame (:class:`ifmi.io.video.VideoFrames`); a
    damaged frame is flagged failed, and a truncated or damaged file gives
    one :class:`~ifmi.errors.InputWarning`. As for a
    dataset folder, the mirror band is decided from up to five frames
    spread over the clip (:meth:`ifmi.io.video.VideoFrames.spread_frames`),
    so a dark object in the first frame does not narrow it; the result's
    ``config`` holds the radii.

    Raises
    ------
    InputError
        Missing or unreadable calibration or video, frames whose size
        differs from the calibration's, or a calibration too small for the
        method (naming the calibration file).
    """
    from ifmi.io.camera_file import read_camera
    from ifmi.io.video import VideoFrames

    model = read_camera(Path(calib_path))  # calib_results.txt or a Kalibr camera.yaml
    frames = VideoFrames(video_path, size=model.size)
    return _estimate_frames(frames, model, calib_path, method=method, config=config, progress=progress)


def estimate_bag(bag_path: str | os.PathLike, calib_path: str | os.PathLike, *, topic: str | None = None,
                 method: str, config: EstimateConfig = EstimateConfig(),
                 progress: bool = False) -> SequenceEstimate:
    """Estimate the frames of one image topic of a ROS bag with one calibration.

    As :func:`estimate_video`, with the frames of :class:`ifmi.io.bags.BagFrames`:
    the trajectory's timestamps are the frames' stamps in seconds
    (``header.stamp``, or the receive time where it is zero), the records'
    ``frame`` the position in the topic. A frame that cannot be used is
    flagged failed; the mirror band is decided from up to five frames
    spread over the topic, the frames a dataset folder of the same images
    would use, so a bag of lossless images gives the folder's estimate.

    Parameters
    ----------
    bag_path : path-like
        A ``.bag``, ``.mcap`` or ``.db3`` file or a ROS 2 bag folder.
    calib_path : path-like
        ``calib_results.txt`` or ``camera.yaml`` of the camera.
    topic : str, optional, keyword-only
        The image topic; default the bag's only one.
    method, config, progress
        As for :func:`estimate_sequence`.

    Raises
    ------
    InputError
        Missing or unreadable calibration or bag, a topic the bag lacks or
        of another type (the message lists the bag's image topics), a first
        frame that cannot be used or has another size than the
        calibration's, or a calibration too small for the method.
    """
    from ifmi.io.bags import BagFrames
    from ifmi.io.camera_file import read_camera

    model = read_camera(Path(calib_path))
    frames = BagFrames(bag_path, topic=topic, size=model.size, prefetch=True)
    return _estimate_frames(frames, model, calib_path, method=method, config=config, progress=progress)


def _estimate_frames(frames, model, calib_path, *, method: str, config: EstimateConfig,
                     progress: bool) -> SequenceEstimate:
    """Estimate ``frames`` (a video's or a bag's: iterable, ``spread_frames``, ``timestamps``)."""
    check_config_for_model(config, model, method=method, calib_path=calib_path)
    try:
        # The RANSAC threshold is resolved on the calibration's band, then the band is decided.
        config = _config_with_band(resolved_config(config, model), model,
                                   lambda: frames.spread_frames(_BAND_FRAMES), calib_path)
        estimate = estimate_sequence(frames, model, method=method, config=config, progress=progress,
                                     total=len(frames) or None)
    except CalibrationFitError as exc:
        raise exc.for_file(calib_path) from None
    trajectory = replace(estimate.trajectory, timestamps=np.asarray(frames.timestamps, dtype=np.float64))
    return replace(estimate, trajectory=trajectory)
