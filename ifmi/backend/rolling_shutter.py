"""Rolling-shutter compensation of matched rays under constant angular velocity.

A rolling-shutter sensor reads its rows one after another: row ``r`` of an
``H``-row image is exposed ``readout * r / (H - 1)`` frame intervals after
row 0 (``readout`` is the fraction of the frame interval the read-out of the
whole image takes; 0 is a global shutter). While the camera turns, each row
sees the scene from a different orientation, so the rays of one image do not
share one rotation, and a relative pose fitted to them as if they did is off
by a part of the rotation made during the read-out.

Conventions (those of ``omnisim``'s capture model and of the ground truth
it writes):

* Times are in frame intervals. A frame's pose is that of its **middle
  row** (row ``(H - 1) / 2``); row ``r`` is ``readout * (r - (H - 1) / 2) /
  (H - 1)`` frame intervals later than it (negative above the middle).
* The camera turns at a constant angular velocity ``w`` (rad per frame
  interval, a rotation vector in the camera frame): its world-from-camera
  orientation at time ``t`` after a frame's middle row is ``R_mid
  expm([w]x t)``. Then ``R_ab = expm([w]x (b - a))`` for frames ``a`` and
  ``b``, so ``w`` follows from a relative rotation
  (:func:`angular_velocity_from_rotation`).
* A ray measured in row ``r`` (time offset ``dt``) is, in the middle row's
  camera frame, ``expm([w]x dt) @ ray`` (:func:`rays_at_middle_row`).
* Each frame has its own ``w``. Relative rotations of successive frames
  give mean velocities over the intervals between them; a frame's ``w`` is
  interpolated from the intervals before and after it
  (:func:`velocity_at_frame`) or, for the newest frame, extrapolated half an
  interval past the last one (:func:`velocity_after_intervals`): the
  velocity is taken as linear in time.

Translation during the read-out is not modelled (its effect on the rays
falls with the scene's distance, the rotation's does not).

:func:`relative_pose_rolling_shutter` alternates the two: fit the pose, take
``w`` from it, move every ray to its image's middle row, fit again.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from ifmi.geometry.row_timing import row_time_offsets
from ifmi.options import check_finite_fields

__all__ = ["RollingShutterOptions", "row_time_offsets", "angular_velocity_from_rotation",
           "velocity_at_frame", "velocity_after_intervals", "rays_at_middle_row",
           "relative_pose_rolling_shutter"]

# Most re-fits with compensated rays (each costs one relative-pose solve).
_MAX_ITERATIONS = 10


@dataclass(frozen=True)
class RollingShutterOptions:
    """Rolling-shutter model of the camera (see the module docstring).

    Attributes
    ----------
    readout : float
        Time from the start of row 0 to the start of the last row, as a
        fraction of the frame interval, in ``[0, 1]``. 0 (the default): a
        global shutter, no compensation. A sensor that reads its rows in
        ``T`` seconds at ``f`` frames per second has ``readout = T * f``.
    iterations : int
        Re-fits with compensated rays, ``1..10``; each takes the angular
        velocities from the previous fit. On exact views three reach the
        fixed point to 1e-8 rad; two leave a few 1e-6 rad where the new
        frame's velocity is extrapolated from a first fit far off.
    """

    readout: float = 0.0
    iterations: int = 3

    def __post_init__(self) -> None:
        check_finite_fields(self, ("readout",))
        if not 0.0 <= self.readout <= 1.0:
            raise ValueError(f"readout must be in [0, 1] (a fraction of the frame interval), got {self.readout}")
        if isinstance(self.iterations, bool) or not 1 <= self.iterations <= _MAX_ITERATIONS:
            raise ValueError(f"iterations must be in 1..{_MAX_ITERATIONS}, got {self.iterations}")




def angular_velocity_from_rotation(rotation_ab: np.ndarray, frames: float) -> np.ndarray:
    """Constant angular velocity (rad per frame interval, camera frame) that turns frame a into b.

    Parameters
    ----------
    rotation_ab : (3, 3) ndarray
        ``R_ab``, frame b's orientation in frame a.
    frames : float
        Frame intervals from a to b (> 0).

    Returns
    -------
    (3,) ndarray
        ``w`` with ``expm([w]x frames) = R_ab``.
    """
    if not frames > 0:
        raise ValueError(f"expected frames > 0, got {frames}")
    return Rotation.from_matrix(rotation_ab).as_rotvec() / frames


def velocity_at_frame(before: tuple | None, after: tuple | None) -> np.ndarray:
    """Angular velocity at a frame from the mean velocities of the intervals around it.

    The velocity is taken as linear in time: a mean velocity over an
    interval is its value at the interval's centre.

    Parameters
    ----------
    before, after : (w, span) or None
        Mean angular velocity ``w`` ((3,) rad per frame interval, e.g.
        :func:`angular_velocity_from_rotation`) over the ``span`` frame
        intervals that end (``before``) or start (``after``) at the frame,
        in its camera frame. At least one is given.

    Returns
    -------
    (3,) ndarray
        ``w_before + (w_after - w_before) * span_before / (span_before + span_after)``;
        the one given when the other is None.
    """
    if before is None or after is None:
        return np.asarray((after if before is None else before)[0], dtype=np.float64)
    (w_before, span_before), (w_after, span_after) = before, after
    return w_before + (w_after - w_before) * span_before / (span_before + span_after)


def velocity_after_intervals(previous: tuple | None, latest: tuple) -> np.ndarray:
    """Angular velocity at the end of the latest interval, extrapolated linearly in time.

    Parameters
    ----------
    previous : (w, span) or None
        Mean angular velocity over the interval that ends where ``latest``
        starts (None: unknown, the latest is kept).
    latest : (w, span)
        Mean angular velocity over the last interval, both in the camera
        frame of its end.

    Returns
    -------
    (3,) ndarray
        ``w_latest + (w_latest - w_previous) * span_latest / (span_latest + span_previous)``.
    """
    if previous is None:
        return np.asarray(latest[0], dtype=np.float64)
    (w_previous, span_previous), (w_latest, span_latest) = previous, latest
    return w_latest + (w_latest - w_previous) * span_latest / (span_latest + span_previous)


def rays_at_middle_row(rays: np.ndarray, time_offsets: np.ndarray, angular_velocity: np.ndarray) -> np.ndarray:
    """Rays measured at their rows' times, expressed in the camera frame of the middle row.

    Parameters
    ----------
    rays : (N, 3) ndarray
        Unit rays in the camera frame of the row that saw them.
    time_offsets : (N,) ndarray
        Each ray's row time relative to the middle row (frame intervals,
        :func:`row_time_offsets`).
    angular_velocity : (3,) ndarray
        ``w``, rad per frame interval in the camera frame.

    Returns
    -------
    (N, 3) ndarray
        ``expm([w]x dt_i) @ rays[i]``: unit rays.
    """
    turns = Rotation.from_rotvec(np.asarray(time_offsets, dtype=np.float64)[:, None]
                                 * np.asarray(angular_velocity, dtype=np.float64)[None, :])
    return turns.apply(np.asarray(rays, dtype=np.float64))


def relative_pose_rolling_shutter(solve: Callable, rays_a: np.ndarray, rays_b: np.ndarray,
                                  rows_a: np.ndarray, rows_b: np.ndarray, *, height: int,
                                  velocities: Callable, options: RollingShutterOptions) -> tuple:
    """Relative pose of two rolling-shutter frames: fit, compensate the rays, fit again.

    Parameters
    ----------
    solve : callable
        ``solve(rays_a, rays_b) -> (pose, info)`` with ``pose.rotation``
        (``R_ab``) and ``info.success``, e.g.
        :func:`ifmi.backend.relative_pose.relative_pose_from_rays` with its options
        bound.
    rays_a, rays_b : (N, 3) ndarray
        Matched unit rays as measured (each in its own row's camera frame).
    rows_a, rows_b : (N,) ndarray
        Image rows (pixels, 0-based) the rays were measured at.
    height : int, keyword-only
        Image height in pixels.
    velocities : callable, keyword-only
        ``velocities(R_ab) -> (w_a, w_b)``: the angular velocities (rad per
        frame interval, each in its own camera frame) during frame a's and
        frame b's read-out, given the current fit; for two frames ``n``
        intervals apart under one constant velocity,
        ``lambda r: (angular_velocity_from_rotation(r, n),) * 2``.
    options : RollingShutterOptions, keyword-only

    Returns
    -------
    pose, info
        Those of the last successful fit; the first fit's when it failed or
        ``options.readout`` is 0. A re-fit that fails ends the iterations.
    """
    pose, info = solve(rays_a, rays_b)
    if options.readout == 0.0 or not info.success:
        return pose, info
    offsets_a = row_time_offsets(rows_a, height=height, readout=options.readout)
    offsets_b = row_time_offsets(rows_b, height=height, readout=options.readout)
    for _ in range(options.iterations):
        velocity_a, velocity_b = velocities(pose.rotation)
        refit, refit_info = solve(rays_at_middle_row(rays_a, offsets_a, velocity_a),
                                  rays_at_middle_row(rays_b, offsets_b, velocity_b))
        if not refit_info.success:
            break
        pose, info = refit, refit_info
    return pose, info
