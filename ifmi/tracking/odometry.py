"""Chaining relative rotations into a trajectory, frame to frame or against keyframes.

Each frame ``k`` is estimated against a reference frame ``r`` whose pose is
known, giving ``R_rk``; its pose is ``R_0k = R_0r @ R_rk``.

* Frame-to-frame mode (default): the reference is the previous frame, so
  every frame adds the error of one estimate.
* Keyframe mode: the reference stays the same keyframe while the match
  stays good (enough inliers, rotation from the keyframe below a bound);
  otherwise the last successfully estimated frame becomes the keyframe and
  the frame is estimated again against it. When both the last good frame
  and the constant-velocity prediction of the new one lie beyond the
  rotation bound from the keyframe (motion of more than the bound per
  frame), the keyframe is not tried: the last good frame becomes the
  keyframe at once. Error then grows with the number of keyframes, not of
  frames.

Each pair goes through the front end's ``solve_pair`` (:mod:`ifmi.front_end`,
with defaults for what a front end lacks): front ends that declare
``uses_prior_rotation`` receive a predicted ``R_rk`` (constant angular
velocity from the last two successfully estimated poses) and may use it to
look for the motion near the prediction, and ``refine_correspondences``
is given each solution. Front ends are told each successful frame's
``R_0k`` (``accept_pose``). The iFMI front end runs its own per-pair
pipeline (:mod:`ifmi.spectral.pair_pipeline`).

A frame whose estimate fails keeps the last pose (flagged with a reason)
and never becomes a reference: its held pose is not its true pose, and its
image may be what made it fail. The next frame is estimated against the
keyframe and, if that fails, against the last successfully estimated frame;
the constant-velocity prediction spans the failed frames. Only after
``KeyframeOptions.max_failures`` failures in a row (default 2) does the
current frame become the reference with the held pose (tracking resumes
with an offset equal to the rotation missed meanwhile), so the reference
does not stay on a frame the camera has moved away from. The new reference
may itself be the cause (a covered lens, a corrupt image): while frames
keep failing after a reset, each is also matched against the last good
frame before it, and a match with at least ``KeyframeOptions.min_inliers``
inliers puts the track back on the true chain, without the offset.

With a rolling-shutter read-out time (:class:`~ifmi.backend.rolling_shutter.RollingShutterOptions`)
each relative pose is re-fitted with every ray moved to its image's middle
row (:mod:`ifmi.backend.rolling_shutter`). Each frame's angular velocity comes
from the relative rotations of the successfully estimated frames around it,
taken as linear in time: interpolated at the reference, extrapolated half
an interval at the new frame (given the current fit).

Positions chain the estimated translation directions as unit-length steps
per frame: monocular translation is known only up to scale.

With a bundle-adjustment window (:class:`~ifmi.backend.bundle_adjustment.BundleAdjustmentOptions`,
off by default) the trajectory is refined over the points the frames
share: each accepted pair's inlier rays are kept, rays of one frame handed
to two pairs are joined into tracks, and the chained poses are adjusted
by a fixed-lag smoother over the last ``window`` frames
(:func:`~ifmi.backend.bundle_adjustment.poses_from_sliding_window`). The records
keep each pair's own estimate; the trajectory holds the refined poses.
It needs a global shutter (a rolling-shutter fit moves each pair's rays
by its own velocities).
"""

from __future__ import annotations

import math
import time
from bisect import insort
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, fields, replace
from typing import Any, Callable, Iterable, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from ifmi.backend.bundle_adjustment import BundleAdjustmentOptions, poses_from_sliding_window, tracks_from_pair_rays
from ifmi.errors import InputError
from ifmi.frames import MissingFrame
from ifmi.front_end import REFINE_FAILURE, with_contract_defaults
from ifmi.backend.plane_twin import PlaneTwinOptions
from ifmi.backend.relative_pose import RelativePoseOptions, relative_pose_from_rays
from ifmi.backend.rolling_shutter import (RollingShutterOptions, angular_velocity_from_rotation, relative_pose_rolling_shutter,
                              velocity_after_intervals, velocity_at_frame)
from ifmi.geometry.trajectory import Trajectory
from ifmi.tracking.plane_twins import PlaneTwinChain

__all__ = ["KeyframeOptions", "FrameRecord", "FRAME_COLUMNS", "RECOVERED_AFTER_RESET", "REFINE_FAILURE", "PREPARE_MS",
           "Tracker", "track_sequence"]


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
        When the last good frame's and the predicted rotation from the
        keyframe both exceed it, the keyframe is not matched at all.
    max_failures : int
        In both modes: after this many failed frames in a row the current
        frame becomes the reference with the held pose; 0 never gives up on
        the last good frame. Front ends with a coarse search re-acquire a
        lost track against the last good frame themselves, so a short wait
        suffices.
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
    rotation_sigma_rad : float
        Predicted RMS error of that rotation from the relative-pose fit's
        noise and geometry (:attr:`ifmi.backend.relative_pose.RelativePoseInfo.rotation_sigma_rad`),
        radians; NaN for frame 0, failed frames and unknown noise.
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
    rotation_sigma_rad: float = math.nan
    diagnostics: dict = field(default_factory=dict)

    def to_row(self) -> dict:
        """Flat dict for a CSV row: the fixed columns first, then the diagnostics."""
        row = {
            "frame": self.frame, "reference_frame": self.reference_frame,
            "success": self.success, "reason": self.reason,
            "n_correspondences": self.n_correspondences, "n_inliers": self.n_inliers,
            "seconds": self.seconds, "model": self.model, "rotation_rad": self.rotation_rad,
            "rotation_sigma_rad": self.rotation_sigma_rad,
        }
        for key, value in self.diagnostics.items():
            row.setdefault(key, value)
        return row


# Columns of frames.csv that every frame has (FrameRecord's fields but its diagnostics), and the
# diagnostics columns the tracker adds (a frame estimated against the reference before a reset;
# why a front end's refined correspondences failed): names a front end's diagnostics cannot have.
FRAME_COLUMNS = tuple(f.name for f in fields(FrameRecord) if f.name != "diagnostics")
RECOVERED_AFTER_RESET = "recovered_after_reset"
# Diagnostics column of every prepared frame: the wall time of the front end's ``prepare`` (milliseconds).
PREPARE_MS = "t_prepare_ms"


@dataclass
class _Reference:
    frame: int
    state: Any
    rotation: np.ndarray
    position: np.ndarray
    first_inliers: int = -1
    # Mean angular velocities (rad per frame interval, this frame's camera frame) and spans
    # (frame intervals) of the intervals from the previous successfully estimated frame and to
    # the next one, once known: the rolling-shutter model of its read-out.
    velocity_before: tuple | None = None
    velocity_after: tuple | None = None


def _selection_columns(info) -> dict:
    """``frames.csv`` columns of the back end's model choice (both models' GRIC, parallax, noise),
    empty without a solve or from a custom pose solver that gives none."""
    selection = getattr(info, "selection", None)
    return {} if selection is None else selection.columns()


def _median_of_ascending(values: list) -> float:
    """Median of a list in ascending order (the mean of the middle two of an even count), as
    ``np.median``: kept sorted as it grows, a long sequence's prior costs no sort per pair."""
    middle = len(values) // 2
    return values[middle] if len(values) % 2 else (values[middle - 1] + values[middle]) / 2.0


def _angle(rotation: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))


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


def _left_behind(keyframe: _Reference, last_good: _Reference, predicted: np.ndarray,
                 options: KeyframeOptions) -> bool:
    """Whether a match against ``keyframe`` would be poor by its angle alone (:func:`_poor`):
    the last good frame and the predicted pose ``R_0k`` both lie beyond ``options.max_angle_rad``
    from it."""
    return min(_angle(keyframe.rotation.T @ last_good.rotation),
               _angle(keyframe.rotation.T @ predicted)) > options.max_angle_rad


PoseSolver = Callable[..., tuple]


class Tracker:
    """Frame-by-frame chaining of relative rotations (see the module docstring).

    Parameters
    ----------
    front_end : FrontEnd
        Object with ``prepare`` and ``correspondences`` (:mod:`ifmi.pipeline`).
    pose_options : RelativePoseOptions, keyword-only
        With ``ransac_threshold_rad`` set.
    keyframe : KeyframeOptions, keyword-only
    pose_solver : callable, keyword-only
        ``pose_solver(rays_a, rays_b, *, options, rays_per_measurement) -> (pose, info)``
        like :func:`ifmi.backend.relative_pose.relative_pose_from_rays` (the default);
        another solver can be compared on the same front end.
    rolling_shutter : RollingShutterOptions, keyword-only
        With a read-out time, every pose is re-fitted with the rays moved
        to their image's middle row (:mod:`ifmi.backend.rolling_shutter`; the rows
        are those of the correspondences' ``pixels_a`` and ``pixels_b``,
        frames taken as equally spaced). Default: a global shutter.
    bundle_adjustment : BundleAdjustmentOptions, keyword-only
        With a ``window``, :meth:`trajectory` returns the poses refined
        over the points the frames share (see the module docstring); its
        ``robust_scale_rad`` defaults to the RANSAC threshold. Default off.
    plane_twin : PlaneTwinOptions, keyword-only
        Settling a plane's twin decomposition over the sequence
        (:mod:`ifmi.tracking.plane_twins`); :meth:`trajectory` returns the
        re-chained poses. Default on.

    Raises
    ------
    ValueError
        ``pose_options.ransac_threshold_rad`` is not set (a threshold in
        pixels must be converted for the camera first), or a
        bundle-adjustment window is asked for with a rolling shutter.
    """

    def __init__(self, front_end, *, pose_options: RelativePoseOptions,
                 keyframe: KeyframeOptions = KeyframeOptions(),
                 pose_solver: PoseSolver = relative_pose_from_rays,
                 rolling_shutter: RollingShutterOptions = RollingShutterOptions(),
                 bundle_adjustment: BundleAdjustmentOptions = BundleAdjustmentOptions(),
                 plane_twin: PlaneTwinOptions = PlaneTwinOptions()):
        if pose_options.ransac_threshold_rad is None:
            raise ValueError("pose_options.ransac_threshold_rad is None; resolve it for the camera "
                             "first (RelativePoseOptions.resolved or ifmi.pipeline.resolved_config)")
        self.front_end = front_end
        self._contract = with_contract_defaults(front_end)
        self.pose_options = pose_options
        self.keyframe = keyframe
        self.pose_solver = pose_solver
        self.rolling_shutter = rolling_shutter
        conflict = bundle_adjustment.shutter_conflict(rolling_shutter.readout)
        if conflict is not None:
            raise ValueError(conflict)
        if bundle_adjustment.robust_scale_rad is None:
            bundle_adjustment = replace(bundle_adjustment, robust_scale_rad=pose_options.ransac_threshold_rad)
        self.bundle_adjustment = bundle_adjustment
        self._plane_twins = PlaneTwinChain(options=plane_twin)
        # Each accepted pair's (reference, frame, inlier rays_a, inlier rays_b), for the adjustment.
        self._pair_rays: list = []
        # The solved pairs' noise_rms_rad and noise_measurements, each list kept in ascending order:
        # their medians are the prior of the next pairs' noise.
        self._noise_rms: list = []
        self._noise_measurements: list = []
        # Of the solved pairs with both models fitted: how many showed translation on their own
        # evidence, and how many there were (the next pairs' translation prior).
        self._translated_pairs, self._compared_pairs = 0, 0
        self._height = 0  # rows of the images (the first frame's), for the rolling-shutter row times
        self.rotations: list = []
        self.positions: list = []
        self.records: list = []
        # reference: the frame estimates are made against (the keyframe, or the last good
        # frame); last_good: the last successfully estimated frame; good: its (frame, R_0k)
        # history for the prediction.
        self._reference: _Reference | None = None
        self._last_good: _Reference | None = None
        self._good: list = []
        self._failures_in_row = 0
        # The last good frame before a reference reset and its prediction history (see _recover).
        self._before_reset: _Reference | None = None
        self._good_before_reset: list = []

    def _solve(self, reference: _Reference, state, predicted: np.ndarray, frame: int):
        """``(pose, info, corr)`` of ``frame`` against ``reference``; ``(None, None, corr)`` when matching failed.

        The pair goes through the front end's ``solve_pair`` (:mod:`ifmi.front_end`) with the
        predicted ``R_ab`` and this tracker's back end.
        """
        solved = self._contract.solve_pair(reference.state, state, prior_rotation=reference.rotation.T @ predicted,
                                           solve=lambda corr: self._solve_rays(reference, corr, frame))
        return solved.pose, solved.info, solved.correspondences

    def _solve_rays(self, reference: _Reference, corr, frame: int) -> tuple:
        """``(pose, info)`` of the back end on ``corr``'s rays (with the rolling-shutter model when set)."""
        options = self._pair_pose_options()

        def solve(rays_a, rays_b):
            return self.pose_solver(rays_a, rays_b, options=options,
                                    rays_per_measurement=corr.rays_per_measurement)

        if self.rolling_shutter.readout == 0.0:
            return solve(corr.rays_a, corr.rays_b)
        return relative_pose_rolling_shutter(
            solve, corr.rays_a, corr.rays_b, corr.pixels_a[:, 0], corr.pixels_b[:, 0], height=self._height,
            velocities=lambda rotation_ab: self._velocities(reference, rotation_ab, frame),
            options=self.rolling_shutter)

    def _pair_pose_options(self) -> RelativePoseOptions:
        """The back end's options for the next pair: with ``sequence_model_prior``, the share of the
        solved pairs so far that showed translation as its translation prior (Laplace's rule of
        succession); with ``sequence_noise_prior``, their noise evidence as its noise prior (medians of
        their root mean squares and of their measurements: one typical pair's worth)."""
        options = self.pose_options
        if options.sequence_model_prior and options.translation_prior is None:
            options = replace(options, translation_prior=(self._translated_pairs + 1) / (self._compared_pairs + 2))
        if not options.sequence_noise_prior or options.noise_sigma_rad is not None or not self._noise_rms:
            return options
        return replace(options, noise_prior_rms_rad=_median_of_ascending(self._noise_rms),
                       noise_prior_measurements=_median_of_ascending(self._noise_measurements))

    def _keep_pair_evidence(self, info) -> None:
        """Add a solved pair's own evidence to the priors': its noise (``ModelSelection.noise_rms_rad``)
        and, with both models fitted, whether it showed translation without a prior."""
        selection = getattr(info, "selection", None)
        rms = getattr(selection, "noise_rms_rad", math.nan)
        if rms > 0 and math.isfinite(rms):
            insort(self._noise_rms, float(rms))
            insort(self._noise_measurements, float(selection.noise_measurements))
        scores = (getattr(selection, "gric_rotation", math.nan), getattr(selection, "gric_5pt", math.nan))
        if all(math.isfinite(score) for score in scores):
            self._compared_pairs += 1
            self._translated_pairs += bool(selection.evidence_prefers_translation)

    def _velocities(self, reference: _Reference, rotation_ab: np.ndarray, frame: int) -> tuple:
        """Angular velocities at the read-outs of ``reference`` and ``frame`` given ``R_ab``.

        The interval from the last successfully estimated frame l to b follows from
        ``R_ab``. Frame b's velocity extrapolates it and l's interval before it; the
        reference's interpolates its intervals before and after it (after: to the next good
        frame when known, as for a keyframe, else to b).
        """
        last = self._last_good
        rotation_lb = rotation_ab if last is reference else last.rotation.T @ reference.rotation @ rotation_ab
        latest = (angular_velocity_from_rotation(rotation_lb, frame - last.frame), frame - last.frame)
        # l's earlier interval, turned into b's camera frame (a rotation vector of R_lb is its own axis).
        previous = None if last.velocity_before is None else (rotation_lb.T @ last.velocity_before[0],
                                                              last.velocity_before[1])
        after = reference.velocity_after
        if after is None:
            after = (angular_velocity_from_rotation(rotation_ab, frame - reference.frame), frame - reference.frame)
        return (velocity_at_frame(reference.velocity_before, after),
                velocity_after_intervals(previous, latest))

    def _good_frame(self, k: int, state, rotation: np.ndarray, position: np.ndarray) -> _Reference:
        """Frame ``k``'s reference record; with a read-out time, its interval velocity from the
        last good frame is kept on both (the rolling-shutter model, :meth:`_velocities`)."""
        if self.rolling_shutter.readout == 0.0:
            return _Reference(k, state, rotation, position)
        last = self._last_good
        span = k - last.frame
        interval = (angular_velocity_from_rotation(last.rotation.T @ rotation, span), span)
        if last.velocity_after is None:
            last.velocity_after = interval
        return _Reference(k, state, rotation, position, velocity_before=interval)

    def _accept(self, state, rotation: np.ndarray) -> None:
        """Tell the front end (``accept_pose``) a successfully estimated frame's ``R_0k``."""
        self._contract.accept_pose(state, rotation)

    def _recover(self, state, k: int):
        """``(reference, pose, info, corr)`` of frame ``k`` matched against the last good frame
        before a reference reset (constant-velocity prediction across the gap), or None.

        After a reset the chain continues from a held pose that is off by the rotation
        missed meanwhile. While frames keep failing against the new reference (it may be
        the frame that made tracking fail: a covered lens, a corrupt image), each is also
        tried against the frame before the reset; a match with at least
        ``KeyframeOptions.min_inliers`` inliers (a match good enough to keep a keyframe; the
        frames may lie far apart) puts the track back on the true chain. The first success of
        any kind ends the attempts.
        """
        reference = self._before_reset
        pose, info, corr = self._solve(reference, state, _predict(self._good_before_reset, k), k)
        if info is None or not info.success or info.n_inliers < self.keyframe.min_inliers:
            return None
        self._reference, self._good = reference, self._good_before_reset
        corr = replace(corr, diagnostics={**corr.diagnostics, RECOVERED_AFTER_RESET: True})
        return reference, pose, info, corr

    def _append(self, record: FrameRecord, rotation: np.ndarray, position: np.ndarray) -> FrameRecord:
        self.rotations.append(rotation)
        self.positions.append(position)
        self.records.append(record)
        return record

    def step(self, image, *, started: float | None = None, prepared: tuple | None = None) -> FrameRecord:
        """Estimate the next frame's pose and return its record.

        Parameters
        ----------
        image : (H, W) or (H, W, 3) uint8 ndarray or MissingFrame
            A :class:`MissingFrame` is flagged as failed and holds the pose.
        started : float, optional, keyword-only
            ``time.perf_counter()`` when work on this frame began (e.g.
            before reading it); default now.
        prepared : tuple, optional, keyword-only
            ``(state, milliseconds)``: the front end's ``prepare`` of ``image``, made
            already (e.g. in the background), and its duration; default prepare it now.

        Raises
        ------
        InputError
            The first frame is a :class:`MissingFrame`.
        """
        start = time.perf_counter() if started is None else started
        k = len(self.records)
        if isinstance(image, MissingFrame):
            if self._reference is None:
                raise InputError(image.source, f"first frame unusable: {image.reason}")
            self._failures_in_row += 1
            record = FrameRecord(k, self._reference.frame, False, f"image: {image.reason}", 0, 0,
                                 time.perf_counter() - start)
            return self._append(record, self.rotations[-1], self.positions[-1])
        state, prepare_ms = _timed_prepare(self.front_end, image) if prepared is None else prepared
        if self._reference is None:
            if self.rolling_shutter.readout > 0.0:
                self._height = int(np.shape(image)[0])
            self._accept(state, np.eye(3))
            self._reference = self._last_good = _Reference(0, state, np.eye(3), np.zeros(3))
            self._good = [(0, np.eye(3))]
            return self._append(FrameRecord(0, 0, True, "", 0, 0, time.perf_counter() - start,
                                            diagnostics={PREPARE_MS: prepare_ms}), np.eye(3), np.zeros(3))
        record, rotation, position = self._estimate(k, state)
        record = replace(record, seconds=time.perf_counter() - start,
                         diagnostics={**record.diagnostics, PREPARE_MS: prepare_ms})
        return self._append(record, rotation, position)

    def _estimate(self, k: int, state) -> tuple[FrameRecord, np.ndarray, np.ndarray]:
        keyframe = self.keyframe
        predicted = _predict(self._good, k)
        reference = self._reference
        if (keyframe.enabled and self._last_good.frame != reference.frame
                and _left_behind(reference, self._last_good, predicted, keyframe)):
            reference = self._reference = self._last_good
        pose, info, corr = self._solve(reference, state, predicted, k)
        if (self._last_good.frame != reference.frame
                and (_poor(info, pose, reference, keyframe) if keyframe.enabled
                     else info is None or not info.success)):
            reference = self._reference = self._last_good
            pose, info, corr = self._solve(reference, state, predicted, k)
        if (info is None or not info.success) and self._before_reset is not None:
            recovered = self._recover(state, k)
            if recovered is not None:
                reference, pose, info, corr = recovered
        if info is not None and info.success:
            self._before_reset = None
            rotation = reference.rotation @ pose.rotation
            position = reference.position + (k - reference.frame) * (reference.rotation @ pose.translation_direction)
            if reference.first_inliers < 0:
                reference.first_inliers = info.n_inliers
            self._accept(state, rotation)
            self._last_good = self._good_frame(k, state, rotation, position)
            if not keyframe.enabled:
                self._reference = self._last_good
            self._good = [self._good[-1], (k, rotation)]
            self._failures_in_row = 0
            if self.bundle_adjustment.window:
                inliers = np.asarray(info.inlier_mask, dtype=bool)
                self._pair_rays.append((reference.frame, k, corr.rays_a[inliers], corr.rays_b[inliers]))
            self._plane_twins.observe(k, corr, pose, info, threshold_rad=self.pose_options.ransac_threshold_rad)
            self._keep_pair_evidence(info)
            sigma = getattr(info, "rotation_sigma_rad", math.nan)  # a custom pose_solver may not predict it
            record = FrameRecord(k, reference.frame, True, "", info.n_correspondences, info.n_inliers,
                                 0.0, info.model, _angle(pose.rotation), sigma,
                                 {**corr.diagnostics, **_selection_columns(info)})
            return record, rotation, position
        rotation, position = self.rotations[-1], self.positions[-1]
        reason = corr.reason if info is None else f"relative pose: {info.reason}"
        self._failures_in_row += 1
        if keyframe.max_failures and self._failures_in_row >= keyframe.max_failures:
            # Give up on the last good frame: restart from this one with the held pose, but keep
            # the last frame of the true chain (the first such, over repeated resets) to recover on.
            if self._before_reset is None:
                self._before_reset, self._good_before_reset = self._last_good, self._good
            self._reference = self._last_good = _Reference(k, state, rotation, position)
            self._good = [(k, rotation)]
            self._failures_in_row = 0
            reason += f"; reference reset after {keyframe.max_failures} failures"
        record = FrameRecord(k, reference.frame, False, reason, len(corr.rays_a),
                             0 if info is None else info.n_inliers, 0.0,
                             "" if info is None else info.model, 0.0,
                             diagnostics={**corr.diagnostics, **_selection_columns(info)})
        return record, rotation, position

    def trajectory(self, timestamps: Sequence[float] | None = None) -> Trajectory:
        """Poses of the frames so far; ``timestamps`` default to the frame indices.

        With a bundle-adjustment window the poses are refined over the points
        the frames share (recomputed on each call, from the chained poses).
        """
        n = len(self.rotations)
        if timestamps is None:
            stamps = np.arange(n, dtype=np.float64)
        else:
            stamps = np.asarray(timestamps, dtype=np.float64)
            if stamps.shape != (n,):
                raise ValueError(f"expected {n} timestamps, got {stamps.shape}")
        rotations = np.asarray(self.rotations).reshape(n, 3, 3)
        positions = np.asarray(self.positions).reshape(n, 3)
        # A failed frame holds the pose before it; a good one is chained from its reference.
        references = np.array([record.reference_frame if record.success else max(record.frame - 1, 0)
                               for record in self.records], dtype=int)
        rotations, positions, self.records = self._plane_twins.apply(rotations, positions, self.records, references)
        if self.bundle_adjustment.window and self._pair_rays:
            observations = tracks_from_pair_rays(self._pair_rays,
                                                 tolerance_rad=self.bundle_adjustment.match_tolerance_rad)
            rotations, positions, _ = poses_from_sliding_window(rotations, positions, references, observations,
                                                                options=self.bundle_adjustment)
        return Trajectory(timestamps=stamps, positions=positions, rotations=rotations)


def track_sequence(images: Iterable[np.ndarray], front_end, *, pose_options: RelativePoseOptions,
                   keyframe: KeyframeOptions = KeyframeOptions(),
                   on_frame: Callable[[FrameRecord], None] | None = None,
                   timestamps: Sequence[float] | None = None,
                   pose_solver: PoseSolver = relative_pose_from_rays,
                   rolling_shutter: RollingShutterOptions = RollingShutterOptions(),
                   bundle_adjustment: BundleAdjustmentOptions = BundleAdjustmentOptions(),
                   plane_twin: PlaneTwinOptions = PlaneTwinOptions(),
                   ) -> tuple[Trajectory, list[FrameRecord]]:
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
    pose_solver : callable, keyword-only
        See :class:`Tracker`.
    rolling_shutter : RollingShutterOptions, keyword-only
        See :class:`Tracker`.
    bundle_adjustment : BundleAdjustmentOptions, keyword-only
        See :class:`Tracker`.
    plane_twin : PlaneTwinOptions, keyword-only
        See :class:`Tracker`.

    Returns
    -------
    trajectory : Trajectory
    records : list of FrameRecord

    Raises
    ------
    InputError
        The first frame is a :class:`MissingFrame`.
    ValueError
        ``pose_options.ransac_threshold_rad`` is not set.
    """
    tracker = Tracker(front_end, pose_options=pose_options, keyframe=keyframe, pose_solver=pose_solver,
                      rolling_shutter=rolling_shutter, bundle_adjustment=bundle_adjustment, plane_twin=plane_twin)
    frames = _frames_prepared_ahead if tracker._contract.prepares_in_background else _frames
    for image, started, prepared in frames(iter(images), front_end):
        record = tracker.step(image, started=started, prepared=prepared)
        if on_frame is not None:
            on_frame(record)
    return tracker.trajectory(timestamps), tracker.records


def _timed_prepare(front_end, image) -> tuple:
    """``(front_end.prepare(image), its wall milliseconds)``."""
    started = time.perf_counter()
    state = front_end.prepare(image)
    return state, 1e3 * (time.perf_counter() - started)


def _frames(iterator, front_end):
    """``(image, started, None)`` of each frame: read when asked, prepared by the tracker's step."""
    while True:
        started = time.perf_counter()  # the frame's time includes producing it (e.g. reading)
        try:
            image = next(iterator)
        except StopIteration:
            return
        yield image, started, None


def _read_and_prepare(iterator, front_end) -> tuple | None:
    """The next frame and its ``(state, ms)`` (None for a :class:`MissingFrame`), or None at the end."""
    try:
        image = next(iterator)
    except StopIteration:
        return None
    return image, None if isinstance(image, MissingFrame) else _timed_prepare(front_end, image)


def _frames_prepared_ahead(iterator, front_end):
    """``(image, started, (state, ms))`` of each frame, the next frame read and prepared in a background
    thread while the caller works on this one. ``started`` is when the caller began to wait for the
    frame, so the frames' times add up to the wall time; the frames are read and prepared in order,
    one at a time."""
    with ThreadPoolExecutor(max_workers=1) as worker:
        ahead = worker.submit(_read_and_prepare, iterator, front_end)
        while True:
            started = time.perf_counter()
            item = ahead.result()
            if item is None:
                return
            ahead = worker.submit(_read_and_prepare, iterator, front_end)
            yield item[0], started, item[1]
