"""Coarse global stage: large yaw and tilt from whole panoramas, re-acquisition after abrupt motion."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.spectral.global_motion import GlobalMotionConfig, GlobalMotionEstimator, rotation_from_ray_pairs
from ifmi.geometry.rotations import geodesic_angle
from ifmi.spectral.ifmi_front_end import CoarseOptions, RecoveryOptions
from ifmi.synthetic import environment_texture, omni_from_environment
from ifmi.spectral.panorama import PanoramaConfig, panorama_image_from_omni_image, panorama_mapping

SIZE = 200
MODEL = paracatadioptric_model((SIZE, SIZE), horizon_radius_px=60.0)
BAND = (20.0, 95.0)


@pytest.fixture(scope="module")
def scene():
    texture = environment_texture(height=360, seed=2)
    mapping = panorama_mapping(MODEL, config=PanoramaConfig(radius_min_px=BAND[0], radius_max_px=BAND[1]))
    return texture, mapping


def _coarse(texture, mapping, estimator, rotation_0k):
    image = omni_from_environment(texture, MODEL, rotation_0k, band_px=BAND)
    return estimator.coarse_panorama(panorama_image_from_omni_image(mapping, image))


def _rotation(yaw_deg, tilt_deg, tilt_axis_deg):
    axis = np.radians(tilt_axis_deg)
    tilt = Rotation.from_rotvec(np.radians(tilt_deg) * np.array([np.cos(axis), np.sin(axis), 0.0]))
    return (tilt * Rotation.from_euler("z", yaw_deg, degrees=True)).as_matrix()


@pytest.mark.parametrize("yaw, tilt, axis", [(100.0, 6.0, 40.0), (-150.0, 12.0, 200.0), (35.0, 0.0, 0.0),
                                             (-8.0, 15.0, 300.0)])
def test_large_yaw_and_tilt_are_recovered_from_the_identity(scene, yaw, tilt, axis):
    texture, mapping = scene
    estimator = GlobalMotionEstimator(mapping)
    truth = _rotation(yaw, tilt, axis)  # R_01: frame 0 is the identity
    a = _coarse(texture, mapping, estimator, np.eye(3))
    b = _coarse(texture, mapping, estimator, truth)
    result = estimator.estimate(a, b)
    assert result.success and result.n_sectors >= 6
    # A coarse pixel here is 360/128 = 2.8 degrees; measured errors 0.08 to 0.44 degree.
    assert np.degrees(geodesic_angle(truth, result.rotation)) < 1.0


def test_a_wrong_prediction_is_corrected_and_a_good_one_kept(scene):
    texture, mapping = scene
    estimator = GlobalMotionEstimator(mapping)
    truth = _rotation(-25.0, 8.0, 120.0)
    a = _coarse(texture, mapping, estimator, np.eye(3))
    b = _coarse(texture, mapping, estimator, truth)
    # 40 degrees off in yaw and 10 in tilt: the search starts there and finds the truth.
    wrong = _rotation(15.0, 10.0, 300.0)
    found = estimator.estimate(a, b, priors=(wrong, None))
    assert np.degrees(geodesic_angle(truth, found.rotation)) < 1.0
    # A prediction within half a coarse pixel is returned as it is (no sector passes).
    near = truth @ Rotation.from_euler("z", 0.5, degrees=True).as_matrix()
    kept = estimator.estimate(a, b, priors=(near, None))
    assert np.array_equal(kept.rotation, near) and kept.n_sectors == 0


def test_a_start_equal_to_one_searched_is_not_searched_again(scene, monkeypatch):
    # The first pair of a sequence predicts the identity, which is also the re-acquisition start:
    # one search gives the result of searching from both.
    texture, mapping = scene
    estimator = GlobalMotionEstimator(mapping)
    truth = _rotation(-40.0, 6.0, 70.0)
    a = _coarse(texture, mapping, estimator, np.eye(3))
    b = _coarse(texture, mapping, estimator, truth)
    alone = estimator.estimate(a, b)
    searches = []
    original = GlobalMotionEstimator._search
    monkeypatch.setattr(GlobalMotionEstimator, "_search",
                        lambda self, *args: searches.append(1) or original(self, *args))
    both = estimator.estimate(a, b, priors=(np.eye(3), None))
    assert len(searches) == 1 and np.array_equal(both.rotation, alone.rotation)
    assert np.degrees(geodesic_angle(truth, both.rotation)) < 1.0
    # A different second start is searched: the first moved the identity by more than 0.1 rad.
    estimator.estimate(a, b, priors=(np.eye(3), truth))
    assert len(searches) == 3


def test_a_half_turn_of_a_symmetric_scene_does_not_replace_the_prediction(scene, monkeypatch):
    # A scene that repeats after half a turn (each half of the environment the same texture, as
    # a room with one texture on every wall seen from near its middle): the panorama turned half
    # round matches as well as the true one. The prediction is 8 degrees off, so the search from
    # it moves it past confirm_angle_rad and the identity is searched too.
    _, mapping = scene
    texture = environment_texture(height=360, seed=2)
    half = texture.shape[1] // 2
    periodic = np.concatenate([texture[:, :half], texture[:, :half]], axis=1)
    truth = _rotation(-25.0, 6.0, 120.0)
    prediction = Rotation.from_rotvec([0.0, 0.08, 0.12]).as_matrix() @ truth
    searched = {}
    original = GlobalMotionEstimator._search

    def search(self, reference, coarse_b, start):
        found = original(self, reference, coarse_b, start)
        searched["prediction" if np.array_equal(start, prediction) else "identity"] = found[0]
        return found

    monkeypatch.setattr(GlobalMotionEstimator, "_search", search)
    results = {}
    for ratio in (1.0, 0.5):
        estimator = GlobalMotionEstimator(mapping, config=GlobalMotionConfig(confirm_mismatch_ratio=ratio))
        a = _coarse(periodic, mapping, estimator, np.eye(3))
        b = _coarse(periodic, mapping, estimator, truth)
        results[ratio] = estimator.estimate(a, b, priors=(prediction, None))
    # The premise: from the prediction the search finds the truth, from the identity the half
    # turn, which matches a little better (0.9622 against 0.9621).
    near, far = searched["prediction"], searched["identity"]
    assert np.degrees(geodesic_angle(truth, near.rotation)) < 1.0
    assert np.degrees(geodesic_angle(truth, far.rotation)) > 170.0 and far.score > near.score
    # Any better match replacing the prediction's (ratio 1) took the half turn; the default asks a
    # result that far to leave at most half the mismatch, and keeps the truth.
    assert np.degrees(geodesic_angle(truth, results[1.0].rotation)) > 170.0
    assert np.degrees(geodesic_angle(truth, results[0.5].rotation)) < 1.0


def test_kabsch_fit_is_exact_on_exact_rays():
    rng = np.random.default_rng(3)
    rays_b = rng.normal(size=(10, 3))
    rays_b /= np.linalg.norm(rays_b, axis=1, keepdims=True)
    truth = Rotation.from_rotvec([0.3, -1.2, 2.0]).as_matrix()
    fitted = rotation_from_ray_pairs(rays_b @ truth.T, rays_b, rng.uniform(0.5, 2.0, 10))
    assert geodesic_angle(truth, fitted) < 1e-12


def test_tracking_survives_an_abrupt_reversal(scene):
    # Steps of +20 degrees, then a sudden -25: the constant-velocity prediction is 45 degrees
    # off, beyond any tile's reach; the coarse stage must find the motion.
    from ifmi.pipeline import EstimateConfig, estimate_sequence

    texture, _ = scene
    yaws = [0.0, 20.0, 40.0, 15.0, -10.0]
    truth = np.stack([_rotation(y, 3.0 * k, 60.0) for k, y in enumerate(yaws)])
    images = [omni_from_environment(texture, MODEL, r, band_px=BAND) for r in truth]
    config = EstimateConfig()
    panorama = PanoramaConfig(radius_min_px=BAND[0], radius_max_px=BAND[1])
    from dataclasses import replace

    config = replace(config, ifmi=replace(config.ifmi, panorama=panorama))
    estimate = estimate_sequence(images, MODEL, method="ifmi", config=config)
    assert all(r.success for r in estimate.frames)
    # Measured at most 0.035 degree.
    assert np.degrees(np.max(geodesic_angle(truth, estimate.trajectory.rotations))) < 0.2
    # Without the coarse stage the tiles cannot reach 20-degree steps: every later frame fails.
    without = replace(config, ifmi=replace(config.ifmi, coarse=CoarseOptions(enabled=False)))
    baseline = estimate_sequence(images, MODEL, method="ifmi", config=without)
    assert not any(r.success for r in baseline.frames[1:])


def test_config_is_checked():
    with pytest.raises(ValueError, match="min_sectors"):
        GlobalMotionConfig(sectors=6, min_sectors=8)
    for ratio in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="0 < confirm_mismatch_ratio <= 1"):
            GlobalMotionConfig(confirm_mismatch_ratio=ratio)
    with pytest.raises(ValueError, match="width"):
        GlobalMotionConfig(width=16)


def test_more_sector_passes_than_the_bound_are_refused():
    # 10**20 passes were accepted and the estimate never ended.
    with pytest.raises(ValueError, match=r"expected iterations <= 100 sector passes, got 100000000000000000000"):
        GlobalMotionConfig(iterations=10 ** 20)
    assert GlobalMotionConfig(iterations=100).iterations == 100


@pytest.mark.parametrize(("values", "count"), [
    ({"wide_tilt_step_deg": 0.01}, "2563200"), ({"wide_tilt_step_deg": 1e-300}, "inf"),
    ({"wide_tilt_max_deg": 1e12}, "6.25e+22"), ({"wide_tilt_max_deg": float("inf")}, "inf"),
])
def test_a_wide_search_grid_of_too_many_starts_is_refused(values, count):
    # Such grids failed allocating their starts or took minutes per pair, at the first pair the
    # wide search served (a fast one).
    with pytest.raises(ValueError, match=rf"expected a wide search grid of at most 1024 starts, got {re.escape(count)} "):
        GlobalMotionConfig(**values)
    fine = GlobalMotionEstimator(panorama_mapping(MODEL), config=GlobalMotionConfig(wide_tilt_step_deg=0.6))
    assert len(fine._tilted_starts(np.eye(3))) == 728


def _front_end_pair(texture, truth, config):
    from ifmi.spectral.ifmi_front_end import IfmiFrontEnd

    front_end = IfmiFrontEnd(MODEL, config)
    states = [front_end.prepare(omni_from_environment(texture, MODEL, r, band_px=BAND)) for r in (np.eye(3), truth)]
    return front_end, states


def _coarse_result_off_by(monkeypatch, yaw_error_deg):
    """Make the coarse stage return its first start turned by ``yaw_error_deg`` (a coarse-stage error)."""
    from ifmi.spectral.global_motion import GlobalMotion

    def off(self, coarse_a, coarse_b, *, priors=(None,)):
        start = np.eye(3) if priors[0] is None else priors[0]
        rotation = start @ Rotation.from_euler("z", yaw_error_deg, degrees=True).as_matrix()
        return GlobalMotion(rotation, True, "", 2.0, 12, 0.9)

    monkeypatch.setattr(GlobalMotionEstimator, "estimate", off)


def _coarse_stage_always_runs(monkeypatch):
    """Make tiles registered at the prediction never settle there, so that the coarse stage runs."""
    import ifmi.spectral.pair_pipeline as pair_pipeline

    monkeypatch.setattr(pair_pipeline, "_settled_at", lambda *args: False)


def _counted_coarse_stage(monkeypatch) -> list:
    """Count the coarse stage's estimates (the returned list grows by one per call)."""
    calls = []
    original = GlobalMotionEstimator.estimate
    monkeypatch.setattr(GlobalMotionEstimator, "estimate",
                        lambda self, *args, **kwargs: calls.append(1) or original(self, *args, **kwargs))
    return calls


def test_tiles_that_settle_at_the_prediction_skip_the_coarse_stage(scene, monkeypatch):
    from ifmi.spectral.ifmi_front_end import IfmiConfig

    texture, _ = scene
    truth = _rotation(12.0, 2.0, 60.0)
    config = IfmiConfig(panorama=PanoramaConfig(radius_min_px=BAND[0], radius_max_px=BAND[1]))
    calls = _counted_coarse_stage(monkeypatch)
    # An exact prediction: the tiles registered there settle, the coarse stage is not asked.
    front_end, (a, b) = _front_end_pair(texture, truth, config)
    exact = front_end.correspondences(a, b, prior_rotation=truth)
    assert exact.success and calls == [] and "coarse_score" not in exact.diagnostics
    # A prediction off in yaw by three times the coarse stage's settle shift (settled_shift_px
    # coarse pixels): the tiles measure that move, and the coarse stage runs.
    stage = front_end.global_stage
    off_deg = 3 * stage.config.settled_shift_px * 360.0 / stage.shape[1]
    front_end, (a, b) = _front_end_pair(texture, truth, config)
    prediction = truth @ Rotation.from_euler("z", off_deg, degrees=True).as_matrix()
    off = front_end.correspondences(a, b, prior_rotation=prediction)
    assert off.success and calls == [1] and "coarse_score" in off.diagnostics
    rotation = rotation_from_ray_pairs(off.rays_a, off.rays_b)
    assert np.degrees(geodesic_angle(truth, rotation)) < 0.05


def test_a_coarse_correction_the_tiles_match_worse_than_the_prediction_is_overruled(scene, monkeypatch):
    from dataclasses import replace

    from ifmi.spectral.ifmi_front_end import CoarseOptions, IfmiConfig, RecoveryOptions

    texture, _ = scene
    truth = _rotation(12.0, 2.0, 60.0)
    panorama = PanoramaConfig(radius_min_px=BAND[0], radius_max_px=BAND[1])
    # No dense retry and no wide search: the prediction check alone decides.
    config = IfmiConfig(panorama=panorama, coarse=CoarseOptions(prediction_check_tiles=0.45),
                        recovery=RecoveryOptions(dense_retry_fraction=0.0, wide_search_fraction=0.0))
    front_end, (a, b) = _front_end_pair(texture, truth, config)
    # The coarse stage moves an exact prediction by 0.4 of a tile (away from the identity, which the
    # re-acquisition starts from): the tiles barely overlap there. It runs although the tiles settle
    # at the prediction (they would skip it).
    tile_deg = 360.0 * front_end.layout.tile_size / front_end.mapping.width
    _coarse_result_off_by(monkeypatch, -0.4 * tile_deg)
    _coarse_stage_always_runs(monkeypatch)
    checked = front_end.correspondences(a, b, prior_rotation=truth)
    d = checked.diagnostics
    assert d["prediction_kept"] and d["n_tiles_kept"] > d["n_tiles_kept_coarse"]
    # Frame b keeps the tiles of the registration that won (measured 23 of 24 against 2 at the coarse rotation).
    assert b.tracked_valid.sum() == d["n_tiles_kept"] >= 0.9 * front_end.layout.count
    rotation = rotation_from_ray_pairs(checked.rays_a, checked.rays_b)
    # Measured 0.004 degree (noise-free synthetic frames).
    assert np.degrees(geodesic_angle(truth, rotation)) < 0.05
    # Without the check the coarse stage's rotation places the tiles, too few pass and the pair fails.
    unchecked, (a, b) = _front_end_pair(texture, truth, replace(config, coarse=replace(config.coarse, prediction_check_tiles=0.0)))
    plain = unchecked.correspondences(a, b, prior_rotation=truth)
    assert not plain.success and "prediction_kept" not in plain.diagnostics
    assert plain.diagnostics["n_tiles_kept"] == d["n_tiles_kept_coarse"] < config.rays.min_tiles


def test_the_prediction_is_checked_only_within_the_tiles_reach(scene, monkeypatch):
    from ifmi.spectral.ifmi_front_end import IfmiConfig

    texture, _ = scene
    truth = _rotation(12.0, 2.0, 60.0)
    panorama = PanoramaConfig(radius_min_px=BAND[0], radius_max_px=BAND[1])
    front_end, (a, b) = _front_end_pair(texture, truth, IfmiConfig(panorama=panorama))
    tile_deg = 360.0 * front_end.layout.tile_size / front_end.mapping.width
    # A correction beyond prediction_check_tiles (0.125 tile) is taken without registering at the prediction.
    _coarse_result_off_by(monkeypatch, 0.2 * tile_deg)
    _coarse_stage_always_runs(monkeypatch)
    diagnostics = front_end.correspondences(a, b, prior_rotation=truth).diagnostics
    assert "prediction_kept" not in diagnostics
    assert diagnostics["coarse_correction_rad"] == pytest.approx(np.radians(0.2 * tile_deg))


def test_prediction_check_option_is_checked():
    from ifmi.spectral.ifmi_front_end import IfmiConfig

    with pytest.raises(ValueError, match="prediction_check_tiles"):
        CoarseOptions(prediction_check_tiles=0.5)


def test_a_prediction_the_coarse_stage_confirmed_is_registered_once(scene, monkeypatch):
    from ifmi.spectral.ifmi_front_end import IfmiConfig, IfmiFrontEnd

    texture, _ = scene
    truth = _rotation(12.0, 2.0, 60.0)
    panorama = PanoramaConfig(radius_min_px=BAND[0], radius_max_px=BAND[1])
    front_end, (a, b) = _front_end_pair(texture, truth, IfmiConfig(panorama=panorama))
    _coarse_result_off_by(monkeypatch, 0.0)  # returned unchanged: its correction angle is float noise
    _coarse_stage_always_runs(monkeypatch)
    calls = []
    original = IfmiFrontEnd.tiles_at
    monkeypatch.setattr(IfmiFrontEnd, "tiles_at",
                        lambda self, *args, **kwargs: calls.append(1) or original(self, *args, **kwargs))
    diagnostics = front_end.correspondences(a, b, prior_rotation=truth).diagnostics
    assert len(calls) == 1 and "prediction_kept" not in diagnostics
