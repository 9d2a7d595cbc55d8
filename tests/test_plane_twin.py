"""The plane twin: exact decompositions, the planarity test, and the sequence picking the true twin."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.backend.homography import (homography_from_rays, homography_transfer_angles, inlier_homography,
                                     refitted_homography)
from ifmi.backend.plane_twin import (PlaneTwinOptions, planar_pair, plane_decompositions, rechained,
                                     resolve_plane_twins)
from ifmi.geometry.rotations import geodesic_angle

HEIGHT_M = 1.6
HALF_VIEW_RAD = np.radians(65.0)  # a double-sphere fisheye looking down sees the road this far off its axis


def _cone_rays(n, rng):
    """Unit rays of camera b within HALF_VIEW_RAD of its axis (z), (n, 3)."""
    z = rng.uniform(np.cos(HALF_VIEW_RAD), 1.0, n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _noisy(rays, sigma, rng):
    return _unit(rays + rng.normal(0.0, sigma, rays.shape))


def _pair_rays(rotation_ab, translation_ab, points_b):
    """Rays of both cameras of points given in camera b (X_a = R_ab X_b + t_ab)."""
    return _unit(points_b @ rotation_ab.T + translation_ab), _unit(points_b)


def _plane_pair(rng, *, step=0.05, n=100):
    rotation_ab = Rotation.from_rotvec([0.01, -0.02, 0.03]).as_matrix()
    translation_ab = step * _unit(np.array([1.0, 0.2, 0.1]))
    rays_b = _cone_rays(n, rng)
    normal_b = np.array([0.0, 0.0, 1.0])
    points_b = rays_b * (HEIGHT_M / (rays_b @ normal_b))[:, None]
    return rotation_ab, translation_ab, normal_b, points_b


def test_inlier_homography_of_exact_plane_rays_among_gross_outliers():
    # 200 exact rays of the plane and 20 paired with random rays: the fit to all is pulled off,
    # the refits on the transferred rays recover the plane's homography to rounding.
    rng = np.random.default_rng(5)
    rotation_ab, translation_ab, normal_b, points_b = _plane_pair(rng, n=220)
    rays_a, rays_b = _pair_rays(rotation_ab, translation_ab, points_b)
    rays_a[:20] = _cone_rays(20, rng)
    homography, errors = inlier_homography(rays_a, rays_b, threshold_rad=5e-3)
    assert np.max(errors[20:]) < 1e-9 and np.min(errors[:20]) > 5e-3
    expected = rotation_ab + np.outer(translation_ab, normal_b) / HEIGHT_M
    np.testing.assert_allclose(homography / np.linalg.norm(homography),
                               np.sign(np.sum(homography * expected)) * expected / np.linalg.norm(expected),
                               atol=1e-9)


def test_refits_stop_when_the_inliers_are_those_of_the_last_fit():
    # Exact plane rays: every ray is an inlier of the first fit, so a refit on them could only
    # repeat it; with ``fitted`` the fit is not called again, and the result is the same.
    rng = np.random.default_rng(6)
    rotation_ab, translation_ab, _, points_b = _plane_pair(rng)
    rays_a, rays_b = _pair_rays(rotation_ab, translation_ab, points_b)
    first = homography_from_rays(rays_a, rays_b)
    calls = []

    def fit(a, b):
        calls.append(len(a))
        return homography_from_rays(a, b)

    kept = refitted_homography(first, rays_a, rays_b, threshold_rad=5e-3, refits=2, fit=fit,
                               fitted=np.ones(len(rays_a), dtype=bool))
    assert calls == []
    refitted = refitted_homography(first, rays_a, rays_b, threshold_rad=5e-3, refits=2, fit=fit)
    assert calls == [len(rays_a)]  # one refit, then the same inliers: no second
    assert np.array_equal(kept[0], first) and np.array_equal(refitted[0], first)
    assert np.array_equal(kept[1], refitted[1])


def test_decompositions_of_an_exact_homography_hold_the_true_motion_and_its_twin():
    rng = np.random.default_rng(3)
    rotation_ab, translation_ab, normal_b, points_b = _plane_pair(rng)
    rays_a, rays_b = _pair_rays(rotation_ab, translation_ab, points_b)
    fitted = homography_from_rays(rays_a, rays_b)
    assert np.max(homography_transfer_angles(fitted, rays_a, rays_b)) < 1e-9
    rotations, translations, normals = plane_decompositions(fitted, rays_a, rays_b)
    errors = geodesic_angle(rotations, np.broadcast_to(rotation_ab, rotations.shape))
    true = int(np.argmin(errors))
    assert errors[true] < 1e-9
    np.testing.assert_allclose(translations[true] * HEIGHT_M, translation_ab, atol=1e-9)
    np.testing.assert_allclose(normals[true], normal_b, atol=1e-9)
    # The twin: rotation off by about |t| / d, normal near the translation direction.
    twin = 1 - true
    assert 0.5 * 0.05 / HEIGHT_M < errors[twin] < 2.0 * 0.05 / HEIGHT_M
    assert abs(normals[twin] @ _unit(translation_ab)) > 0.9
    # Both explain every ray in front of camera b.
    assert np.all(rays_b @ normals[true] > 0)


def test_a_plane_pair_is_planar_and_a_deep_scene_is_not():
    rng = np.random.default_rng(4)
    sigma = 1e-3
    rotation_ab, translation_ab, _, points_b = _plane_pair(rng)
    options = dict(noise_sigma_rad=np.sqrt(2.0) * sigma, threshold_rad=5.0 * sigma)
    rays_a, rays_b = _pair_rays(rotation_ab, translation_ab, points_b)
    candidates = planar_pair(_noisy(rays_a, sigma, rng), _noisy(rays_b, sigma, rng), rotation_ab,
                             _unit(translation_ab), **options)
    assert candidates is not None and candidates.gric_homography < candidates.gric_5pt
    assert geodesic_angle(candidates.rotations[candidates.current][None], rotation_ab[None])[0] < 5e-3
    # The same rays at depths from 1 to 5 times the plane's: no plane explains them.
    points_b = points_b * rng.uniform(1.0, 5.0, len(points_b))[:, None]
    rays_a, rays_b = _pair_rays(rotation_ab, translation_ab, points_b)
    assert planar_pair(_noisy(rays_a, sigma, rng), _noisy(rays_b, sigma, rng), rotation_ab,
                       _unit(translation_ab), **options) is None


def _trajectory(frames, step, turn_rad):
    """World poses (camera to world) of a camera looking down from HEIGHT_M, moving ``step`` per frame on
    an arc whose heading turns by ``turn_rad`` per frame, yawing and tilting a little."""
    down = Rotation.from_euler("x", np.pi).as_matrix()  # camera z along world -z
    rotations, positions = [], []
    position = np.array([0.0, 0.0, HEIGHT_M])
    for k in range(frames):
        tilt = Rotation.from_rotvec([0.03 * np.sin(0.5 * k), 0.02 * np.cos(0.3 * k), 0.035 * k]).as_matrix()
        rotations.append(tilt @ down)
        positions.append(position.copy())
        heading = turn_rad * k
        position = position + step * np.array([np.cos(heading), np.sin(heading), 0.02])
    return np.array(rotations), np.array(positions)


def _sequence(rng, *, step, turn_rad, sigma, twins, frames=12, n=90, planar=True):
    """Pairs (k-1, k) of a camera over a floor: each pair's candidates as a 5-point estimate picked
    the twin (``twins[k]``) or the true motion, and the true R_0k."""
    world_rotations, world_positions = _trajectory(frames, step, turn_rad)
    relative, found = np.repeat(np.eye(3)[None], frames, axis=0), {}
    true_index = {}
    for k in range(1, frames):
        rotation_ab = world_rotations[k - 1].T @ world_rotations[k]
        translation_ab = world_rotations[k - 1].T @ (world_positions[k] - world_positions[k - 1])
        rays_b = _cone_rays(n, rng)
        normal_b = -world_rotations[k].T @ np.array([0.0, 0.0, 1.0])
        depths = (world_positions[k][2] / (rays_b @ normal_b))
        if not planar:
            depths = depths * rng.uniform(0.3, 1.0, n)
        rays_a, _ = _pair_rays(rotation_ab, translation_ab, rays_b * depths[:, None])
        exact = plane_decompositions(rotation_ab + np.outer(translation_ab, normal_b) / world_positions[k][2],
                                     rays_a, rays_b)
        true = int(np.argmin(geodesic_angle(exact[0], np.broadcast_to(rotation_ab, (2, 3, 3)))))
        estimate = 1 - true if twins[k] else true
        relative[k] = exact[0][estimate]
        candidates = planar_pair(_noisy(rays_a, sigma, rng), _noisy(rays_b, sigma, rng), exact[0][estimate],
                                 _unit(exact[1][estimate]), noise_sigma_rad=np.sqrt(2.0) * sigma,
                                 threshold_rad=5.0 * sigma)
        if candidates is not None:
            found[k] = candidates
            true_index[k] = int(np.argmin(geodesic_angle(candidates.rotations,
                                                         np.broadcast_to(rotation_ab, (2, 3, 3)))))
    return relative, found, true_index, world_rotations


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("step", [0.01, 0.05, 0.2])
def test_the_sequence_picks_the_true_twin_on_a_floor(seed, step):
    rng = np.random.default_rng(seed)
    twins = rng.random(12) < 0.5  # the 5-point estimates picked the twin on about half of the pairs
    twins[1] = seed % 2 == 0  # both kinds of first pair
    relative, planar, true_index, world = _sequence(rng, step=step, turn_rad=np.radians(4.0), sigma=1e-3,
                                                    twins=twins)
    assert len(planar) == 11
    choices = resolve_plane_twins(np.maximum(np.arange(12) - 1, 0), relative, planar)
    assert choices == true_index
    chained = np.empty_like(relative)
    chained[0] = np.eye(3)
    for k in range(1, 12):
        chained[k] = chained[k - 1] @ relative[k]
    replaced = {k: (planar[k].rotations[c], planar[k].translations[c]) for k, c in choices.items()
                if c != planar[k].current}
    rotations, _ = rechained(chained, np.zeros((12, 3)), np.maximum(np.arange(12) - 1, 0), replaced)
    truth = world[0].T @ world
    before = geodesic_angle(chained, truth)
    after = geodesic_angle(rotations, truth)
    # Each pair's rotation is then the homography's true decomposition (noise of 1 mrad over 90 rays).
    assert np.max(after) < 0.01
    if twins[1:].any():
        assert np.max(after) < np.max(before)


def test_a_deep_scene_is_left_alone():
    rng = np.random.default_rng(9)
    twins = np.zeros(12, dtype=bool)
    relative, planar, _, _ = _sequence(rng, step=0.05, turn_rad=np.radians(4.0), sigma=1e-3, twins=twins,
                                       planar=False)
    assert planar == {}
    assert resolve_plane_twins(np.maximum(np.arange(12) - 1, 0), relative, planar) == {}


def test_one_planar_pair_changes_nothing():
    rng = np.random.default_rng(10)
    twins = np.ones(12, dtype=bool)
    relative, planar, _, _ = _sequence(rng, step=0.05, turn_rad=np.radians(4.0), sigma=1e-3, twins=twins,
                                       frames=2)
    assert len(planar) == 1
    assert resolve_plane_twins(np.array([0, 0]), relative, planar, options=PlaneTwinOptions()) == {}


def _tracked(rng, *, pose_of, frames=8, sigma=1e-3):
    """A turning track over a floor through PlaneTwinChain: each pair's 5-point pose is the exact
    twin decomposition (``pose_of="twin"``), the exact true one (``"true"``) or the truth turned by
    6 mrad (``"off"``); returns the chained rotations, the chain's result, its labels and the truth."""
    from types import SimpleNamespace

    from ifmi.tracking.odometry import FrameRecord
    from ifmi.tracking.plane_twins import PLANE_TWIN, PlaneTwinChain

    world, positions = _trajectory(frames, 0.05, np.radians(4.0))
    chain, chained, records = PlaneTwinChain(), [np.eye(3)], [FrameRecord(0, 0, True, "", 0, 0, 0.0)]
    for k in range(1, frames):
        rotation_ab = world[k - 1].T @ world[k]
        translation_ab = world[k - 1].T @ (positions[k] - positions[k - 1])
        normal_b = -world[k].T @ np.array([0.0, 0.0, 1.0])
        rays_b = _cone_rays(90, rng)
        rays_a, _ = _pair_rays(rotation_ab, translation_ab, rays_b * (positions[k][2] / (rays_b @ normal_b))[:, None])
        exact = plane_decompositions(rotation_ab + np.outer(translation_ab, normal_b) / positions[k][2], rays_a, rays_b)
        twin = int(np.argmax(geodesic_angle(exact[0], np.broadcast_to(rotation_ab, (2, 3, 3)))))
        pick = {"twin": twin, "true": 1 - twin}.get(pose_of)
        pose = (SimpleNamespace(rotation=exact[0][pick], translation_direction=_unit(exact[1][pick])) if pick is not None
                else SimpleNamespace(rotation=Rotation.from_rotvec([0.006, 0.0, 0.0]).as_matrix() @ rotation_ab,
                                     translation_direction=_unit(translation_ab)))
        info = SimpleNamespace(model="5pt", inlier_mask=np.ones(90, dtype=bool),
                               selection=SimpleNamespace(noise_sigma_rad=np.sqrt(2.0) * sigma))
        corr = SimpleNamespace(rays_a=_noisy(rays_a, sigma, rng), rays_b=_noisy(rays_b, sigma, rng),
                               rays_per_measurement=1)
        chain.observe(k, corr, pose, info, threshold_rad=5.0 * sigma)
        chained.append(chained[-1] @ pose.rotation)
        records.append(FrameRecord(k, k - 1, True, "", 90, 90, 0.0, "5pt"))
    references = np.maximum(np.arange(frames) - 1, 0)  # every frame chained from the one before
    rotations, _, labelled = chain.apply(np.array(chained), np.zeros((frames, 3)), records, references)
    return np.array(chained), rotations, [r.diagnostics.get(PLANE_TWIN) for r in labelled], world[0].T @ world


def test_the_tracker_record_re_chains_planar_pairs_and_labels_them():
    chained, rotations, labels, truth = _tracked(np.random.default_rng(11), pose_of="twin")
    assert np.max(geodesic_angle(chained, truth)) > 0.1  # every pair the twin: 30 mrad each
    assert np.max(geodesic_angle(rotations, truth)) < 0.01
    assert labels == [None] + ["swapped"] * (len(truth) - 1)


def test_kept_pairs_keep_their_pose_exactly_and_replaced_ones_say_so():
    # 5-point poses at the true decomposition: kept, the chain unchanged to the last bit.
    chained, rotations, labels, _ = _tracked(np.random.default_rng(11), pose_of="true")
    assert labels == [None] + ["kept"] * (len(chained) - 1)
    np.testing.assert_array_equal(rotations, chained)
    # 6 mrad off the truth, over a tenth of the way to the twin: the nearer decomposition replaces them.
    chained, rotations, labels, truth = _tracked(np.random.default_rng(11), pose_of="off")
    assert labels == [None] + ["homography"] * (len(chained) - 1)
    assert np.all(geodesic_angle(rotations[1:], chained[1:]) > 1e-3)
    assert np.max(geodesic_angle(rotations, truth)) < 0.01


def test_a_pair_at_the_chosen_decomposition_keeps_its_pose_and_one_between_them_does_not():
    from ifmi.backend.plane_twin import replaces_estimate

    rng = np.random.default_rng(12)
    sigma = 1e-3
    rotation_ab, translation_ab, _, points_b = _plane_pair(rng)
    rays_a, rays_b = (_noisy(rays, sigma, rng) for rays in _pair_rays(rotation_ab, translation_ab, points_b))
    options = dict(noise_sigma_rad=np.sqrt(2.0) * sigma, threshold_rad=5.0 * sigma)
    at_truth = planar_pair(rays_a, rays_b, rotation_ab, _unit(translation_ab), **options)
    true = at_truth.current
    assert not replaces_estimate(at_truth, true)
    assert replaces_estimate(at_truth, 1 - true)
    # A 5-point pose halfway between the two decompositions is replaced by either.
    halfway = Rotation.from_matrix(at_truth.rotations).mean().as_matrix()
    between = planar_pair(rays_a, rays_b, halfway, _unit(translation_ab), **options)
    assert replaces_estimate(between, 0) and replaces_estimate(between, 1)


@pytest.mark.parametrize("field, value", [("normal_tolerance_rad", 0.0), ("min_plane_share", 1.5),
                                          ("agreement_fraction", 0.5), ("min_planar_pairs", 1)])
def test_options_out_of_range_are_refused(field, value):
    with pytest.raises(ValueError, match=field):
        PlaneTwinOptions(**{field: value})


@pytest.mark.parametrize("seed", range(3))
def test_a_straight_track_of_twins_only_is_set_right_by_the_drift_they_add(seed):
    # No turn of the heading: the twins' normals move only with the rotation error each twin adds.
    rng = np.random.default_rng(seed)
    relative, planar, true_index, _ = _sequence(rng, step=0.05, turn_rad=0.0, sigma=1e-3,
                                                twins=np.ones(12, dtype=bool))
    assert resolve_plane_twins(np.maximum(np.arange(12) - 1, 0), relative, planar) == true_index
