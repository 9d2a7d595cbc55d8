"""Trajectory chaining, keyframes and failure handling with an exact fake front end."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.tracking.odometry import KeyframeOptions, track_sequence
from ifmi.pipeline import Correspondences
from ifmi.backend.relative_pose import RelativePoseOptions
from ifmi.geometry.rotations import geodesic_angle


# Exact rays: any small angular threshold works.
POSE = RelativePoseOptions(ransac_threshold_rad=1e-3)


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
    traj, records = track_sequence(frames, ExactFrontEnd(), pose_options=POSE)
    assert len(traj) == 12 and all(r.success for r in records)
    assert np.max(geodesic_angle(truth, traj.rotations)) < 1e-9
    assert [r.reference_frame for r in records] == [0] + list(range(11))


def test_frame_rows_carry_the_model_choice_and_its_evidence():
    # Exact rays of a pure rotation: the rotation model, both scores and the noise in each row.
    frames, _ = _frames(4)
    _, records = track_sequence(frames, ExactFrontEnd(), pose_options=POSE)
    for record in records[1:]:
        row = record.to_row()
        assert row["model"] == "rotation" and row["gric_rotation"] < row["gric_5pt"]
        assert row["selection_sigma_rad"] >= 0 and row["parallax_rad"] < 1e-9


def _exact_keyframe_run(n, step):
    """``(front end, records)`` of keyframe mode (0.2 rad bound) on ``n`` exact frames, checked exact."""
    frames, truth = _frames(n, step=step)
    fe = ExactFrontEnd()
    options = KeyframeOptions(enabled=True, min_inliers=10, max_angle_rad=0.2)
    traj, records = track_sequence(frames, fe, pose_options=POSE, keyframe=options)
    assert np.max(geodesic_angle(truth, traj.rotations)) < 1e-9
    return fe, records


def test_keyframes_switch_only_when_rotation_grows():
    _, records = _exact_keyframe_run(12, 0.05)
    refs = [r.reference_frame for r in records]
    # Per-frame rotation is 0.075 rad: frames 1 and 2 use keyframe 0, frame 3 is too far (0.225).
    assert refs[:4] == [0, 0, 0, 2]
    assert len(set(refs)) < len(refs) - 3
    assert all(r.rotation_rad <= 0.2 + 1e-9 for r in records)


def test_a_keyframe_left_behind_by_fast_motion_is_not_matched():
    # 0.3 rad per frame against a 0.2 rad bound: from frame 2 on, the last good frame and the
    # prediction both lie beyond the bound from the keyframe, so each frame is matched once,
    # against the frame before it.
    fe, records = _exact_keyframe_run(10, 0.2)
    assert fe.pairs == [(k - 1, k) for k in range(1, 10)]
    assert [r.reference_frame for r in records] == [0] + list(range(9))


def test_failed_frame_holds_the_previous_pose_and_tracking_continues():
    frames, truth = _frames(8)
    traj, records = track_sequence(frames, ExactFrontEnd(fail={4}), pose_options=POSE)
    assert not records[4].success and records[4].reason == "no overlap"
    assert np.allclose(traj.rotations[4], traj.rotations[3])
    # Frame 5 is estimated against frame 3, the last good frame.
    assert records[5].reference_frame == 3
    assert np.max(geodesic_angle(truth[5:], traj.rotations[5:])) < 1e-9
    assert records[4].to_row()["n_tiles"] == 0


def test_empty_sequence_gives_empty_trajectory():
    traj, records = track_sequence([], ExactFrontEnd(), pose_options=POSE)
    assert len(traj) == 0 and records == []


class CorruptFrontEnd(ExactFrontEnd):
    """Pairs that involve a frame in ``corrupt`` (as reference or as target) give random rays."""

    def __init__(self, corrupt=()):
        super().__init__()
        self.corrupt = set(corrupt)

    def correspondences(self, state_a, state_b):
        (ka, _), (kb, _) = state_a, state_b
        if ka in self.corrupt or kb in self.corrupt:
            self.pairs.append((ka, kb))
            rng = np.random.default_rng(1000 * ka + kb)
            rays = rng.normal(size=(2, len(self.world), 3))
            rays /= np.linalg.norm(rays, axis=2, keepdims=True)
            return Correspondences(rays[0] * 0, rays[1] * 0, rays[0], rays[1], {"n_tiles": 1})
        return super().correspondences(state_a, state_b)


@pytest.mark.parametrize("keyframes", [False, True])
def test_consecutive_failures_never_become_references(keyframes):
    frames, truth = _frames(12, step=0.03)
    fe = CorruptFrontEnd(corrupt={4, 5, 6})
    # Three failures in a row stay below max_failures: the last good frame stays the reference.
    options = KeyframeOptions(enabled=keyframes, min_inliers=10, max_angle_rad=0.5, max_failures=4)
    traj, records = track_sequence(frames, fe, pose_options=POSE, keyframe=options)
    assert [r.success for r in records] == [True] * 4 + [False] * 3 + [True] * 5
    # Failed frames hold the last good pose ...
    for k in (4, 5, 6):
        assert np.allclose(traj.rotations[k], traj.rotations[3])
    # ... and are never matched as references: frame 7 is estimated against a good frame.
    assert not any(a in fe.corrupt for a, _ in fe.pairs)
    assert records[7].reference_frame <= 3
    good = [k for k in range(12) if k not in fe.corrupt]
    assert np.max(geodesic_angle(truth[good], traj.rotations[good])) < 1e-9


def test_prediction_spans_failed_frames():
    class Recording(CorruptFrontEnd):
        uses_prior_rotation = True

        def correspondences(self, state_a, state_b, prior_rotation=None):
            self.priors.append((state_a[0], state_b[0], prior_rotation))
            return super().correspondences(state_a, state_b)

    frames, truth = _frames(9, step=0.03)
    fe = Recording(corrupt={4, 5})
    fe.priors = []
    track_sequence(frames, fe, pose_options=POSE, keyframe=KeyframeOptions(max_failures=3))
    # Constant angular velocity: the prediction for frame 6 from frame 3 is exact.
    a, b, prior = [p for p in fe.priors if p[:2] == (3, 6)][0]
    assert geodesic_angle(truth[3].T @ truth[6], prior) < 1e-9


class FarFrontEnd(CorruptFrontEnd):
    """As CorruptFrontEnd, and frames more than ``reach`` apart share no view (the camera moved away)."""

    def __init__(self, corrupt=(), reach=10 ** 9):
        super().__init__(corrupt)
        self.reach = reach

    def correspondences(self, state_a, state_b):
        if abs(state_b[0] - state_a[0]) > self.reach:
            self.pairs.append((state_a[0], state_b[0]))
            return Correspondences.failed("no overlap", {"n_tiles": 0})
        return super().correspondences(state_a, state_b)


def test_reference_resets_after_max_failures():
    frames, truth = _frames(10, step=0.03)
    fe = FarFrontEnd(corrupt={3, 4}, reach=2)
    # Frame 3's corruption does not stop frame 4 from being compared with frame 2, but
    # after two failures in a row frame 4 becomes the reference with the held pose.
    options = KeyframeOptions(max_failures=2)
    traj, records = track_sequence(frames, fe, pose_options=POSE, keyframe=options)
    assert "reference reset after 2 failures" in records[4].reason
    # Frame 5 fails against the corrupt frame 4, and frame 2 is out of its reach.
    assert records[5].reference_frame == 4 and not records[5].success and (2, 5) in fe.pairs
    # Frames 5 and 6 fail against the corrupt frame 4; frame 6 becomes the reference.
    assert records[6].reference_frame == 4 and "reference reset" in records[6].reason
    assert all(r.success for r in records[7:]) and records[7].reference_frame == 6
    # Tracking resumes with the rotation missed since frame 2 as a constant offset.
    offset = truth[2] @ truth[6].T
    assert np.max(geodesic_angle(offset @ truth[7:], traj.rotations[7:])) < 1e-9
    assert KeyframeOptions().max_failures > 0
    with pytest.raises(ValueError, match="max_failures"):
        KeyframeOptions(max_failures=-1)


@pytest.mark.parametrize("keyframes", [False, True])
def test_a_frame_failing_after_a_reset_recovers_on_the_frame_before_it(keyframes):
    # Frames 3-5 are corrupt (a covered lens): the reset at frame 4 makes a corrupt frame the
    # reference. Frame 6 fails against it and is matched against frame 2, the last good frame
    # before the reset: the track is back on the true chain, with no offset.
    frames, truth = _frames(10, step=0.03)
    fe = FarFrontEnd(corrupt={3, 4, 5})
    options = KeyframeOptions(enabled=keyframes, min_inliers=10, max_angle_rad=0.5, max_failures=2)
    traj, records = track_sequence(frames, fe, pose_options=POSE, keyframe=options)
    assert [r.success for r in records] == [True] * 3 + [False] * 3 + [True] * 4
    assert "reference reset" in records[4].reason and records[6].reference_frame == 2
    assert records[6].diagnostics["recovered_after_reset"]
    assert not any(r.diagnostics.get("recovered_after_reset") for r in records[7:])
    good = [0, 1, 2, 6, 7, 8, 9]
    assert np.max(geodesic_angle(truth[good], traj.rotations[good])) < 1e-9
    # Frame 5 was tried against frame 2 as well. After the recovery frame 6 is the reference
    # (frame mode) or frame 2 stays the keyframe.
    assert (2, 5) in fe.pairs
    assert [r.reference_frame for r in records[7:]] == ([2, 2, 2] if keyframes else [6, 7, 8])


def test_a_weak_match_does_not_recover_the_track():
    # As above, but the recovery pair (2, 6) keeps only 20 of its rays, fewer than
    # min_inliers: frame 6 fails, and the reference resets again (frame 6 with the held pose).
    class Weak(FarFrontEnd):
        def correspondences(self, state_a, state_b):
            corr = super().correspondences(state_a, state_b)
            if (state_a[0], state_b[0]) == (2, 6):
                return Correspondences(corr.pixels_a[:20], corr.pixels_b[:20], corr.rays_a[:20],
                                       corr.rays_b[:20], corr.diagnostics)
            return corr

    frames, truth = _frames(10, step=0.03)
    fe = Weak(corrupt={3, 4, 5})
    options = KeyframeOptions(min_inliers=40, max_failures=2)
    traj, records = track_sequence(frames, fe, pose_options=POSE, keyframe=options)
    assert (2, 6) in fe.pairs and not records[6].success and "reference reset" in records[6].reason
    assert not any(r.diagnostics.get("recovered_after_reset") for r in records)


def test_each_finished_frame_is_reported_in_order():
    frames, _ = _frames(5)
    seen = []
    traj, records = track_sequence(frames, ExactFrontEnd(fail={2}), pose_options=POSE,
                                   on_frame=seen.append)
    assert [r.frame for r in seen] == [0, 1, 2, 3, 4]
    assert seen == records and not seen[2].success


def test_tracker_steps_frame_by_frame_with_a_given_pose_solver():
    from ifmi.tracking.odometry import Tracker
    from ifmi.backend.relative_pose import relative_pose_from_rays

    calls = []

    def counting_solver(rays_a, rays_b, **kwargs):
        calls.append(len(rays_a))
        return relative_pose_from_rays(rays_a, rays_b, **kwargs)

    frames, truth = _frames(6)
    tracker = Tracker(ExactFrontEnd(), pose_options=POSE, pose_solver=counting_solver)
    records = [tracker.step(frame) for frame in frames]
    assert [r.frame for r in records] == list(range(6)) and all(r.success for r in records)
    assert len(calls) == 5
    assert np.max(geodesic_angle(truth, tracker.trajectory().rotations)) < 1e-9


class NoisyFrontEnd(ExactFrontEnd):
    """Exact rays with seeded Gaussian noise of 1e-3 rad per axis on both frames of each pair."""

    def correspondences(self, state_a, state_b):
        corr = super().correspondences(state_a, state_b)
        rng = np.random.default_rng(state_b[0])
        noisy = [r + rng.normal(0.0, 1e-3, r.shape) for r in (corr.rays_a, corr.rays_b)]
        noisy = [r / np.linalg.norm(r, axis=1, keepdims=True) for r in noisy]
        return Correspondences(corr.pixels_a, corr.pixels_b, *noisy, corr.diagnostics)


def _options_given_to_each_pair(**changes) -> tuple[list, list]:
    """Track six noisy frames with ``POSE`` changed by ``changes``: the back-end options each pair was
    solved with, and the frame records."""
    from dataclasses import replace

    from ifmi.tracking.odometry import Tracker
    from ifmi.backend.relative_pose import relative_pose_from_rays

    given = []

    def recording_solver(rays_a, rays_b, *, options, **kwargs):
        given.append(options)
        return relative_pose_from_rays(rays_a, rays_b, options=options, **kwargs)

    tracker = Tracker(NoisyFrontEnd(), pose_options=replace(POSE, ransac_threshold_rad=6e-3, **changes),
                      pose_solver=recording_solver)
    records = [tracker.step(frame) for frame in _frames(6)[0]]
    assert all(r.success for r in records)
    return given, records


@pytest.mark.parametrize("pooled", [True, False])
def test_each_pair_is_given_the_earlier_pairs_noise_as_its_prior(pooled):
    options, records = _options_given_to_each_pair(sequence_noise_prior=pooled)
    given = [(o.noise_prior_rms_rad, o.noise_prior_measurements) for o in options]
    evidence = np.array([(r.diagnostics["noise_rms_rad"], r.diagnostics["noise_measurements"])
                         for r in records[1:]])
    # The epipolar angle's noise is that of both rays: sqrt(2) * 1e-3 rad, over 75 degrees of freedom.
    assert np.all(np.abs(evidence[:, 0] / (np.sqrt(2.0) * 1e-3) - 1.0) < 0.3) and np.all(evidence[:, 1] == 75)
    if not pooled:
        assert given == [(None, 0.0)] * 5
        return
    assert given[0] == (None, 0.0)
    for k in range(1, 5):
        assert given[k] == pytest.approx(tuple(np.median(evidence[:k], axis=0)), rel=1e-12)


@pytest.mark.parametrize("pooled", [True, False])
def test_each_pair_is_given_the_share_of_translated_pairs_as_its_prior(pooled):
    from ifmi.backend.relative_pose import ModelSelection

    options, records = _options_given_to_each_pair(sequence_model_prior=pooled)
    given = [o.translation_prior for o in options]
    if not pooled:
        assert given == [None] * 5
        return
    # Laplace's rule of succession over the earlier pairs' own evidence (their scores without a prior).
    shown = [ModelSelection(**{key: r.diagnostics[key] for key in ("gric_rotation", "gric_5pt", "gric_homography")}
                            ).evidence_prefers_translation for r in records[1:]]
    assert given == [pytest.approx((sum(shown[:k]) + 1) / (k + 2), rel=1e-12) for k in range(5)]
    assert [r.diagnostics["translation_prior"] for r in records[1:]] == pytest.approx(given, rel=1e-12)


def test_front_end_is_told_the_pose_of_every_successful_frame_only():
    class Accepting(CorruptFrontEnd):
        def accept_pose(self, state, rotation):
            self.accepted.append((state[0], rotation))

    frames, truth = _frames(8, step=0.03)
    fe = Accepting(corrupt={3})
    fe.accepted = []
    traj, records = track_sequence(frames, fe, pose_options=POSE, keyframe=KeyframeOptions(max_failures=3))
    assert [k for k, _ in fe.accepted] == [k for k, r in enumerate(records) if r.success] == [0, 1, 2, 4, 5, 6, 7]
    for k, rotation in fe.accepted:
        assert np.array_equal(rotation, traj.rotations[k])
        assert geodesic_angle(truth[k], rotation) < 1e-9


class RefiningFrontEnd(ExactFrontEnd):
    """Rays of frame b turned by ``error`` (a biased first match); ``refine_correspondences`` gives
    the exact rays (``refined`` of them, 80 at most), or None when ``refined`` is 0."""

    def __init__(self, error, refined=80):
        super().__init__()
        self.error, self.refined, self.refine_calls = error, refined, []

    def correspondences(self, state_a, state_b):
        first = super().correspondences(state_a, state_b)
        return Correspondences(first.pixels_a, first.pixels_b, first.rays_a, first.rays_b @ self.error.T,
                               {"n_tiles": 1})

    def refine_correspondences(self, state_a, state_b, first, *, rotation_ab):
        self.refine_calls.append((state_a[0], state_b[0], rotation_ab))
        if not self.refined:
            return None
        exact = super().correspondences(state_a, state_b)
        n = self.refined
        return Correspondences(exact.pixels_a[:n], exact.pixels_b[:n], exact.rays_a[:n], exact.rays_b[:n],
                               {"n_tiles": 1, "refined": True})


@pytest.mark.parametrize("refined", [80, 0, 3])
def test_correspondences_refined_at_the_solved_pose_are_solved_again(refined):
    # The first match is biased by 0.01 rad; the front end is passed the rotation solved from it
    # and may return other rays, which replace the first solution when they solve (80 exact rays).
    # None (0) or too few rays to solve (3) keep the first solution.
    error = Rotation.from_rotvec([0.0, 0.01, 0.0]).as_matrix()
    frames, truth = _frames(5)
    fe = RefiningFrontEnd(error, refined=refined)
    traj, records = track_sequence(frames, fe, pose_options=POSE)
    assert all(r.success for r in records)
    assert [(a, b) for a, b, _ in fe.refine_calls] == [(k - 1, k) for k in range(1, 5)]
    for (a, b, rotation_ab) in fe.refine_calls:
        assert abs(geodesic_angle(truth[a].T @ truth[b], rotation_ab) - 0.01) < 1e-6
    relative = [geodesic_angle(truth[k - 1].T @ truth[k], traj.rotations[k - 1].T @ traj.rotations[k])
                for k in range(1, 5)]
    if refined == 80:
        assert max(relative) < 1e-9 and all(r.diagnostics.get("refined") for r in records[1:])
    else:
        assert np.allclose(relative, 0.01, atol=1e-6) and not any(r.diagnostics.get("refined") for r in records)




class BackgroundFrontEnd(ExactFrontEnd):
    """An exact front end whose frames are prepared in the background: it notes each ``prepare``
    and whether it ran off the main thread."""

    prepares_in_background = True

    def __init__(self, fail=()):
        super().__init__(fail)
        import threading

        self._main = threading.get_ident()
        self._thread = threading.get_ident
        self.prepared, self.in_background = [], []

    def prepare(self, image):
        self.prepared.append(image[0])
        self.in_background.append(self._thread() != self._main)
        return image


def test_a_front_end_prepared_in_the_background_gives_the_same_estimate_in_order():
    from ifmi.frames import MissingFrame

    frames, truth = _frames(8)
    frames[5] = MissingFrame("frame 5", "unreadable")
    plain_traj, plain = track_sequence(frames, ExactFrontEnd(fail={3}), pose_options=POSE)
    fe = BackgroundFrontEnd(fail={3})
    traj, records = track_sequence(frames, fe, pose_options=POSE)
    assert np.array_equal(traj.rotations, plain_traj.rotations)
    assert [(r.frame, r.success, r.reference_frame) for r in records] == \
        [(r.frame, r.success, r.reference_frame) for r in plain]
    # Every frame but the missing one prepared once, in order, off the main thread.
    assert fe.prepared == [0, 1, 2, 3, 4, 6, 7] and all(fe.in_background)
    assert all(r.to_row()["t_prepare_ms"] >= 0 for r in records if r.frame != 5)
    assert not records[5].success and "unreadable" in records[5].reason
