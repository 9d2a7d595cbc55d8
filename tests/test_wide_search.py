"""Wide coarse search: a wrong yaw from a smeared whole-panorama correlation is replaced."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.camera import paracatadioptric_model
from ifmi.global_motion import GlobalMotion, GlobalMotionConfig, GlobalMotionEstimator, rotation_from_ray_pairs
from ifmi.rotations import geodesic_angle
from ifmi.spectral_front_end import IfmiConfig, IfmiFrontEnd
from ifmi.synthetic import environment_texture, omni_from_environment
from ifmi.unwarp import PanoramaConfig, panorama_image_from_omni_image, panorama_mapping

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
    found = estimator.wide_search(a, b, start=None, current_rotation=WRONG, current_score=wrong_score)
    assert found is not None and found.success
    # Measured 0.12 degree; a coarse pixel is 2.8 degrees.
    assert np.degrees(geodesic_angle(TRUTH, found.rotation)) < 1.0
    assert 1.0 - found.score <= 0.5 * (1.0 - wrong_score)


def test_the_wide_search_leaves_a_right_rotation_alone(texture):
    estimator, mapping = _estimator()
    a, b = _coarse_pair(texture, estimator, mapping)
    right = estimator.estimate(a, b)
    assert np.degrees(geodesic_angle(TRUTH, right.rotation)) < 1.0
    assert estimator.wide_search(a, b, start=None, current_rotation=right.rotation,
                                 current_score=right.score) is None


def test_the_wide_search_can_be_turned_off(texture):
    estimator, mapping = _estimator(GlobalMotionConfig(wide_tilt_max_deg=0.0))
    a, b = _coarse_pair(texture, estimator, mapping)
    wrong_score = estimator.score(a, estimator.warped(b, WRONG))
    assert estimator.wide_search(a, b, start=None, current_rotation=WRONG, current_score=wrong_score) is None


def _coarse_stage_returns(monkeypatch, rotation, score):
    monkeypatch.setattr(GlobalMotionEstimator, "estimate",
                        lambda self, coarse_a, coarse_b, *, priors=(None,): GlobalMotion(rotation, True, "", 1.3,
                                                                                          12, score))


def test_the_front_end_searches_wide_when_the_tiles_fail(texture, monkeypatch):
    config = IfmiConfig(panorama=PANORAMA, dense_retry_fraction=0.0)
    front_end = IfmiFrontEnd(MODEL, config)
    a, b = (front_end.prepare(omni_from_environment(texture, MODEL, r, band_px=BAND)) for r in (np.eye(3), TRUTH))
    score = front_end.global_stage.score(a.coarse_panorama, front_end.global_stage.warped(b.coarse_panorama, WRONG))
    # The coarse stage (from the prediction and on re-acquisition) lands on the wrong yaw.
    _coarse_stage_returns(monkeypatch, WRONG, score)
    pair = front_end.correspondences(a, b, prior_rotation=np.eye(3))
    assert pair.success and pair.diagnostics["wide_search"]
    assert b.tracked_valid.sum() == pair.diagnostics["n_tiles_kept"] >= config.min_tiles
    # Measured 0.026 degree (noise-free synthetic frames).
    assert np.degrees(geodesic_angle(TRUTH, rotation_from_ray_pairs(pair.rays_a, pair.rays_b))) < 0.1
    # Without the wide search the tiles at the wrong yaw cannot pass: the pair fails.
    plain = IfmiFrontEnd(MODEL, replace(config, wide_search_fraction=0.0))
    a, b = (plain.prepare(omni_from_environment(texture, MODEL, r, band_px=BAND)) for r in (np.eye(3), TRUTH))
    failed = plain.correspondences(a, b, prior_rotation=np.eye(3))
    assert not failed.success and "wide_search" not in failed.diagnostics


@pytest.mark.parametrize("kwargs, name", [({"wide_tilt_max_deg": -1.0}, "wide_tilt_max_deg"),
                                          ({"wide_tilt_step_deg": 0.0}, "wide_tilt_step_deg"),
                                          ({"wide_mismatch_ratio": 1.5}, "wide_mismatch_ratio"),
                                          ({"wide_candidates": 0}, "wide_candidates")])
def test_wide_search_options_are_checked(kwargs, name):
    with pytest.raises(ValueError, match=name):
        GlobalMotionConfig(**kwargs)


def test_wide_search_fraction_is_checked():
    with pytest.raises(ValueError, match="wide_search_fraction"):
        IfmiConfig(wide_search_fraction=1.5)
