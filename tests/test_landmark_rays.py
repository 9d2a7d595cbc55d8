"""Landmark rays: a tracked tile's ray in the reference frame follows the accepted trajectory."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.geometry.camera import rays_from_pixels
from ifmi.tracking.odometry import track_sequence
from ifmi.backend.relative_pose import RelativePoseOptions
from ifmi.geometry.rotations import geodesic_angle
from ifmi.spectral.ifmi_front_end import _LANDMARK_GATE_PX, IfmiConfig, IfmiFrontEnd, RaysOptions, RefinementOptions, TrackingOptions
from ifmi.spectral.panorama import rays_from_panorama_pixels
from test_panorama_interpolation import MODEL, _scene


def _walk(frames, step_deg, seed):
    """Seeded smooth random walk ``R_0k``: angular velocity with memory, yaw twice the tilt."""
    rng = np.random.default_rng(seed)
    rotations, velocity = [np.eye(3)], np.zeros(3)
    for _ in range(frames - 1):
        velocity = 0.7 * velocity + rng.uniform(-1, 1, 3) * np.radians(step_deg) * np.array([0.5, 0.5, 1.0])
        rotations.append(rotations[-1] @ Rotation.from_rotvec(velocity).as_matrix())
    return np.array(rotations)


@pytest.fixture(scope="module")
def frame():
    return _scene(seed=0)


def _layout_centre_rays(fe):
    offsets, _ = fe._layout_placement
    return rays_from_panorama_pixels(fe.mapping, offsets)


def _angle(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.einsum("...i,...i->...", a, b))


@pytest.mark.slow
@pytest.mark.parametrize("off_px, weight", [(0.05, 1.0), (0.05, 0.5), (2.0, 1.0)])
def test_tracked_tile_rays_follow_the_accepted_pose_within_the_gate(frame, off_px, weight):
    # Frames 0 and 1 accepted; frame 1's accepted pose is off the truth by off_px panorama
    # pixels of yaw. Frame 2 is then matched against frame 1. The centre of every tile tracked
    # from frame 0 is turned from its measured ray the weight's part of the way to its frame-0
    # ray as the accepted pose sees it, when that lies within the gate (0.25 px); beyond it,
    # the measured placement stays. Tiles cut anew in frame 1 lie on their landmarks already.
    truth = _walk(3, 1.0, seed=5)
    # Flow points on the tile centres (not their energy centroids): the rays the landmarks turn.
    fe = IfmiFrontEnd(MODEL, IfmiConfig(rays=RaysOptions(points_per_tile=1, at_energy_centroid=False),
                                        tracking=TrackingOptions(landmark_weight=weight)))
    states = [fe.prepare(frame(r)) for r in truth]
    fe.accept_pose(states[0], np.eye(3))
    fe.correspondences(states[0], states[1], prior_rotation=truth[1])
    off = Rotation.from_rotvec([0.0, 0.0, off_px * 2 * np.pi / fe.mapping.width]).as_matrix()
    accepted = truth[1] @ off
    fe.accept_pose(states[1], accepted)
    corr = fe.correspondences(states[1], states[2], prior_rotation=truth[1].T @ truth[2])
    offsets_a = fe.reference_tiles(states[1])[0]
    tracked_from_0 = ~fe._needs_new_tile(states[1].tracked, states[1].tracked_valid)
    kept = np.flatnonzero(states[2].tracked_valid)  # the tiles of corr's rays, in order
    assert corr.success and len(corr.rays_a) == len(kept) and tracked_from_0[kept].sum() > 100
    old = tracked_from_0[kept]
    measured = rays_from_panorama_pixels(fe.mapping, offsets_a)[kept]
    landmark = (_layout_centre_rays(fe) @ accepted)[kept]  # R_01^T applied to each frame-0 ray
    if off_px <= _LANDMARK_GATE_PX:
        assert corr.diagnostics["n_tiles_landmark"] == len(kept)
        apart = _angle(measured[old], landmark[old])
        assert np.abs(_angle(measured[old], corr.rays_a[old]) - weight * apart).max() < 1e-12
        assert np.abs(_angle(corr.rays_a[old], landmark[old]) - (1 - weight) * apart).max() < 1e-12
    else:
        assert corr.diagnostics["n_tiles_landmark"] == (~old).sum()
        assert np.abs(corr.rays_a[old] - measured[old]).max() < 1e-12
    assert np.abs(corr.rays_a[~old] - measured[~old]).max() < 1e-12
    # The omni pixels of frame a are those of its (turned) rays.
    assert np.allclose(rays_from_pixels(MODEL, corr.pixels_a), corr.rays_a, atol=1e-6)


@pytest.mark.slow
def test_a_reference_without_an_accepted_pose_keeps_measured_rays_and_drops_the_landmarks(frame):
    # As after a reference reset: frame 1 serves as reference with no accepted pose. Its pair
    # and the tiles carried on from it use measured placements; frame 2, accepted, gives
    # landmarks only to tiles cut anew in it.
    truth = _walk(4, 1.5, seed=6)
    fe = IfmiFrontEnd(MODEL, IfmiConfig(rays=RaysOptions(points_per_tile=1)))
    states = [fe.prepare(frame(r)) for r in truth]
    fe.accept_pose(states[0], np.eye(3))
    fe.correspondences(states[0], states[1], prior_rotation=truth[1])
    corr = fe.correspondences(states[1], states[2], prior_rotation=truth[1].T @ truth[2])
    assert corr.success and "n_tiles_landmark" not in corr.diagnostics
    assert states[2].tracked_landmarks is None
    fe.accept_pose(states[2], truth[2])
    corr = fe.correspondences(states[2], states[3], prior_rotation=truth[2].T @ truth[3])
    new = fe._needs_new_tile(states[2].tracked, states[2].tracked_valid)
    landmarks = states[2].reference_landmarks
    assert np.isnan(landmarks[~new]).all() and np.isfinite(landmarks[new]).all() and 0 < new.sum() < len(new)
    assert corr.diagnostics["n_tiles_landmark"] == new[states[3].tracked_valid].sum()


def test_landmark_options_are_checked():
    with pytest.raises(ValueError, match="landmark_weight"):
        TrackingOptions(landmark_weight=0.0)


@pytest.mark.slow
def test_landmark_rays_lower_the_frame_to_frame_drift(frame):
    # Exact renders of a band-limited texture (tests/test_panorama_interpolation.py) along three
    # 3-degree random walks whose tilt makes tiles leave the panorama and be cut anew. Geodesic
    # ATE in frame mode, measured with / without landmark rays (default weight 0.5): walk seed 1
    # 1.40e-6 / 2.43e-6, seed 2 1.03e-6 / 2.78e-6, seed 3 0.97e-6 / 1.33e-6; summed 0.52x.
    # Which tiles are cut anew, and so the drift without landmarks, moves with single grey
    # levels of the frames (rounding them differently gave 1.52e-6 / 2.63e-6 / 0.99e-6).
    pose = RelativePoseOptions(ransac_threshold_rad=2 * np.pi / 2048)
    ate = {True: [], False: []}
    for seed in (1, 2, 3):
        truth = _walk(16, 3.0, seed=seed)
        images = [frame(r) for r in truth]
        for landmarks in (True, False):
            fe = IfmiFrontEnd(MODEL, IfmiConfig(tracking=TrackingOptions(landmark_rays=landmarks)))
            trajectory, records = track_sequence(images, fe, pose_options=pose)
            assert all(r.success for r in records)
            assert ("n_tiles_landmark" in records[2].diagnostics) == landmarks
            ate[landmarks].append(float(np.sqrt(np.mean(geodesic_angle(truth, trajectory.rotations) ** 2))))
    assert max(ate[True]) < 2e-6 and sum(ate[True]) < 0.8 * sum(ate[False]), ate


@pytest.mark.slow
def test_narrow_panoramas_keep_measured_rays(frame):
    # Below min_width_sharp (here the 1024 px images' own 2048 px panorama) nothing is turned.
    truth = _walk(3, 1.0, seed=5)
    fe = IfmiFrontEnd(MODEL, IfmiConfig(refinement=RefinementOptions(min_width_sharp=4096)))
    trajectory, records = track_sequence([frame(r) for r in truth], fe,
                                         pose_options=RelativePoseOptions(ransac_threshold_rad=2 * np.pi / 2048))
    assert all(r.success for r in records) and not any("n_tiles_landmark" in r.diagnostics for r in records)
