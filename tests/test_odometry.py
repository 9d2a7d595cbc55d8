"""Trajectory chaining, keyframes and failure handling with an exact fake front end."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ifmi.odometry import KeyframeOptions, track_sequence
from ifmi.pipeline import Correspondences
from ifmi.relative_pose import RelativePoseOptions
from ifmi.rotations import geodesic_angle


class ExactFrontEnd:
    """Frames are their orientation R_0k; rays are exact, frames listed in ``fail`` match nothing."""

    def __init__(self, fail=()):
        self.fail = set(fail)
        rng = np.random.default_rng(0)
        rays = rng.normal(size=(80, 3))
        self.world = rays / np.linalg.norm(rays, axis=1, keepdims=True)
        self.pairs = []

    def prepare(self, image):
        return image

    def correspondences(self, state_a, state_b):
        (ka, ra), (kb, rb) = state_a, state_b
        self.pairs.append((ka, kb))
        if kb in self.fail:
            return Correspondences.failed("no overlap", {"n_tiles": 0})
        rays_a = self.world @ ra  # world -> camera a: R_0a^T w
        rays_b = self.world @ rb
        return Correspondences(rays_a * 0, rays_b * 0, rays_a, rays_b, {"n_tiles": 1})


def _frames(n, step=0.02):
    rot = Rotation.from_rotvec(np.outer(np.arange(n), [step, -step / 2, step])).as_matrix()
    return [(k, rot[k]) for k in range(n)], rot


def test_frame_to_frame_chaining_is_exact():
    frames, truth = _frames(12)
    traj, records = track_sequence(frames, ExactFrontEnd(), pose_options=RelativePoseOptions())
    assert len(traj) == 12 and all(r.success for r in records)
    assert np.max(geodesic_angle(truth, traj.rotations)) < 1e-9
    assert [r.reference_frame for r in records] == [0] + list(range(11))


def test_keyframes_switch_only_when_rotation_grows():
    frames, truth = _frames(12, step=0.05)
    fe = ExactFrontEnd()
    options = KeyframeOptions(enabled=True, min_inliers=10, max_angle_rad=0.2)
    traj, records = track_sequence(frames, fe, pose_options=RelativePoseOptions(), keyframe=options)
    assert np.max(geodesic_angle(truth, traj.rotations)) < 1e-9
    refs = [r.reference_frame for r in records]
    # Per-frame rotation is 0.075 rad: frames 1 and 2 use keyframe 0, frame 3 is too far (0.225).
    assert refs[:4] == [0, 0, 0, 2]
    assert len(set(refs)) < len(refs) - 3
    assert all(r.rotation_rad <= 0.2 + 1e-9 for r in records)


def test_failed_frame_holds_the_previous_pose_and_tracking_continues():
    frames, truth = _frames(8)
    traj, records = track_sequence(frames, ExactFrontEnd(fail={4}), pose_options=RelativePoseOptions())
    assert not records[4].success and records[4].reason == "no overlap"
    assert np.allclose(traj.rotations[4], traj.rotations[3])
    # Frame 5 is estimated against frame 3, the last good frame.
    assert records[5].reference_frame == 3
    assert np.max(geodesic_angle(truth[5:], traj.rotations[5:])) < 1e-9
    assert records[4].to_row()["n_tiles"] == 0


def test_empty_sequence_gives_empty_trajectory():
    traj, records = track_sequence([], ExactFrontEnd(), pose_options=RelativePoseOptions())
    assert len(traj) == 0 and records == []
