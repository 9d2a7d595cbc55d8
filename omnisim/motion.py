"""Camera trajectories: smooth seeded random rotations (and translations), or a TUM file.

Poses are camera-to-world: ``R_wc`` (3,3) maps camera-frame directions to the
world (z up) and ``p_w`` (3,) is the camera centre in metres. The camera's
own axes follow the OCamCalib frame (z = mirror axis, up when level).
Orientation angles follow the project convention: ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ifmi.io.tum import Trajectory, read_tum
from ifmi.geometry.rotations import matrix_from_rpy

from .config import TrajectorySettings
from .settings import MAX_CAMERA_REACH_M

__all__ = ["WorldPoses", "smooth_noise", "random_trajectory", "poses_from_tum",
           "relative_trajectory", "world_trajectory", "poses_for_settings", "poses_at_times",
           "trajectory_in_camera"]


@dataclass(frozen=True)
class WorldPoses:
    """Camera-to-world poses of a sequence: rotations (N,3,3) ``R_wc``, positions (N,3) metres."""

    rotations: np.ndarray
    positions: np.ndarray

    def __len__(self) -> int:
        return len(self.rotations)


def smooth_noise(n: int, *, rng: np.random.Generator, smoothness: float) -> np.ndarray:
    """Unit-variance Gaussian noise of length ``n``, low-passed by a Gaussian of ``smoothness`` frames.

    Value ``k`` depends only on the first ``k + 4 * smoothness + 1`` draws, so a
    longer sequence from the same generator state starts with the same values.

    Returns
    -------
    (n,) ndarray
    """
    pad = int(np.ceil(4 * smoothness)) + 1
    white = rng.standard_normal(n + 2 * pad)
    if smoothness <= 0:
        return white[pad:pad + n]
    k = np.arange(-pad, pad + 1)
    kernel = np.exp(-0.5 * (k / smoothness) ** 2)
    kernel /= np.sqrt(np.sum(kernel ** 2))  # keeps unit variance
    return np.convolve(white, kernel, mode="valid")[:n]


def _bounded_follow(targets: np.ndarray, max_step: float) -> np.ndarray:
    """Follow ``targets`` from ``targets[0]`` moving at most ``max_step`` per frame."""
    out = np.empty_like(targets)
    out[0] = targets[0]
    for k in range(1, len(targets)):
        out[k] = out[k - 1] + np.clip(targets[k] - out[k - 1], -max_step, max_step)
    return out


# Gain of the smooth unit-variance noise before tanh squashes it into (-1, 1):
# with 1.5 the bound is approached (|tanh| > 0.9) about 8 % of the time.
_SQUASH_GAIN = 1.5


def random_trajectory(settings: TrajectorySettings, *, seed: int) -> WorldPoses:
    """Smooth random orientation (and optional translation) of a hand-held or vehicle camera.

    Yaw turns with a smooth random rate bounded by ``max_yaw_step_deg`` per
    frame; roll and pitch follow smooth random targets within
    ``±max_roll_deg`` / ``±max_pitch_deg``, moving at most ``max_tilt_step_deg``
    per frame. Translation (if ``translation_step_m`` > 0) is a smooth random
    walk with steps up to that length, kept within ``translation_radius_m``
    of the start. Every signal has its own random stream and is computed
    frame by frame, so a sequence of N frames is the prefix of any longer one
    with the same seed.

    Parameters
    ----------
    settings : TrajectorySettings
    seed : int, keyword-only
        Random seed; the same seed gives the same poses.
    """
    n = settings.frames
    s = settings.smoothness_frames

    def stream(k: int, smoothness: float) -> np.ndarray:
        return np.tanh(_SQUASH_GAIN * smooth_noise(n, rng=np.random.default_rng([seed, 0x7A1, k]),
                                                   smoothness=smoothness))

    yaw0 = np.random.default_rng([seed, 0x7A1, 0]).uniform(-np.pi, np.pi)
    yaw_rate = np.radians(settings.max_yaw_step_deg) * stream(1, s)
    yaw = yaw0 + np.concatenate([[0.0], np.cumsum(yaw_rate[:-1])])
    tilt_step = np.radians(settings.max_tilt_step_deg)
    roll = _bounded_follow(np.radians(settings.max_roll_deg) * stream(2, 4 * s), tilt_step)
    pitch = _bounded_follow(np.radians(settings.max_pitch_deg) * stream(3, 4 * s), tilt_step)
    rotations = matrix_from_rpy(np.stack([roll, pitch, yaw], axis=1))
    positions = np.tile(np.asarray(settings.position, dtype=np.float64), (n, 1))
    if settings.translation_step_m > 0 and n > 1:
        # Per-axis steps bounded so the 3D step never exceeds translation_step_m.
        velocity = np.stack([stream(4 + axis, 4 * s) for axis in range(3)], axis=1)
        velocity *= settings.translation_step_m / np.sqrt(3.0)
        velocity[:, 2] *= 0.2  # hand-held height varies less than the horizontal position
        offset = np.zeros(3)
        for k in range(1, n):
            offset = offset + velocity[k]
            radius = np.linalg.norm(offset)
            if radius > settings.translation_radius_m > 0:
                offset *= settings.translation_radius_m / radius
            positions[k] += offset
    return WorldPoses(rotations=rotations, positions=positions)


def poses_from_tum(path, *, frames: int, position) -> WorldPoses:
    """World poses from a TUM file (its poses are read as camera-to-world, metres).

    The first ``frames`` poses are used, one per frame in line order, so their
    timestamps must increase; ``position`` (3,) offsets them in metres.
    """
    from ifmi.errors import InputError

    traj = read_tum(path)
    if len(traj) < frames:
        raise InputError(path, f"trajectory has {len(traj)} poses, expected at least {frames} frames")
    times = traj.timestamps[:frames]
    late = np.flatnonzero(np.diff(times) <= 0)
    if late.size:
        k = int(late[0]) + 1
        raise InputError(path, f"pose {k} has timestamp {times[k]:g} after {times[k - 1]:g}; expected "
                               "increasing timestamps (the poses are rendered in line order, one per frame)")
    positions = traj.positions[:frames] + np.asarray(position, dtype=np.float64)
    far = np.flatnonzero(~(np.abs(positions).max(axis=1) <= MAX_CAMERA_REACH_M))
    if far.size:
        raise InputError(path, f"pose {int(far[0])}: expected positions (plus [trajectory] position) of magnitude "
                               f"<= {MAX_CAMERA_REACH_M:.0e} m (the renderer places the camera in float32, to "
                               f"0.5 mm there; shift them with [trajectory] position), got "
                               f"{positions[far[0]].tolist()}")
    return WorldPoses(rotations=traj.rotations[:frames].copy(), positions=positions)


def poses_for_settings(settings: TrajectorySettings, *, seed: int) -> WorldPoses:
    """World poses of a scene file's trajectory table (random or from its TUM file)."""
    if settings.tum:
        return poses_from_tum(settings.tum, frames=settings.frames, position=settings.position)
    return random_trajectory(settings, seed=seed)


def relative_trajectory(poses: WorldPoses) -> Trajectory:
    """Ground truth ``T_0k`` (camera k in camera 0's frame), frame indices as timestamps."""
    r0 = poses.rotations[0]
    rotations = np.einsum("ji,njk->nik", r0, poses.rotations)
    positions = (poses.positions - poses.positions[0]) @ r0
    rotations[0] = np.eye(3)
    return Trajectory(timestamps=np.arange(len(poses), dtype=np.float64), positions=positions,
                      rotations=rotations)


def world_trajectory(poses: WorldPoses) -> Trajectory:
    """Camera-to-world poses as a TUM trajectory (frame indices as timestamps)."""
    return Trajectory(timestamps=np.arange(len(poses), dtype=np.float64),
                      positions=poses.positions.copy(), rotations=poses.rotations.copy())


def poses_at_times(poses: WorldPoses, times) -> WorldPoses:
    """Poses between the trajectory's samples: slerp for rotation, lerp for position.

    Pose ``k`` of ``poses`` is the camera at time ``k`` (times in frame
    intervals). At time ``t = k + f`` (``0 <= f < 1``) the rotation is
    ``R_k exp(f log(R_k^T R_k+1))`` -- the slerp of the two unit quaternions
    along the shorter arc -- and the position ``(1 - f) p_k + f p_k+1``. The
    omni sensor interpolates exactly so per ray (:mod:`omnisim.capture`).

    Parameters
    ----------
    poses : WorldPoses
        Camera-to-world poses at integer times 0 .. N-1.
    times : (M,) array_like
        Times in frame intervals, within ``[0, N - 1]``.

    Returns
    -------
    WorldPoses
        M poses; a time on a sample returns that sample exactly.
    """
    from scipy.spatial.transform import Rotation

    times = np.atleast_1d(np.asarray(times, dtype=np.float64))
    last = len(poses) - 1
    if times.size and (times.min() < 0 or times.max() > last):
        raise ValueError(f"expected times within [0, {last}], got [{times.min()}, {times.max()}]")
    start = np.clip(np.floor(times).astype(int), 0, max(last - 1, 0))
    fraction = times - start
    end = np.minimum(start + 1, last)
    r0, r1 = poses.rotations[start], poses.rotations[end]
    relative = Rotation.from_matrix(np.einsum("nji,njk->nik", r0, r1)).as_rotvec()
    step = Rotation.from_rotvec(relative * fraction[:, None]).as_matrix()
    rotations = np.where((fraction == 0)[:, None, None], r0, r0 @ step)
    p0, p1 = poses.positions[start], poses.positions[end]
    positions = np.where((fraction == 0)[:, None], p0, p0 + fraction[:, None] * (p1 - p0))
    return WorldPoses(rotations=rotations, positions=positions)


def trajectory_in_camera(poses: WorldPoses, *, rotation: np.ndarray, position: np.ndarray,
                         timestamps) -> Trajectory:
    """Poses expressed in the frame of one camera: ``T_c^-1 T_k`` for each pose ``T_k``.

    Parameters
    ----------
    poses : WorldPoses
        Camera-to-world poses (N of them).
    rotation : (3, 3) ndarray, keyword-only
        Camera-to-world rotation of the reference camera ``c``.
    position : (3,) ndarray, keyword-only
        Its centre, metres.
    timestamps : (N,) array_like, keyword-only
        Timestamps written with the poses.
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    rotations = np.einsum("ji,njk->nik", rotation, poses.rotations)
    positions = (poses.positions - np.asarray(position, dtype=np.float64)) @ rotation
    return Trajectory(timestamps=np.asarray(timestamps, dtype=np.float64), positions=positions,
                      rotations=rotations)
