"""Wide coarse search: a wrong yaw from a smeared whole-panorama correlation is replaced."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.spectral.global_motion import GlobalMotion, GlobalMotionConfig, GlobalMotionEstimator, rotation_from_ray_pairs
from ifmi.geometry.rotations import geodesic_angle
from ifmi.tracking.odometry import track_sequence
from ifmi.backend.relative_pose import RelativePoseOptions
from ifmi.spectral import pair_pipeline as pair_pipeline
from ifmi.spectral.ifmi_front_end import IfmiConfig, IfmiFrontEnd, RecoveryOptions
from ifmi.synthetic import environment_texture, omni_from_environment
from ifmi.spectral.panorama import PanoramaConfig, panorama_image_from_omni_image, panorama_mapping

SIZE = 200
MODEL = paracatadioptric_model((SIZE, SIZE), horizon_radius_px=60.0)
BAND = (20.0, 95.0)
PANORAMA = PanoramaConfig(radius_min_px=BAND[0], radius_max_px=BAND[1])
# R_01 of the pair: 30 degrees of yaw and 10 of tilt, as between lawn frames taken every 10th.
TRUTH = (Rotation.from_rotvec(np.radians(10.0) * np.array([np.cos(0.4), np.sin(0.4), 0.0]))
         * Rotation.from_euler("z", -30.0, degrees=True)).as_matrix()
# What a smeared correlation gave on such pairs: the right tilt at a yaw 145 degrees off.
WRONG = TRUTH @ Rotation.from_euler("z", 145.0, degrees=True).as_matrix()


@pytest.fixture(scope="module")
def texture():
    return environment_texture(height=360, seed=5)


def _coarse_pair(texture, estimator, mapping):
    return [estimator.coarse_panorama(panorama_image_from_omni_image(
        mapping, omni_from_environment(texture, MODEL, r, band_px=BAND))) for r in (np.eye(3), TRUTH)]


def _estimator(config=GlobalMotionConfig()):
    mapping = panorama_mapping(MODEL, config=PANORAMA)
    return GlobalMotionEstimator(mapping, config=config), mapping


def test_the_wide_search_replaces_a_wrong_yaw(texture):
    estimator, mapping = _estimator()
    a, b = _coarse_pair(texture, estimator, mapping)
    wrong_score = estimator.score(a, estimator.warped(b, WRONG))
    found = estimator.wide_search(a, b, start=None, current_score=wrong_score)
    assert found is not None and found.success
    # Measured 0.12 degree; a coarse pixel is 2.8 degrees.
    assert np.degrees(geodesic_angle(TRUTH, found.rotation)) < 1.0
    assert 1.0 - found.score <= 0.5 * (1.0 - wrong_score)
    assert estimator.clearly_better(found, current_rotation=WRONG, current_score=wrong_score)


def test_the_wide_search_leaves_a_right_rotation_alone(texture):
    estimator, mapping = _estimator()
    a, b = _coarse_pair(texture, estimator, mapping)
    right = estimator.estimate(a, b)
    assert np.degrees(geodesic_angle(TRUTH, right.rotation)) < 1.0
    found = estimator.wide_search(a, b, start=None, current_score=right.score)
    # Nothing matches better, or only a rotation next to it that does not clearly replace it.
    assert found is None or (found.score > right.score and np.degrees(geodesic_angle(TRUTH, found.rotation)) < 1.0
                             and not estimator.clearly_better(found, current_rotation=right.rotation,
                                                              current_score=right.score))


@pytest.mark.parametrize("every_start, searches", [(False, 2), (True, 8)])
def test_the_wide_search_refines_the_clearest_starts_or_every_start(texture, monkeypatch, every_start, searches):
    estimator, mapping = _estimator()
    a, b = _coarse_pair(texture, estimator, mapping)
    starts = []
    search = GlobalMotionEstimator._search

    def counted(self, reference, coarse_b, start):
        starts.append(start)
        return search(self, reference, coarse_b, start)

    monkeypatch.setattr(GlobalMotionEstimator, "_search", counted)
    wrong_score = estimator.score(a, estimator.warped(b, WRONG))
    found = estimator.wide_search(a, b, start=None, current_score=wrong_score, every_start=every_start)
    # The default grid: 8 starts tilted by 8 degrees; wide_candidates 2 of them by default.
    assert len(starts) == searches and len({s.tobytes() for s in starts}) == searches
    assert found is not None and np.degrees(geodesic_angle(TRUTH, found.rotation)) < 1.0


def test_a_near_or_slightly_better_result_is_not_clearly_better(texture):
    estimator, mapping = _estimator()
    a, b = _coarse_pair(texture, estimator, mapping)
    wrong_score = estimator.score(a, estimator.warped(b, WRONG))
    right = GlobalMotion(TRUTH, True, "", 2.0, 12, estimator.score(a, estimator.warped(b, TRUTH)))
    # Far and clearly better; the same rotation nudged by 0.05 rad (under confirm_angle_rad) is not far.
    assert estimator.clearly_better(right, current_rotation=WRONG, current_score=wrong_score)
    nudged = TRUTH @ Rotation.from_euler("x", 0.05).as_matrix()
    assert not estimator.clearly_better(right, current_rotation=nudged, current_score=wrong_score)
    # Far but leaving more than wide_mismatch_ratio (0.5) of the mismatch: 0.6 of it.
    slightly = replace(right, score=1.0 - 0.6 * (1.0 - wrong_score))
    assert not estimator.clearly_better(slightly, current_rotation=WRONG, current_score=wrong_score)


def test_the_wide_search_can_be_turned_off(texture):
    estimator, mapping = _estimator(GlobalMotionConfig(wide_tilt_max_deg=0.0))
    a, b = _coarse_pair(texture, estimator, mapping)
    wrong_score = estimator.score(a, estimator.warped(b, WRONG))
    assert estimator.wide_search(a, b, start=None, current_score=wrong_score) is None


def _coarse_stage_returns(monkeypatch, rotation, score):
    monkeypatch.setattr(GlobalMotionEstimator, "estimate",
                        lambda self, coarse_a, coarse_b, *, priors=(None,): GlobalMotion(rotation, True, "", 1.3,
                                                                                          12, score))


def test_the_front_end_searches_wide_when_the_tiles_fail(texture, monkeypatch):
    config = IfmiConfig(panorama=PANORAMA, recovery=RecoveryOptions(dense_retry_fraction=0.0))
    front_end = IfmiFrontEnd(MODEL, config)
    a, b = (front_end.prepare(omni_from_environment(texture, MODEL, r, band_px=BAND)) for r in (np.eye(3), TRUTH))
    score = front_end.global_stage.score(a.coarse_panorama, front_end.global_stage.warped(b.coarse_panorama, WRONG))
    # The coarse stage (from the prediction and on re-acquisition) lands on the wrong yaw.
    _coarse_stage_returns(monkeypatch, WRONG, score)
    pair = front_end.correspondences(a, b, prior_rotation=np.eye(3))
    assert pair.success and pair.diagnostics["wide_search"]
    assert b.tracked_valid.sum() == pair.diagnostics["n_tiles_kept"] >= config.rays.min_tiles
    # Measured 0.026 degree (noise-free synthetic frames).
    assert np.degrees(geodesic_angle(TRUTH, rotation_from_ray_pairs(pair.rays_a, pair.rays_b))) < 0.1
    # Without the wide search the tiles at the wrong yaw cannot pass: the pair fails.
    plain = IfmiFrontEnd(MODEL, replace(config, recovery=replace(config.recovery, wide_search_fraction=0.0)))
    a, b = (plain.prepare(omni_from_environment(texture, MODEL, r, band_px=BAND)) for r in (np.eye(3), TRUTH))
    failed = plain.correspondences(a, b, prior_rotation=np.eye(3))
    assert not failed.success and "wide_search" not in failed.diagnostics


def _frames(front_end, texture):
    return [front_end.prepare(omni_from_environment(texture, MODEL, r, band_px=BAND)) for r in (np.eye(3), TRUTH)]


def test_the_front_end_searches_wide_when_the_coarse_stage_kept_the_prediction(texture, monkeypatch):
    # The first pair of a sequence: the prediction is the identity, 31 degrees from R_01. When the
    # coarse stage's own search matches worse than its start it returns the start unchanged; the
    # tiles then fail there, and the failing pair is rescued by the wide search.
    config = IfmiConfig(panorama=PANORAMA, recovery=RecoveryOptions(dense_retry_fraction=0.0))
    front_end = IfmiFrontEnd(MODEL, config)
    a, b = _frames(front_end, texture)
    score = front_end.global_stage.score(a.coarse_panorama, b.coarse_panorama)
    monkeypatch.setattr(GlobalMotionEstimator, "estimate",
                        lambda self, coarse_a, coarse_b, *, priors=(None,): GlobalMotion(np.eye(3), True, "", 1.3,
                                                                                          0, score))
    failed = pair_pipeline.matched(front_end, a, b, np.eye(3))
    assert not failed.correspondences.success
    pair = pair_pipeline.rescued(front_end, a, b, failed, np.eye(3)).correspondences
    assert pair.success and pair.diagnostics["wide_search"] and pair.diagnostics["wide_rescue"]
    # Measured 0.026 degree, as from the wrong yaw above.
    assert np.degrees(geodesic_angle(TRUTH, rotation_from_ray_pairs(pair.rays_a, pair.rays_b))) < 0.1


def test_a_failing_pair_takes_a_rotation_that_only_matches_better(texture, monkeypatch):
    # Under parallax every coarse rotation leaves most of the mismatch, so the wide search's result
    # cannot be clearly better by its score; a pair that would fail takes it when its tiles pass.
    # The coarse stage is told here that the wrong yaw matches almost as well as the truth.
    config = IfmiConfig(panorama=PANORAMA, recovery=RecoveryOptions(dense_retry_fraction=0.0))
    front_end = IfmiFrontEnd(MODEL, config)
    a, b = _frames(front_end, texture)
    stage = front_end.global_stage
    close = stage.score(a.coarse_panorama, stage.warped(b.coarse_panorama, TRUTH)) - 0.02
    _coarse_stage_returns(monkeypatch, WRONG, close)
    found = stage.wide_search(a.coarse_panorama, b.coarse_panorama, start=None, current_score=close)
    assert found is not None and not stage.clearly_better(found, current_rotation=WRONG, current_score=close)
    failed = pair_pipeline.matched(front_end, a, b, np.eye(3))
    assert not failed.correspondences.success
    rescued = pair_pipeline.rescued(front_end, a, b, failed, np.eye(3))
    pair = rescued.correspondences
    assert pair.success and pair.diagnostics["wide_search"] and pair.diagnostics["wide_rescue"]
    # Frame b would keep the rescue's registration.
    assert rescued.kept.tracked_valid.sum() == pair.diagnostics["n_tiles_kept"] >= config.rays.min_tiles
    assert np.degrees(geodesic_angle(TRUTH, rotation_from_ray_pairs(pair.rays_a, pair.rays_b))) < 0.1
    # Without the wide search there is nothing to rescue with.
    plain = IfmiFrontEnd(MODEL, replace(config, recovery=replace(config.recovery, wide_search_fraction=0.0)))
    a, b = _frames(plain, texture)
    failed = pair_pipeline.matched(plain, a, b, np.eye(3))
    assert not failed.correspondences.success and "wide_search" not in failed.correspondences.diagnostics
    assert pair_pipeline.rescued(plain, a, b, failed, np.eye(3)) is None


def test_a_rescue_whose_tiles_fail_leaves_the_failed_pair(texture, monkeypatch):
    # Frame b shows another scene: the wide search finds some rotation matching better than the
    # coarse stage's (observed below), its tiles fail too, and the pair keeps its first
    # registration, as without a rescue; nothing of frame b changes.
    other = omni_from_environment(environment_texture(height=360, seed=9), MODEL, np.eye(3), band_px=BAND)
    found = []
    search = GlobalMotionEstimator.wide_search

    def observed(self, *args, **kwargs):
        found.append(search(self, *args, **kwargs))
        return found[-1]

    monkeypatch.setattr(GlobalMotionEstimator, "wide_search", observed)
    front_end = IfmiFrontEnd(MODEL, IfmiConfig(panorama=PANORAMA, recovery=RecoveryOptions(dense_retry_fraction=0.0)))
    a = front_end.prepare(omni_from_environment(texture, MODEL, np.eye(3), band_px=BAND))
    b = front_end.prepare(other)
    failed = front_end.correspondences(a, b, prior_rotation=np.eye(3))
    assert not failed.success
    matched = pair_pipeline.matched(front_end, a, b, np.eye(3))
    kept = (b.tracked_valid.copy(), b.tracked.offsets.copy())
    found.clear()
    assert pair_pipeline.rescued(front_end, a, b, matched, np.eye(3)) is None
    assert len(found) == 1 and found[0] is not None
    np.testing.assert_array_equal(b.tracked_valid, kept[0])
    np.testing.assert_array_equal(b.tracked.offsets, kept[1])


def test_a_pair_whose_tiles_fail_at_the_prediction_is_reacquired_from_the_identity(texture, monkeypatch):
    # The coarse stage lands on the wrong yaw from the prediction and on the truth from the identity
    # (a lost track: the prediction is far off); the re-acquisition's registration keeps more tiles.
    config = IfmiConfig(panorama=PANORAMA, recovery=RecoveryOptions(dense_retry_fraction=0.0,
                                                                    wide_search_fraction=0.0))
    front_end = IfmiFrontEnd(MODEL, config)
    a, b = _frames(front_end, texture)
    starts = []

    def estimate(self, coarse_a, coarse_b, *, priors=(None,)):
        starts.append(priors[0])
        return GlobalMotion(WRONG if priors[0] is not None else TRUTH, True, "", 1.3, 12, 0.1)

    monkeypatch.setattr(GlobalMotionEstimator, "estimate", estimate)
    pair = pair_pipeline.matched(front_end, a, b, np.eye(3))
    assert len(starts) == 2 and starts[0] is not None and starts[1] is None
    corr = pair.correspondences
    assert corr.success and corr.diagnostics["reacquired"] and pair.kept.rotation is TRUTH
    assert corr.diagnostics["n_tiles_kept"] >= config.rays.min_tiles
    # Measured 0.03 degree (noise-free synthetic frames).
    assert np.degrees(geodesic_angle(TRUTH, rotation_from_ray_pairs(corr.rays_a, corr.rays_b))) < 0.1


def test_there_is_no_rescue_without_a_prediction_or_twice(texture, monkeypatch):
    front_end = IfmiFrontEnd(MODEL, IfmiConfig(panorama=PANORAMA, recovery=RecoveryOptions(
        dense_retry_fraction=0.0, wide_search_fraction=0.0)))
    a, b = _frames(front_end, texture)
    # The coarse stage lands on the wrong yaw (and the first wide search is off): the pair fails.
    _coarse_stage_returns(monkeypatch, WRONG, 0.1)
    failed = pair_pipeline.matched(front_end, a, b, np.eye(3))
    assert not failed.correspondences.success
    front_end.config = replace(front_end.config, recovery=RecoveryOptions(dense_retry_fraction=0.0))
    assert pair_pipeline.rescued(front_end, a, b, failed, None) is None
    rescued = pair_pipeline.rescued(front_end, a, b, failed, np.eye(3))
    assert rescued is not None and rescued.correspondences.success
    assert pair_pipeline.rescued(front_end, a, b, rescued, np.eye(3)) is None


def test_the_odometry_rescues_a_first_pair_the_coarse_stage_kept(texture, monkeypatch):
    # As above, the coarse stage keeps the identity for R_01 (31 degrees off) and the tiles fail
    # there; the tracker passes the failure to the front end's rescue and chains its solution.
    config = IfmiConfig(panorama=PANORAMA, recovery=RecoveryOptions(dense_retry_fraction=0.0))
    frames = [omni_from_environment(texture, MODEL, r, band_px=BAND) for r in (np.eye(3), TRUTH)]
    original = GlobalMotionEstimator.estimate
    monkeypatch.setattr(GlobalMotionEstimator, "estimate",
                        lambda self, coarse_a, coarse_b, *, priors=(None,):
                        replace(original(self, coarse_a, coarse_b, priors=priors), rotation=np.eye(3), n_sectors=0,
                                score=self.score(coarse_a, coarse_b)))
    options = RelativePoseOptions(ransac_threshold_rad=0.01, seed=0)
    trajectory, records = track_sequence(frames, IfmiFrontEnd(MODEL, config), pose_options=options)
    assert records[1].success and records[1].diagnostics["wide_rescue"]
    assert np.degrees(geodesic_angle(TRUTH, trajectory.rotations[1])) < 0.1
    # Without the wide search the first pair fails and frame 1 keeps frame 0's pose.
    _, plain = track_sequence(frames, IfmiFrontEnd(MODEL, replace(config, recovery=replace(config.recovery, wide_search_fraction=0.0))),
                              pose_options=options)
    assert not plain[1].success


@pytest.mark.parametrize("kwargs, name", [({"wide_tilt_max_deg": -1.0}, "wide_tilt_max_deg"),
                                          ({"wide_tilt_step_deg": 0.0}, "wide_tilt_step_deg"),
                                          ({"wide_mismatch_ratio": 1.5}, "wide_mismatch_ratio"),
                                          ({"wide_candidates": 0}, "wide_candidates")])
def test_wide_search_options_are_checked(kwargs, name):
    with pytest.raises(ValueError, match=name):
        GlobalMotionConfig(**kwargs)


def test_wide_search_fraction_is_checked():
    with pytest.raises(ValueError, match="wide_search_fraction"):
        RecoveryOptions(wide_search_fraction=1.5)
