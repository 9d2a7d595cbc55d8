"""A scene that matches itself turned half round: the smaller of two solving rotations is taken."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.spectral import pair_pipeline as pair_pipeline
from ifmi.geometry.camera import paracatadioptric_model
from ifmi.front_end import Correspondences, FrontEndBase, SolvedPair
from ifmi.spectral.global_motion import GlobalMotionEstimator
from ifmi.tracking.odometry import track_sequence
from ifmi.backend.relative_pose import RelativePoseOptions, relative_pose_from_rays
from ifmi.geometry.rotations import geodesic_angle
from ifmi.spectral.ifmi_front_end import IfmiConfig, IfmiFrontEnd, RecoveryOptions
from ifmi.synthetic import environment_texture, omni_from_environment
from ifmi.spectral.panorama import PanoramaConfig, panorama_image_from_omni_image, panorama_mapping

SIZE = 200
MODEL = paracatadioptric_model((SIZE, SIZE), horizon_radius_px=60.0)
BAND = (20.0, 95.0)
PANORAMA = PanoramaConfig(radius_min_px=BAND[0], radius_max_px=BAND[1])
# R_01: 30 degrees of yaw and 10 of tilt, as between frames of a fast sequence.
TRUTH = (Rotation.from_rotvec(np.radians(10.0) * np.array([np.cos(0.4), np.sin(0.4), 0.0]))
         * Rotation.from_euler("z", -30.0, degrees=True)).as_matrix()
HALF_TURN = np.diag([-1.0, -1.0, 1.0])
OPTIONS = RelativePoseOptions(ransac_threshold_rad=0.01, seed=0)


@pytest.fixture(scope="module")
def symmetric_texture():
    """An environment whose second half of azimuths repeats the first: the same seen turned half round
    about z (frame 0's axis), so ``HALF_TURN @ TRUTH`` explains the pair exactly as well as ``TRUTH``."""
    texture = environment_texture(height=360, seed=5)
    half = texture[:, :texture.shape[1] // 2]
    return np.concatenate([half, half], axis=1)


@pytest.fixture(scope="module")
def texture():
    return environment_texture(height=360, seed=5)


def _solve(corr):
    return relative_pose_from_rays(corr.rays_a, corr.rays_b, options=OPTIONS,
                                   rays_per_measurement=corr.rays_per_measurement)


def _pair(front_end, environment, rotation):
    return [front_end.prepare(omni_from_environment(environment, MODEL, r, band_px=BAND))
            for r in (np.eye(3), rotation)]


def _solved(front_end, a, b, prior):
    """``(matched, pose, info)`` of the pair's stages up to its rays at ``prior``, solved."""
    matched = pair_pipeline.matched(front_end, a, b, prior)
    pose, info = _solve(matched.correspondences)
    assert info.success
    return matched, pose, info


def test_a_half_turn_solution_is_replaced_by_the_rotation_near_the_prediction(symmetric_texture):
    front_end = IfmiFrontEnd(MODEL, IfmiConfig(panorama=PANORAMA))
    a, b = _pair(front_end, symmetric_texture, TRUTH)
    wrong = HALF_TURN @ TRUTH
    # The pair solved at the half turn, as the coarse stage's highest peak can put it (measured 0.019
    # degree from it: the frames cannot tell the two apart).
    solved = _solved(front_end, a, b, wrong)
    first, info = solved[1:]
    assert np.degrees(geodesic_angle(wrong, first.rotation)) < 0.1
    found = pair_pipeline.half_turn_checked(front_end, a, b, solved, np.eye(3), _solve)
    assert found is not None
    turned, pose, alternative = found
    corr = turned.correspondences
    assert corr.diagnostics["half_turn"] and alternative.success
    assert alternative.n_inliers >= 0.5 * info.n_inliers
    # Measured 0.019 degree (noise-free synthetic frames); the half turn was 180 degrees off.
    assert np.degrees(geodesic_angle(TRUTH, pose.rotation)) < 0.1
    # Frame b would keep the alternative's registration, at the near search's rotation (a fraction of
    # a 2.8-degree coarse pixel off).
    assert turned.kept is not None and np.degrees(geodesic_angle(TRUTH, turned.rotation)) < 2.8


def test_a_large_true_rotation_keeps_its_solution(texture):
    # A scene that does not match itself half round: 150 degrees of yaw between the frames is kept,
    # as the rotation 30 degrees the other way does not solve with as many inliers.
    truth = TRUTH @ Rotation.from_euler("z", -120.0, degrees=True).as_matrix()
    front_end = IfmiFrontEnd(MODEL, IfmiConfig(panorama=PANORAMA))
    a, b = _pair(front_end, texture, truth)
    first = _solved(front_end, a, b, truth)
    pose, info = first[1:]
    assert np.degrees(geodesic_angle(truth, pose.rotation)) < 0.1  # measured 0.011 degree
    kept = (b.tracked, b.tracked_valid, b.tracked_landmarks)
    solved = []

    def observed(corr):
        solved.append(_solve(corr))
        return solved[-1]

    assert pair_pipeline.half_turn_checked(front_end, a, b, first, np.eye(3), observed) is None
    # The alternative was tried and not taken (here its tiles fail: nothing reaches the back end),
    # and nothing of frame b changed.
    assert len(solved) <= 1 and all(not i.success or i.n_inliers < 0.5 * info.n_inliers for _, i in solved)
    for now, before in zip((b.tracked, b.tracked_valid, b.tracked_landmarks), kept):
        assert now is before


def test_a_solution_near_the_prediction_is_not_checked(symmetric_texture):
    front_end = IfmiFrontEnd(MODEL, IfmiConfig(panorama=PANORAMA))
    a, b = _pair(front_end, symmetric_texture, TRUTH)

    def never(corr):
        raise AssertionError("nothing is solved again")

    def solution(rotation):  # what the stage reads of a solved pair before it decides to try
        return None, SimpleNamespace(rotation=rotation), SimpleNamespace(n_inliers=100)

    # 31 degrees from the identity: within the default quarter turn.
    assert pair_pipeline.half_turn_checked(front_end, a, b, solution(TRUTH), np.eye(3), never) is None
    # Turned off (a bound of pi), or no prediction: nothing is tried either.
    off = IfmiFrontEnd(MODEL, IfmiConfig(panorama=PANORAMA, recovery=RecoveryOptions(half_turn_check_rad=np.pi)))
    a, b = _pair(off, symmetric_texture, TRUTH)
    assert pair_pipeline.half_turn_checked(off, a, b, solution(HALF_TURN @ TRUTH), np.eye(3), never) is None
    assert pair_pipeline.half_turn_checked(front_end, a, b, solution(HALF_TURN @ TRUTH), None, never) is None


def test_the_near_search_keeps_the_yaw_near_its_start(texture):
    mapping = panorama_mapping(MODEL, config=PANORAMA)
    stage = GlobalMotionEstimator(mapping)
    a, b = (stage.coarse_panorama(panorama_image_from_omni_image(
        mapping, omni_from_environment(texture, MODEL, r, band_px=BAND))) for r in (np.eye(3), TRUTH))
    # From 12 degrees of yaw off the truth it converges on the truth (measured 0.18 degree; a coarse
    # pixel is 2.8 degrees).
    near = TRUTH @ Rotation.from_euler("z", 12.0, degrees=True).as_matrix()
    found = stage.search_near(a, b, starts=near[None], max_yaw_rad=np.radians(20.0))
    assert found.success and np.degrees(geodesic_angle(TRUTH, found.rotation)) < 1.0
    # From the half turn the plain search goes back to the truth (measured 0.11 degree); the near one
    # stays within its 20-degree window and the two sector passes' reach (half a sector of 10 coarse
    # columns each, 14 degrees) of the start: measured 32 degrees from it, 167 from the truth.
    far = HALF_TURN @ TRUTH
    assert np.degrees(geodesic_angle(TRUTH, stage.estimate(a, b, priors=(far,)).rotation)) < 1.0
    kept = stage.search_near(a, b, starts=far[None], max_yaw_rad=np.radians(20.0))
    assert np.degrees(geodesic_angle(far, kept.rotation)) < 20.0 + 2 * 14.0
    assert np.degrees(geodesic_angle(TRUTH, kept.rotation)) > 90.0


class _HalfTurnFrontEnd(FrontEndBase):
    """Exact rays of ``R_0k`` per frame; frame 1's correspondences give the half turn, and its own
    ``solve_pair`` offers the truth (solved by the tracker's back end)."""

    uses_prior_rotation = True

    def __init__(self, rotations, *, offer=True):
        self.rotations, self.offer, self.calls = rotations, offer, []
        rng = np.random.default_rng(0)
        rays = rng.normal(size=(80, 3))
        self.rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def prepare(self, image):
        return int(image)

    def _corr(self, rotation_ab, diagnostics):
        # rays_a = R_ab rays_b
        return Correspondences(self.rays[:, :2] * 0, self.rays[:, :2] * 0, self.rays @ rotation_ab.T, self.rays,
                               diagnostics)

    def correspondences(self, a, b, *, prior_rotation):
        truth = self.rotations[a].T @ self.rotations[b]
        return self._corr(HALF_TURN @ truth if b == 1 else truth, {})

    def solve_pair(self, a, b, *, prior_rotation, solve):
        corr = self.correspondences(a, b, prior_rotation=prior_rotation)
        pose, info = solve(corr)
        self.calls.append((a, b, geodesic_angle(prior_rotation, pose.rotation), info.n_inliers))
        if not self.offer or b != 1:
            return SolvedPair(corr, pose, info)
        corr = self._corr(self.rotations[a].T @ self.rotations[b], {"half_turn": True})
        return SolvedPair(corr, *solve(corr))


@pytest.mark.parametrize("offer", [True, False])
def test_the_tracker_chains_what_the_front_ends_pair_solver_settles_on(offer):
    rotations = [Rotation.from_euler("z", 0.3 * k).as_matrix() for k in range(4)]
    front_end = _HalfTurnFrontEnd(rotations, offer=offer)
    trajectory, records = track_sequence(range(4), front_end, pose_options=OPTIONS)
    # The front end's solve_pair sees every pair with its prediction and the tracker's back end.
    assert [call[:2] for call in front_end.calls] == [(0, 1), (1, 2), (2, 3)]
    assert front_end.calls[0][2] == pytest.approx(np.pi - 0.3, abs=1e-6) and front_end.calls[0][3] == 80
    error = np.degrees(geodesic_angle(rotations[3], trajectory.rotations[3]))
    if offer:
        assert records[1].diagnostics["half_turn"] and error < 1e-6
    else:
        assert "half_turn" not in records[1].diagnostics and error == pytest.approx(180.0, abs=1e-4)


@pytest.mark.parametrize("kwargs", [{"half_turn_check_rad": -0.1}, {"half_turn_check_rad": 4.0}])
def test_half_turn_options_are_checked(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        RecoveryOptions(**kwargs)
