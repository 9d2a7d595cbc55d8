"""Chaining relative rotations into a trajectory, frame to frame or against keyframes.

Each frame ``k`` is estimated against a reference frame ``r`` whose pose is
known, giving ``R_rk``; its pose is ``R_0k = R_0r @ R_rk``.

* Frame-to-frame mode (default): the reference is the previous frame, so
  every frame adds the error of one estimate.
* Keyframe mode: the reference stays the same keyframe while the match
  stays good (enough inliers, rotation from the keyframe below a bound);
  otherwise the last successfully estimated frame becomes the keyframe and
  the frame is estimated again against it. Error then grows with the
  number of keyframes, not of frames.

Front ends that declare ``uses_prior_rotation`` receive a predicted
``R_rk`` (constant angular velocity from the last two successfully
estimated poses) and may use it to look for the motion near the prediction.

A frame whose estimate fails keeps the last pose (flagged with a reason)
and never becomes a reference: its held pose is not its true pose, and its
image may be what made it fail. The next frame is estimated against the
keyframe and, if that fails, against the last successfully estimated frame;
the constant-velocity prediction spans the failed frames. Only after
``KeyframeOptions.max_failures`` failures in a row does the current frame
become the reference with the held pose (tracking resumes with an offset
equal to the rotation missed meanwhile).

Positions chain the estimated translation directions as unit-length steps
per frame: monocular translation is known only up to scale.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Iterable, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import InputError
from .relative_pose import RelativePoseOptions, relative_pose_from_rays
from .trajectory import Trajectory

__all__ = ["KeyframeOptions", "FrameRecord", "MissingFrame", "track_sequence"]


@dataclass(frozen=True)
class KeyframeOptions:
    """Keyframe policy of :func:`track_sequence`.

    Attributes
    ----------
    enabled : bool
        Estimate against keyframes instead of the previous frame.
    min_inliers : int
        Switch keyframes when an estimate against the keyframe has fewer inliers.
    min_inlier_fraction : float
        ... or when its inliers are fewer than this fraction of the inliers
        the current keyframe had against its first partner frame.
    max_angle_rad : float
        ... or when the rotation from the keyframe exceeds this angle (radians).
    max_failures : int
        In both modes: after this many failed frames in a row the current
        frame becomes the reference with the held pose; 0 never gives up on
        the last good frame.
    """

    enabled: bool = False
    min_inliers: int = 40
    min_inlier_fraction: float = 0.6
    max_angle_rad: float = 0.25
    max_failures: int = 2

    def __post_init__(self) -> None:
        if self.max_failures < 0:
            raise ValueError(f"max_failures must be >= 0, got {self.max_failures}")
        if self.min_inliers < 0 or not 0 <= self.min_inlier_fraction <= 1 or not self.max_angle_rad > 0:
            raise ValueError(
                "expected min_inliers >= 0, 0 <= min_inlier_fraction <= 1, max_angle_rad > 0; got "
                f"{self.min_inliers}, {self.min_inlier_fraction}, {self.max_angle_rad}")


@dataclass(frozen=True)
class FrameRecord:
    """Outcome of one frame.

    Attributes
    ----------
    frame : int
    reference_frame : int
        Frame the estimate is relative to (frame 0 refers to itself).
    success : bool
    reason : str
        Empty on success.
    n_correspondences, n_inliers : int
    seconds : float
        Wall time of this frame's work: producing the image (e.g. reading
        it), preparing it, matching and solving.
    model : str
        Relative-pose model used (``"5pt"``, ``"rotation"`` or ``""``).
    rotation_rad : float
        Rotation angle from the reference frame, radians.
    diagnostics : dict
        Front-end figures (JSON scalars).
    """

    frame: int
    reference_frame: int
    success: bool
    reason: str
    n_correspondences: int
    n_inliers: int
    seconds: float
    model: str = ""
    rotation_rad: float = 0.0
    diagnostics: dict = field(default_factory=dict)

    def to_row(self) -> dict:
        """Flat dict for a CSV row: the fixed columns first, then the diagnostics."""
        row = {
            "frame": self.frame, "reference_frame": self.reference_frame,
            "success": self.success, "reason": self.reason,
            "n_correspondences": self.n_correspondences, "n_inliers": self.n_inliers,
            "seconds": self.seconds, "model": self.model, "rotation_rad": self.rotation_rad,
        }
        for key, value in self.diagnostics.items():
            row.setdefault(key, value)
        return row


@dataclass
class _Reference:
    frame: int
    state: Any
    rotation: np.ndarray
    position: np.ndarray
    first_inliers: int = -1


@dataclass(frozen=True)
class MissingFrame:
    """Stands in a sequence for an image that could not be used.

    The frame is flagged as failed with ``reason`` and keeps the previous
    pose; the sequence goes on. Only the first frame must be usable, since it
    defines the reference.

    Attributes
    ----------
    source : str
        Where the image came from (a file path), for messages.
    reason : str
        Why it could not be used, one line.
    """

    source: str
    reason: str


def _angle(rotation: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))


def _solve(front_end, reference: _Reference, state, pose_options: RelativePoseOptions,
           predicted: np.ndarray | None):
    if predicted is not None and getattr(front_end, "uses_prior_rotation", False):
        corr = front_end.correspondences(reference.state, state,
                                         prior_rotation=reference.rotation.T @ predicted)
    else:
        corr = front_end.correspondences(reference.state, state)
    if not corr.success:
        return None, None, corr
    pose, info = relative_pose_from_rays(corr.rays_a, corr.rays_b, options=pose_options,
                                         rays_per_measurement=corr.rays_per_measurement)
    return pose, info, corr


def _predict(good: list, frame: int) -> np.ndarray:
    """Constant-velocity prediction of pose ``R_0k`` of ``frame``.

    ``good`` holds ``(frame, R_0k)`` of the last (up to two) successfully
    estimated frames; the angular velocity between them is extrapolated over
    the gap to ``frame`` (failed frames in between count as time passing).
    """
    if len(good) < 2:
        return good[-1][1]
    (f0, r0), (f1, r1) = good[-2], good[-1]
    step = r0.T @ r1
    if f1 - f0 == 1 and frame - f1 == 1:
        return r1 @ step
    rotvec = Rotation.from_matrix(step).as_rotvec() * (frame - f1) / (f1 - f0)
    return r1 @ Rotation.from_rotvec(rotvec).as_matrix()


def _poor(info, pose, reference: _Reference, options: KeyframeOptions) -> bool:
    if info is None or not info.success:
        return True
    if info.n_inliers < options.min_inliers or _angle(pose.rotation) > options.max_angle_rad:
        return True
    return reference.first_inliers > 0 and info.n_inliers < options.min_inlier_fraction * reference.first_inliers


def track_sequence(images: Iterable[np.ndarray], front_end, *, pose_options: RelativePoseOptions,
                   keyframe: KeyframeOptions = KeyframeOptions(),
                   on_frame: Callable[[FrameRecord], None] | None = None,
                   timestamps: Sequence[float] | None = None) -> tuple[Trajectory, list[FrameRecord]]:
    """Estimate every frame's pose ``T_0k`` with ``front_end`` and the relative-pose back end.

    Parameters
    ----------
    images : iterable of (H, W) or (H, W, 3) uint8 ndarray or MissingFrame
        A :class:`MissingFrame` item is flagged as failed and holds the pose.
    front_end : FrontEnd
        Object with ``prepare`` and ``correspondences`` (:mod:`ifmi.pipeline`).
    pose_options : RelativePoseOptions, keyword-only
    keyframe : KeyframeOptions, keyword-only
    on_frame : callable, optional, keyword-only
        Called with each frame's record as soon as the frame is done (a
        progress display, a live log); default nothing.
    timestamps : (N,) sequence, optional, keyword-only
        Default: frame indices.

    Returns
    -------
    trajectory : Trajectory
    records : list of FrameRecord

    Raises
    ------
    InputError
        The first frame is a :class:`MissingFrame`.
    ValueError
        ``pose_options.ransac_threshold_rad`` is not set (a threshold in
        pixels must be converted for the camera first).
    """
    if pose_options.ransac_threshold_rad is None:
        raise ValueError("pose_options.ransac_threshold_rad is None; resolve it for the camera "
                         "first (RelativePoseOptions.resolved or ifmi.pipeline.resolved_config)")
    rotations, positions, records = [], [], []
    # reference: the frame estimates are made against (the keyframe, or the last good
    # frame); last_good: the last successfully estimated frame; good: its (frame, R_0k)
    # history for the prediction.
    reference = last_good = None
    good: list = []
    failures_in_row = 0
    iterator = iter(images)
    k = 0
    while True:
        start = time.perf_counter()
        try:
            image = next(iterator)
        except StopIteration:
            break
        if isinstance(image, MissingFrame):
            if reference is None:
                raise InputError(image.source, f"first frame unusable: {image.reason}")
            failures_in_row += 1
            rotations.append(rotations[-1])
            positions.append(positions[-1])
            records.append(FrameRecord(k, reference.frame, False, f"image: {image.reason}", 0, 0,
                                       time.perf_counter() - start))
            if on_frame is not None:
                on_frame(records[-1])
            k += 1
            continue
        state = front_end.prepare(image)
        if reference is None:
            reference = last_good = _Reference(0, state, np.eye(3), np.zeros(3))
            good.append((0, np.eye(3)))
            rotations.append(np.eye(3))
            positions.append(np.zeros(3))
            records.append(FrameRecord(0, 0, True, "", 0, 0, time.perf_counter() - start))
            if on_frame is not None:
                on_frame(records[-1])
            k += 1
            continue

        predicted = _predict(good, k)
        pose, info, corr = _solve(front_end, reference, state, pose_options, predicted)
        if (last_good.frame != reference.frame
                and (_poor(info, pose, reference, keyframe) if keyframe.enabled
                     else info is None or not info.success)):
            reference = last_good
            pose, info, corr = _solve(front_end, reference, state, pose_options, predicted)
        used = reference
        if info is not None and info.success:
            rotation = used.rotation @ pose.rotation
            position = used.position + (k - used.frame) * (used.rotation @ pose.translation_direction)
            if used.first_inliers < 0:
                used.first_inliers = info.n_inliers
            last_good = _Reference(k, state, rotation, position)
            if not keyframe.enabled:
                reference = last_good
            good = [good[-1], (k, rotation)]
            failures_in_row = 0
            record = FrameRecord(k, used.frame, True, "", info.n_correspondences, info.n_inliers,
                                 0.0, info.model, _angle(pose.rotation), dict(corr.diagnostics))
        else:
            rotation, position = rotations[-1], positions[-1]
            reason = corr.reason if info is None else f"relative pose: {info.reason}"
            n_corr = len(corr.rays_a)
            n_inl = 0 if info is None else info.n_inliers
            failures_in_row += 1
            if keyframe.max_failures and failures_in_row >= keyframe.max_failures:
                # Give up on the last good frame: restart from this one with the held pose.
                reference = last_good = _Reference(k, state, rotation, position)
                good = [(k, rotation)]
                failures_in_row = 0
                reason += f"; reference reset after {keyframe.max_failures} failures"
            record = FrameRecord(k, used.frame, False, reason, n_corr, n_inl, 0.0,
                                 "" if info is None else info.model, 0.0, dict(corr.diagnostics))
        rotations.append(rotation)
        positions.append(position)
        seconds = time.perf_counter() - start
        records.append(replace(record, seconds=seconds))
        if on_frame is not None:
            on_frame(records[-1])
        k += 1
    n = len(rotations)
    if timestamps is None:
        stamps = np.arange(n, dtype=np.float64)
    else:
        stamps = np.asarray(timestamps, dtype=np.float64)
        if stamps.shape != (n,):
            raise ValueError(f"expected {n} timestamps, got {stamps.shape}")
    trajectory = Trajectory(timestamps=stamps, positions=np.asarray(positions).reshape(n, 3),
                            rotations=np.asarray(rotations).reshape(n, 3, 3))
    return trajectory, records
