"""Relative pose from rays: 5-point RANSAC with refinement, rotation-only model, failures."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.backend.relative_pose import (RelativePoseOptions, epipolar_angles, relative_pose_from_rays,
                                        rotation_from_rays)
from ifmi.geometry.rotations import geodesic_angle


def _options(**kwargs):
    """Options with an angular threshold well above the scenes' ray noise (at most 3e-4 rad)."""
    return RelativePoseOptions(**{"ransac_threshold_rad": 2e-3, **kwargs})


def _scene(n=150, outliers=30, translation=(0.4, -0.2, 0.1), seed=0, noise_rad=0.0):
    rng = np.random.default_rng(seed)
    points_b = rng.normal(size=(n, 3))
    points_b *= rng.uniform(2.0, 6.0, (n, 1)) / np.linalg.norm(points_b, axis=1, keepdims=True)
    rotation = Rotation.from_rotvec([0.05, -0.12, 0.3]).as_matrix()
    points_a = points_b @ rotation.T + np.asarray(translation)
    rays_a = points_a / np.linalg.norm(points_a, axis=1, keepdims=True)
    rays_b = points_b / np.linalg.norm(points_b, axis=1, keepdims=True)
    if noise_rad:
        rays_a = rays_a + rng.normal(0, noise_rad, rays_a.shape)
        rays_a /= np.linalg.norm(rays_a, axis=1, keepdims=True)
    bad = rng.choice(n, outliers, replace=False)
    junk = rng.normal(size=(outliers, 3))
    rays_a[bad] = junk / np.linalg.norm(junk, axis=1, keepdims=True)
    truth = np.zeros(n, dtype=bool)
    truth[bad] = True
    return rays_a, rays_b, rotation, np.asarray(translation), truth


def test_five_point_with_outliers_is_exact_at_zero_noise():
    rays_a, rays_b, rotation, t, outlier = _scene()
    pose, info = relative_pose_from_rays(rays_a, rays_b, options=_options(seed=3))
    assert info.success and info.model == "5pt"
    assert np.degrees(geodesic_angle(rotation, pose.rotation)) < 0.01
    assert np.allclose(pose.translation_direction, t / np.linalg.norm(t), atol=1e-4)
    assert np.array_equal(info.inlier_mask, ~outlier)


def test_five_point_with_noise(assert_rotation_close):
    rays_a, rays_b, rotation, _, _ = _scene(noise_rad=2e-4, seed=1)
    pose, info = relative_pose_from_rays(rays_a, rays_b, options=_options(seed=1))
    assert info.success
    # 120 inliers with 2e-4 rad noise: the rotation is good to a few 1e-5 rad.
    assert_rotation_close(pose.rotation, rotation, atol_rad=1e-4)


def test_pure_rotation_selects_the_rotation_model(assert_rotation_close):
    rays_a, rays_b, rotation, _, outlier = _scene(translation=(0.0, 0.0, 0.0), noise_rad=1e-4)
    pose, info = relative_pose_from_rays(rays_a, rays_b, options=_options())
    assert info.success and info.model == "rotation"
    assert np.all(pose.translation_direction == 0)
    assert_rotation_close(pose.rotation, rotation, atol_rad=1e-4)
    assert not info.inlier_mask[outlier].any()


def test_forced_rotation_only():
    rays_a, rays_b, rotation, _, _ = _scene(translation=(0.0, 0.0, 0.0))
    pose, info = relative_pose_from_rays(rays_a, rays_b, options=_options(rotation_only=True))
    assert info.model == "rotation"
    assert np.degrees(geodesic_angle(rotation, pose.rotation)) < 1e-6


def test_same_seed_same_result():
    rays_a, rays_b, *_ = _scene(noise_rad=3e-4, seed=4)
    p1, i1 = relative_pose_from_rays(rays_a, rays_b, options=_options(seed=9))
    p2, i2 = relative_pose_from_rays(rays_a, rays_b, options=_options(seed=9))
    assert np.array_equal(p1.rotation, p2.rotation) and np.array_equal(i1.inlier_mask, i2.inlier_mask)


def test_kabsch_recovers_rotation():
    rng = np.random.default_rng(2)
    rays_b = rng.normal(size=(20, 3))
    rays_b /= np.linalg.norm(rays_b, axis=1, keepdims=True)
    rotation = Rotation.from_rotvec([0.3, 0.2, -1.0]).as_matrix()
    assert np.allclose(rotation_from_rays(rays_b @ rotation.T, rays_b), rotation)


def test_too_few_correspondences_fails():
    rays_a, rays_b, *_ = _scene(n=6, outliers=0)
    pose, info = relative_pose_from_rays(rays_a, rays_b, options=_options(min_inliers=8))
    assert not info.success and "too few correspondences" in info.reason
    assert np.array_equal(pose.rotation, np.eye(3))


def test_random_rays_fail_with_too_few_inliers():
    rng = np.random.default_rng(0)
    rays = rng.normal(size=(2, 60, 3))
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    _, info = relative_pose_from_rays(rays[0], rays[1], options=RelativePoseOptions(
        ransac_threshold_rad=1e-4, min_inliers=20))
    assert not info.success and "too few inliers" in info.reason


def test_mismatched_shapes_are_rejected():
    with pytest.raises(ValueError, match="equal shape"):
        relative_pose_from_rays(np.zeros((5, 3)), np.zeros((4, 3)), options=_options())


def test_unresolved_threshold_is_rejected():
    rays_a, rays_b, *_ = _scene()
    with pytest.raises(ValueError, match="ransac_threshold_rad is None"):
        relative_pose_from_rays(rays_a, rays_b, options=RelativePoseOptions())


@pytest.mark.parametrize("group", [0, 1.5, True])
def test_bad_group_size_is_rejected(group):
    rays_a, rays_b, *_ = _scene()
    with pytest.raises(ValueError, match=f"expected rays_per_measurement to be an integer >= 1, "
                                         f"got {group!r}"):
        relative_pose_from_rays(rays_a, rays_b, options=_options(), rays_per_measurement=group)


def test_non_finite_rays_are_rejected():
    rays_a, rays_b, *_ = _scene()
    rays_b[[3, 7]] = np.nan
    with pytest.raises(ValueError, match="rays must be finite; 2 of 150 rows are not"):
        relative_pose_from_rays(rays_a, rays_b, options=_options())


def test_pixel_threshold_resolves_and_explicit_threshold_wins():
    options = RelativePoseOptions(ransac_threshold_px=1.5)
    assert options.resolved(4e-3).ransac_threshold_rad == pytest.approx(6e-3)
    explicit = RelativePoseOptions(ransac_threshold_rad=1e-3, ransac_threshold_px=1.5)
    assert explicit.resolved(4e-3) is explicit
    with pytest.raises(ValueError, match="pixel_angle_rad"):
        options.resolved(0.0)


def test_noise_sigma_from_truncated_residuals():
    from ifmi.backend.relative_pose import noise_sigma_from_residuals

    rng = np.random.default_rng(5)
    sigma = 1e-3
    # Rotation-model residual: the norm of a 2-D Gaussian error (Rayleigh with scale sigma).
    angles = np.linalg.norm(rng.normal(0.0, sigma, (4000, 2)), axis=1)
    for threshold in (1.5 * sigma, 4 * sigma):
        kept = angles[angles < threshold]
        # The plain RMS of the kept residuals is biased low at a tight threshold; the
        # truncated maximum-likelihood estimate is not (4000 samples: a few % error).
        assert noise_sigma_from_residuals(kept, threshold) == pytest.approx(sigma, rel=0.06)
    assert np.sqrt(np.mean(angles[angles < 1.5 * sigma] ** 2) / 2) < 0.75 * sigma


@pytest.mark.parametrize("noise_rad", [1e-4, 1e-3, 3e-3])
def test_pure_rotation_picks_rotation_model_whatever_the_noise_to_threshold_ratio(noise_rad):
    # Noise from well below to above the threshold's half: with the noise level taken
    # from the data, GRIC must not hand pure rotations to the 5-point model.
    rays_a, rays_b, rotation, _, _ = _scene(n=400, outliers=80, translation=(0.0, 0.0, 0.0),
                                            noise_rad=noise_rad, seed=7)
    pose, info = relative_pose_from_rays(rays_a, rays_b, options=_options(ransac_threshold_rad=4e-3))
    assert info.success and info.model == "rotation"
    # 320 inliers: the Kabsch rotation is good to about noise / sqrt(320) per axis.
    assert geodesic_angle(rotation, pose.rotation) < 5 * noise_rad / np.sqrt(320) + 1e-6


def test_reweighting_discounts_loose_inliers():
    # Heavy-tailed inliers: 240 rays with 5e-5 rad noise and 80 with 1.5e-3 rad (all
    # within the 4e-3 rad threshold), plus gross outliers.
    rays_a, rays_b, rotation, _, outlier = _scene(n=400, outliers=80, translation=(0.0, 0.0, 0.0),
                                                  noise_rad=5e-5, seed=11)
    rng = np.random.default_rng(12)
    loose = rng.choice(np.flatnonzero(~outlier), 80, replace=False)
    rays_a[loose] += rng.normal(0.0, 1.5e-3, (80, 3))
    rays_a /= np.linalg.norm(rays_a, axis=1, keepdims=True)
    errors = {}
    for iterations in (0, 5):
        options = _options(ransac_threshold_rad=4e-3, robust_iterations=iterations)
        pose, info = relative_pose_from_rays(rays_a, rays_b, options=options)
        assert info.success and info.model == "rotation"
        errors[iterations] = geodesic_angle(rotation, pose.rotation)
    # Least squares averages the loose rays in (about 1.5e-3 * sqrt(80) / 320 = 4e-5 rad);
    # the reweighted fit follows the 240 tight ones (5e-5 / sqrt(240) = 3e-6 rad, with the
    # loose rays' remaining weight about 1e-5 rad). Over seeds 11..18 the gain is 5.7..13x.
    assert errors[5] < 2e-5 and errors[5] < errors[0] / 3
    with pytest.raises(ValueError, match="robust_iterations"):
        RelativePoseOptions(robust_iterations=-1)


def _unit(rng, shape):
    v = rng.normal(size=shape)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_epipolar_angles_match_the_plane_definition():
    from ifmi.backend.relative_pose import epipolar_angles

    rng = np.random.default_rng(21)
    rays_a, rays_b = _unit(rng, (50, 3)), _unit(rng, (50, 3))
    rotations = Rotation.from_rotvec(rng.normal(0.0, 0.5, (4, 3))).as_matrix()
    translations = rng.normal(size=(4, 3))  # any length
    for k in range(4):
        normal = np.cross(translations[k], rays_b @ rotations[k].T)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        expected = np.arcsin(np.abs(np.sum(rays_a * normal, axis=1)))
        assert np.allclose(epipolar_angles(rays_a, rays_b, rotations, translations)[k], expected,
                           rtol=0, atol=1e-12)


def test_rotation_angles_resolve_small_angles():
    from ifmi.backend.relative_pose import rotation_angles

    rng = np.random.default_rng(22)
    rays_b = _unit(rng, (20, 3))
    for angle in (1e-7, 1e-3, 2.0):
        axis = _unit(rng, (3,))
        rotation = Rotation.from_rotvec(angle * axis).as_matrix()
        # Rays orthogonal to the axis turn by exactly the rotation angle.
        orthogonal = rays_b - np.outer(rays_b @ axis, axis)
        orthogonal /= np.linalg.norm(orthogonal, axis=1, keepdims=True)
        assert np.allclose(rotation_angles(orthogonal @ rotation.T, orthogonal, rotation[None])[0],
                           0.0, atol=1e-15)
        assert np.allclose(rotation_angles(orthogonal, orthogonal, rotation), angle, rtol=1e-9)


def test_symmetric_residual_jacobian_matches_finite_differences():
    from ifmi.backend.relative_pose import _symmetric_epipolar_residuals

    rng = np.random.default_rng(23)
    rays_a, rays_b = _unit(rng, (40, 3)), _unit(rng, (40, 3))
    rotation = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix()
    t = _unit(rng, (3,))
    residuals, jac, basis = _symmetric_epipolar_residuals(rays_a, rays_b, rotation, t)
    assert np.allclose(basis @ t, 0.0, atol=1e-15) and np.allclose(basis @ basis.T, np.eye(2))
    # The residuals by their definition.
    rotated = rays_b @ rotation.T
    n1, n2 = np.cross(t, rotated), np.cross(t, rays_a)
    expected = np.concatenate([np.sum(rays_a * n1, axis=1) / np.linalg.norm(n1, axis=1),
                               np.sum(rotated * n2, axis=1) / np.linalg.norm(n2, axis=1)])
    assert np.allclose(residuals, expected, rtol=0, atol=1e-14)

    def perturbed(params):
        r = Rotation.from_rotvec(params[:3]).as_matrix() @ rotation
        moved = t + params[3:] @ basis
        return _symmetric_epipolar_residuals(rays_a, rays_b, r, moved / np.linalg.norm(moved),
                                             jacobian=False)[0]

    step = 1e-6
    numeric = np.stack([(perturbed(step * e) - perturbed(-step * e)) / (2 * step) for e in np.eye(5)], axis=1)
    # Central differences: truncation ~ step^2 and rounding ~ 1e-16 / step, both far below 1e-7.
    assert np.abs(numeric - jac).max() < 1e-7 * max(1.0, np.abs(jac).max())


def test_two_pair_rotations_equal_kabsch():
    from ifmi.backend.relative_pose import _rotations_from_ray_pairs

    rng = np.random.default_rng(24)
    rays = _unit(rng, (2, 30, 3))
    first = np.arange(15)
    second = first + 15
    closed = _rotations_from_ray_pairs(rays, first, second)
    pairs = np.stack([first, second], axis=1)
    kabsch = rotation_from_rays(rays[0][pairs], rays[1][pairs])
    assert np.allclose(closed, kabsch, atol=1e-12)
    assert np.allclose(np.linalg.det(closed), 1.0)


def test_rotation_from_rotation_vector_matches_scipy():
    from ifmi.backend.relative_pose import _rotation_from_rotvec

    rng = np.random.default_rng(25)
    for scale in (0.0, 1e-13, 1e-6, 1e-2, 1.0, 3.0):
        rotvec = scale * _unit(rng, (3,))
        assert np.allclose(_rotation_from_rotvec(rotvec), Rotation.from_rotvec(rotvec).as_matrix(),
                           rtol=0, atol=1e-15)



def test_two_pair_rotations_of_degenerate_pairs_are_rotations():
    from ifmi.backend.relative_pose import _rotations_from_ray_pairs

    rng = np.random.default_rng(27)
    rays = _unit(rng, (2, 6, 3))
    rays[:, 1] = rays[:, 0]  # pair 0 and 1: equal rays in both frames
    rays[:, 3] = -rays[:, 2]  # pair 2 and 3: opposite rays
    first, second = np.array([0, 2, 4]), np.array([1, 3, 5])
    rotations = _rotations_from_ray_pairs(rays, first, second)
    assert np.allclose(rotations @ np.swapaxes(rotations, 1, 2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(rotations), 1.0)
    # The degenerate pairs fall back to the SVD (whose turn about the ray is arbitrary but
    # deterministic), the regular pair is solved in closed form: all equal the Kabsch solution.
    pairs = np.stack([first, second], axis=1)
    assert np.allclose(rotations, rotation_from_rays(rays[0][pairs], rays[1][pairs]), atol=1e-12)
    for k in range(2):
        assert np.allclose(rotations[k] @ rays[1, first[k]], rays[0, first[k]], atol=1e-12)


def _grouped_rays(seed: int, *, groups: int = 20, size: int = 5, noise_rad: float = 3e-3,
                  translation=None, with_rotation: bool = False):
    """Rays in tight groups (like flow points of one tile) whose members share one error."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(groups, 3))
    centres[:, 2] *= 0.3
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    rays_b = centres[:, None] + rng.normal(scale=0.02, size=(groups, size, 3))
    rays_b /= np.linalg.norm(rays_b, axis=-1, keepdims=True)
    rotation = Rotation.from_rotvec(rng.normal(scale=0.05, size=3)).as_matrix()
    points = rays_b * rng.uniform(2.0, 6.0, size=(groups, 1, 1)) @ rotation.T
    if translation is not None:
        points = points + translation
    rays_a = points / np.linalg.norm(points, axis=-1, keepdims=True)
    rays_a = rays_a + rng.normal(scale=noise_rad, size=(groups, 1, 3))
    rays_a /= np.linalg.norm(rays_a, axis=-1, keepdims=True)
    if with_rotation:
        return rays_a.reshape(-1, 3), rays_b.reshape(-1, 3), rotation
    return rays_a.reshape(-1, 3), rays_b.reshape(-1, 3)


def test_grouped_errors_do_not_make_a_pure_rotation_look_like_translation():
    # Counted once per ray, errors shared by a group of five rays are five times the evidence
    # they are; the 5-point model's two extra degrees of freedom then fit some of them.
    options = RelativePoseOptions(ransac_threshold_rad=0.004)
    chosen = {}
    for group in (1, 5):
        models = [relative_pose_from_rays(*_grouped_rays(seed), options=options,
                                          rays_per_measurement=group)[1].model for seed in range(30)]
        chosen[group] = models.count("5pt")
    # Measured with the noise (3e-3 rad) near the threshold and 20 groups: 19 of 30 pure
    # rotations taken for 5-point motion per ray, 2 per group.
    assert chosen[1] >= 8 and chosen[5] <= 3
    # A translation is told from the noise once the noise is measurable inside the threshold
    # (here 1.5e-3 rad against 4e-3; at 3e-3 the inliers spread evenly up to the threshold).
    translating = [relative_pose_from_rays(*_grouped_rays(seed, noise_rad=1.5e-3,
                                                          translation=np.array([0.3, 0.1, 0.0])),
                                           options=options, rays_per_measurement=5)[1].model
                   for seed in range(30)]
    assert translating.count("5pt") == 30


@pytest.mark.parametrize("value", [0, 2.5, True])
def test_rays_per_measurement_is_validated(value):
    rays = np.tile([[1.0, 0.0, 0.0]], (10, 1))
    with pytest.raises(ValueError, match="rays_per_measurement"):
        relative_pose_from_rays(rays, rays, options=RelativePoseOptions(ransac_threshold_rad=0.01),
                                rays_per_measurement=value)


def test_small_translation_is_found_when_its_parallax_exceeds_the_noise():
    # A 2 cm step among points 2-6 m away moves rays by up to about 10 mrad: well above the
    # ray noise, yet the rotation model's residuals hold that parallax, so a noise level taken
    # from them was inflated and handed 11 of these 20 pairs to the rotation model. The
    # noise is taken from the 5-point model's residuals instead (its upper bound of one standard
    # error). Measured: 2 and 1 of the 20 pure rotations at the two noise levels taken for
    # 5-point motion.
    options = RelativePoseOptions(ransac_threshold_rad=0.004)
    for noise_rad in (2e-4, 5e-4):
        moving = [relative_pose_from_rays(*_grouped_rays(seed, noise_rad=noise_rad,
                                                         translation=np.array([0.02, 0.007, 0.0])),
                                          options=options, rays_per_measurement=5)[1].model
                  for seed in range(20)]
        still = [relative_pose_from_rays(*_grouped_rays(seed, noise_rad=noise_rad), options=options,
                                         rays_per_measurement=5)[1].model for seed in range(20)]
        assert moving.count("5pt") == 20 and still.count("5pt") <= 3


def _wall_rays(seed: int, *, wall_tiles: int = 10, other_tiles: int = 5, size: int = 5,
               noise_rad: float = 2e-3, wall_m: float = 3.3):
    """Tile-like ray groups of a fast translated pair in a room: ``wall_tiles`` on the wall ahead
    (x = ``wall_m``), perpendicular to a 0.35 m step along y, and ``other_tiles`` on side walls
    2-3 m away. Parallax on the front wall is almost a uniform yaw of step / distance
    (0.106 rad), which a rotation fits to within the threshold there."""
    rng = np.random.default_rng(seed)
    step = np.array([0.0, 0.35, 0.0])
    azimuth = np.concatenate([rng.uniform(-0.25, 0.25, wall_tiles),
                              rng.choice([-1, 1], other_tiles) * rng.uniform(1.2, 1.9, other_tiles)])
    elevation = rng.uniform(-0.3, 0.3, wall_tiles + other_tiles)
    distance = np.concatenate([wall_m / np.cos(azimuth[:wall_tiles]), rng.uniform(2.0, 3.0, other_tiles)])
    centres = np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                        np.sin(elevation)], axis=1)
    points_a = centres[:, None] * distance[:, None, None] + rng.normal(scale=0.05, size=(len(azimuth), size, 3))
    rotation = Rotation.from_rotvec([0.0, 0.0, 0.48]).as_matrix()
    rays_b = (points_a - step) @ rotation
    rays_b /= np.linalg.norm(rays_b, axis=-1, keepdims=True)
    rays_a = points_a / np.linalg.norm(points_a, axis=-1, keepdims=True)
    rays_a = rays_a + rng.normal(scale=noise_rad, size=(len(azimuth), 1, 3))
    rays_a /= np.linalg.norm(rays_a, axis=-1, keepdims=True)
    return rays_a.reshape(-1, 3), rays_b.reshape(-1, 3), rotation


def test_rotation_fitting_only_the_parallax_of_one_wall_loses_to_the_five_point_model():
    # 15 tiles, 10 on one wall: a rotation 0.106 rad off fits those 10, the 5-point motion all 15.
    # GRIC with the ray noise of the 5-point model's residuals charges the rotation model for the
    # five tiles it misses (measured: all 20 pairs 5-point, errors 1.0-4.8 mrad at 2e-3 rad noise).
    options = RelativePoseOptions(ransac_threshold_rad=0.0122)
    results = []
    for seed in range(20):
        rays_a, rays_b, rotation = _wall_rays(seed)
        pose, info = relative_pose_from_rays(rays_a, rays_b, options=options, rays_per_measurement=5)
        results.append((info.model, geodesic_angle(pose.rotation, rotation)))
    assert sum(model == "5pt" and error < 0.008 for model, error in results) >= 19
    assert np.median([error for _, error in results]) < 0.005


def test_forcing_both_models_is_refused():
    with pytest.raises(ValueError, match="rotation_only and five_point_only"):
        RelativePoseOptions(rotation_only=True, five_point_only=True)


@pytest.mark.parametrize("options", [{"max_iterations": 0}, {"max_iterations": 10 ** 12},
                                     {"min_iterations": -1}, {"min_iterations": 10 ** 9}])
def test_ransac_sample_counts_out_of_range_are_refused(options):
    # A count past 100 000 only turns a hopeless pair into a hang (or, as a minimum, one huge chunk).
    with pytest.raises(ValueError, match=r"expected 1 <= max_iterations <= 100000 and 0 <= min_iterations"):
        RelativePoseOptions(**options)


def _narrow_translated_scene(seed, n=80, half_angle_rad=0.3, noise_rad=5e-4, near_outliers=6,
                             step=(0.0, 0.3, 0.05)):
    """Rays of points 2-4 m away in a cone of +-0.3 rad about +x (tiles that passed on one side of a
    room), a step (default mostly sideways, 0.3 m), noise, and a few rays pushed a few thresholds off."""
    rng = np.random.default_rng(seed)
    directions = np.column_stack([np.ones(n), rng.uniform(-half_angle_rad, half_angle_rad, (n, 2))])
    points_b = directions / np.linalg.norm(directions, axis=1, keepdims=True) * rng.uniform(2.0, 4.0, (n, 1))
    rotation = Rotation.from_rotvec([0.02, -0.05, 0.4]).as_matrix()
    points_a = points_b @ rotation.T + np.asarray(step, dtype=float)
    rays_a = points_a / np.linalg.norm(points_a, axis=1, keepdims=True)
    rays_b = points_b / np.linalg.norm(points_b, axis=1, keepdims=True)
    rays_a += rng.normal(0.0, noise_rad, rays_a.shape)
    rays_a[rng.choice(n, near_outliers, replace=False)] += rng.normal(0.0, 4e-3, (near_outliers, 3))
    return rays_a / np.linalg.norm(rays_a, axis=1, keepdims=True), rays_b, rotation


def test_polishing_the_inlier_set_lowers_the_narrow_field_error():
    # A minimal sample's model sorts rays near the threshold wrongly; over a narrow field one
    # such ray moves the rotation a lot. Measured over these 60 scenes after a short draw (8
    # samples at least): RMS rotation error 2.81 -> 2.24 mrad and worst 9.0 -> 4.4 mrad with three
    # polishing rounds. The default draw (40 samples at least) reaches 2.40 mrad and worst 4.5
    # unpolished, and polishing then changes them by 2 % and 0 %: it guards short draws.
    errors = {}
    for rounds in (0, 3):
        errors[rounds] = []
        for seed in range(60):
            rays_a, rays_b, rotation = _narrow_translated_scene(seed)
            options = _options(polish_rounds=rounds, seed=seed, min_iterations=8)
            pose, info = relative_pose_from_rays(rays_a, rays_b, options=options)
            assert info.success and info.model == "5pt"
            errors[rounds].append(geodesic_angle(rotation, pose.rotation))
    plain, polished = np.asarray(errors[0]), np.asarray(errors[3])
    assert np.sqrt(np.mean(polished ** 2)) < 0.9 * np.sqrt(np.mean(plain ** 2))
    assert polished.max() < 0.6 * plain.max()


@pytest.mark.parametrize("rounds", [-1, 101])
def test_polish_rounds_out_of_range_are_refused(rounds):
    with pytest.raises(ValueError, match=r"expected 0 <= polish_rounds <= 100, got"):
        RelativePoseOptions(polish_rounds=rounds)


def test_refining_several_hypotheses_leaves_the_second_minimum():
    # A small sideways step seen over a narrow field: the epipolar cost has a second minimum (the
    # translation near the viewing direction, the rotation off), and refinement stays in the basin
    # its hypothesis starts in. Measured over these 60 scenes with one hypothesis refined and five:
    # RMS rotation error 2.81 -> 2.25 mrad, worst 13.0 -> 4.3 mrad (with at least 8 RANSAC samples
    # instead of 40: 5.6 -> 2.2 and 28.3 -> 4.3).
    errors = {}
    for keep in (1, 5):
        errors[keep] = []
        for seed in range(60):
            rays_a, rays_b, rotation = _narrow_translated_scene(seed, step=(0.0, 0.1, 0.02))
            pose, info = relative_pose_from_rays(rays_a, rays_b,
                                                 options=_options(refine_hypotheses=keep, seed=seed))
            assert info.success and info.model == "5pt"
            errors[keep].append(geodesic_angle(rotation, pose.rotation))
    one, several = np.asarray(errors[1]), np.asarray(errors[5])
    assert np.sqrt(np.mean(several ** 2)) < 0.9 * np.sqrt(np.mean(one ** 2))
    assert several.max() < 0.5 * one.max()


def test_refined_hypotheses_never_raise_the_truncated_cost():
    # The best RANSAC hypothesis is always among those refined, so keeping the lowest truncated cost
    # can only lower it: the chosen model's cost with five hypotheses is at most that with one.
    from ifmi.backend.relative_pose import epipolar_angles
    threshold = 2e-3
    for seed in range(20):
        rays_a, rays_b, _ = _narrow_translated_scene(seed, step=(0.0, 0.1, 0.02))
        costs = []
        for keep in (1, 5):
            pose, _ = relative_pose_from_rays(rays_a, rays_b, options=_options(refine_hypotheses=keep, seed=seed))
            angles = epipolar_angles(rays_a, rays_b, pose.rotation[None], pose.translation_direction[None])[0]
            costs.append(np.minimum(angles, threshold).sum())
        assert costs[1] <= costs[0] + 1e-12


@pytest.mark.parametrize("keep", [0, 101])
def test_refine_hypotheses_out_of_range_are_refused(keep):
    with pytest.raises(ValueError, match=r"expected 1 <= refine_hypotheses <= 100, got"):
        RelativePoseOptions(refine_hypotheses=keep)


def test_distinct_best_orders_by_inliers_then_cost_and_drops_the_same_model():
    from ifmi.backend.relative_pose import _distinct_best
    threshold = 1e-3

    def turned(angle):
        return Rotation.from_rotvec([0.0, 0.0, angle]).as_matrix()

    t, t_side = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    candidates = [(9, 0.5, turned(0.3), t),            # fewer inliers: after the 10s
                  (10, 2.0, turned(0.5 * threshold), t),  # within the threshold of the next in both: dropped
                  (10, 1.0, turned(0.0), t),           # the best: most inliers, lowest cost
                  (8, 0.1, turned(0.0), t_side)]       # same rotation, translation 90 degrees off: kept
    kept = _distinct_best(candidates, threshold, 3)
    assert len(kept) == 3
    np.testing.assert_array_equal(kept[0][0], turned(0.0))
    np.testing.assert_array_equal(kept[1][0], turned(0.3))
    np.testing.assert_array_equal(kept[2][1], t_side)
    assert len(_distinct_best(candidates, threshold, 1)) == 1
    assert len(_distinct_best(candidates, threshold, 10)) == 3
    assert _distinct_best([], threshold, 5) == []



@pytest.mark.parametrize("translation, size", [((0.3, 0.1, 0.0), 1), ((0.3, 0.1, 0.0), 5),
                                               (None, 1), (None, 5)])
@pytest.mark.slow
def test_predicted_rotation_error_matches_the_error_over_noise_draws(translation, size):
    # 300 scenes with 1e-3 rad ray noise shared by groups of `size` rays: the RMS of the predicted
    # errors matches the RMS of the true ones to first order (measured ratios 0.98, 1.12, 0.98,
    # 1.00 in the order of the parameters; an RMS over 300 three-axis errors is itself good to
    # about 3 %). Counting each ray of a group as its own measurement would predict sqrt(5) too little.
    translation = None if translation is None else np.array(translation)
    options = RelativePoseOptions(ransac_threshold_rad=8e-3, rotation_only=translation is None,
                                  robust_iterations=0)  # least squares, which the prediction describes
    errors, predicted = [], []
    for seed in range(300):
        rays_a, rays_b, rotation = _grouped_rays(seed, groups=60 // size, size=size, noise_rad=1e-3,
                                                 translation=translation, with_rotation=True)
        pose, info = relative_pose_from_rays(rays_a, rays_b, options=options, rays_per_measurement=size)
        assert info.success and info.model == ("rotation" if translation is None else "5pt")
        errors.append(geodesic_angle(rotation, pose.rotation))
        predicted.append(info.rotation_sigma_rad)
    ratio = np.sqrt(np.mean(np.square(predicted)) / np.mean(np.square(errors)))
    assert 0.8 < ratio < 1.25


def test_predicted_rotation_error_is_zero_for_exact_rays_and_nan_on_failure():
    rays_a, rays_b, _, _, _ = _scene(outliers=0)
    _, info = relative_pose_from_rays(rays_a, rays_b, options=_options())
    assert info.model == "5pt" and info.rotation_sigma_rad < 1e-9
    rays_a, rays_b, _, _, _ = _scene(n=6, outliers=0)
    _, info = relative_pose_from_rays(rays_a, rays_b, options=_options())
    assert not info.success and np.isnan(info.rotation_sigma_rad)


def test_two_agreeing_measurements_are_too_few_however_many_rays_they_hold():
    """Two tiles of five flow points fit any rotation: ten inlier rays, but only two measurements."""
    rng = np.random.default_rng(4)
    truth = Rotation.from_rotvec([0.05, -0.02, 0.3]).as_matrix()
    rays_b = rng.normal(size=(25, 3))
    rays_b /= np.linalg.norm(rays_b, axis=1, keepdims=True)
    rays_a = rng.normal(size=(25, 3))  # three tiles of unrelated rays
    rays_a /= np.linalg.norm(rays_a, axis=1, keepdims=True)
    rays_a[:10] = rays_b[:10] @ truth.T  # two tiles that agree with R_ab
    options = RelativePoseOptions(ransac_threshold_rad=1e-3, rotation_only=True)
    _, info = relative_pose_from_rays(rays_a, rays_b, options=options, rays_per_measurement=5)
    assert not info.success and info.n_inliers == 10
    assert info.reason == "too few measurements with inliers (2 < 3; 10 inlier rays in groups of 5)"
    pose, info = relative_pose_from_rays(rays_a, rays_b, rays_per_measurement=5,
                                         options=RelativePoseOptions(ransac_threshold_rad=1e-3, rotation_only=True,
                                                                     min_inlier_measurements=2))
    assert info.success and geodesic_angle(pose.rotation, truth) < 1e-9
    # The same ten rays as ten keypoint matches are ten measurements.
    _, info = relative_pose_from_rays(rays_a, rays_b, options=options)
    assert info.success


def test_min_inlier_measurements_below_one_is_refused():
    with pytest.raises(ValueError, match="min_inlier_measurements >= 1, got 8, 0"):
        RelativePoseOptions(min_inlier_measurements=0)


def _random_ray_pairs(n, seed):
    """``n`` unrelated ray pairs, uniform on the sphere: no motion relates them."""
    rays = np.random.default_rng(seed).normal(size=(2, n, 3))
    return rays / np.linalg.norm(rays, axis=2, keepdims=True)


@pytest.mark.parametrize("n, threshold", [(200, 0.02), (1000, 0.01), (2000, 0.003)])
def test_unrelated_rays_fail_as_chance_consensus(n, threshold):
    failed_as_chance = 0
    for seed in range(4):
        rays = _random_ray_pairs(n, seed)
        options = RelativePoseOptions(ransac_threshold_rad=threshold, seed=seed)
        pose, info = relative_pose_from_rays(rays[0], rays[1], options=options)
        assert not info.success and np.array_equal(pose.rotation, np.eye(3))
        failed_as_chance += "look like chance" in info.reason
        # Without the check, 5-point models of chance inliers pass every other test.
        _, unchecked = relative_pose_from_rays(rays[0], rays[1], options=replace(options, min_draw_success=0.0))
        assert unchecked.success == ("look like chance" in info.reason)
    assert failed_as_chance >= 2


def test_many_true_matches_among_many_outliers_pass():
    # 100 matches of a pure rotation among 1900 unrelated ones (5 % inliers): the rotation model's
    # 200 two-ray samples hold an outlier-free one with probability 0.39, below min_draw_success,
    # but chance pairings explain far fewer inliers.
    rays_a, rays_b, rotation, *_ = _scene(n=2000, outliers=1900, translation=(0.0, 0.0, 0.0), seed=2)
    pose, info = relative_pose_from_rays(rays_a, rays_b, options=_options(seed=1))
    assert info.success and info.model == "rotation" and info.n_inliers >= 100
    assert geodesic_angle(pose.rotation, rotation) < 1e-6


@pytest.mark.parametrize("field, value", [("min_draw_success", -0.1), ("min_draw_success", 1.5),
                                          ("max_chance_false_alarms", -1.0)])
def test_chance_check_options_are_validated(field, value):
    with pytest.raises(ValueError, match=field):
        RelativePoseOptions(**{field: value})


def _two_view(seed: int, *, translation_m: float, depth_m: float = 5.0, noise_rad: float = 1e-3, n: int = 200):
    """Rays of ``n`` points at ``depth_m`` (every direction) seen from two cameras ``translation_m``
    apart along x, camera a turned by a known rotation, with seeded ray noise ``noise_rad`` per axis
    on both cameras; the parallax of a ray perpendicular to the step is ``translation_m / depth_m``."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    points_b = depth_m * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    rotation = Rotation.from_rotvec([0.03, -0.02, 0.25]).as_matrix()
    points_a = points_b @ rotation.T + np.array([translation_m, 0.0, 0.0])
    rays = []
    for points in (points_a, points_b):
        noisy = points / np.linalg.norm(points, axis=1, keepdims=True) + rng.normal(0.0, noise_rad, (n, 3))
        rays.append(noisy / np.linalg.norm(noisy, axis=1, keepdims=True))
    return rays[0], rays[1], rotation


@pytest.mark.parametrize("translation_m, model", [(0.0, "rotation"), (0.001, "rotation"), (0.05, "5pt")])
def test_model_choice_follows_parallax_against_noise(translation_m, model):
    # Noise 1e-3 rad per axis on both rays: a residual of about 1.4e-3 rad per axis. A 1 mm step at
    # 5 m moves rays by at most 2e-4 rad, well below it: the rotation model. A 5 cm step moves them
    # by up to 1e-2 rad: the 5-point model. Measured: the chosen model on all 10 seeds each.
    options = RelativePoseOptions(ransac_threshold_rad=6e-3)
    for seed in range(10):
        rays_a, rays_b, rotation = _two_view(seed, translation_m=translation_m)
        pose, info = relative_pose_from_rays(rays_a, rays_b, options=options)
        selection = info.selection
        assert info.success and info.model == model
        assert (selection.gric_5pt < selection.gric_rotation) == (model == "5pt")
        # The noise of one epipolar angle is that of both rays: sqrt(2) * 1e-3 rad; weighed with its
        # upper bound of one standard error (1.05 times the estimate over 195 degrees of freedom).
        assert selection.noise_sigma_rad == pytest.approx(1.05 * np.sqrt(2.0) * 1e-3, rel=0.15)
        assert geodesic_angle(pose.rotation, rotation) < 1e-3


def test_model_choice_boundary_is_where_the_parallax_meets_the_noise():
    # Sweep the step: the share of 5-point choices rises from none to all as the median parallax
    # (the evidence reported) passes the noise level; measured over 10 seeds: none at 2 mm, all
    # at 2 cm.
    options = RelativePoseOptions(ransac_threshold_rad=6e-3)
    shares, parallaxes = [], []
    for translation_m in (0.002, 0.02):
        infos = [relative_pose_from_rays(*_two_view(seed, translation_m=translation_m)[:2], options=options)[1]
                 for seed in range(10)]
        shares.append(np.mean([info.model == "5pt" for info in infos]))
        parallaxes.append(np.median([info.selection.parallax_rad for info in infos]))
    # The parallax is measured as the rotation residual of the 5-point model's rotation, noise
    # included: a Rayleigh median of 1.18 noise levels without translation.
    noise_only = 1.1774 * np.sqrt(2.0) * 1e-3
    assert parallaxes[0] < 1.2 * noise_only < 1.5 * noise_only < parallaxes[1]


def test_noise_prior_settles_pairs_of_few_measurements():
    # Eight correspondences leave the 5-point model three degrees of freedom to measure the noise
    # with; chance makes that estimate small on a few pairs, and their rotation residuals then look
    # like parallax. Pooled with earlier evidence of the true noise (20 measurements' worth), every
    # pure rotation takes the rotation model and every 5 cm step the 5-point model. Measured over
    # the 100 seeds: without the prior 3 pure rotations took the 5-point model and 1 step did not.
    options = RelativePoseOptions(ransac_threshold_rad=6e-3, noise_prior_rms_rad=np.sqrt(2.0) * 1e-3,
                                  noise_prior_measurements=20.0)
    for translation_m, model in ((0.0, "rotation"), (0.05, "5pt")):
        models = [relative_pose_from_rays(*_two_view(seed, translation_m=translation_m, n=8)[:2],
                                          options=options)[1].model for seed in range(100)]
        assert models.count(model) == 100


def test_noise_prior_counts_as_that_many_measurements_of_its_mean_square():
    from ifmi.backend.relative_pose import _epipolar_noise_evidence, _epipolar_noise_sigma

    errors = np.random.default_rng(3).normal(0.0, 1e-3, 9)
    pooled = _epipolar_noise_sigma(_epipolar_noise_evidence(np.abs(errors), 6e-3, 1), 6e-3, confidence=0.84,
                                   prior=(2e-3, 4.0))
    appended = _epipolar_noise_sigma(_epipolar_noise_evidence(np.abs(np.r_[errors, np.full(4, 2e-3)]), 6e-3, 1),
                                     6e-3, confidence=0.84)
    assert pooled == pytest.approx(appended, rel=1e-12)
    # Four measurements (fewer than the model's five parameters) are measured with the prior only.
    four = _epipolar_noise_evidence(np.abs(errors[:4]), 6e-3, 1)
    assert _epipolar_noise_sigma(four, 6e-3) is None
    assert _epipolar_noise_sigma(four, 6e-3, prior=(2e-3, 4.0)) is not None


def test_a_pair_whose_noise_clearly_differs_from_the_prior_keeps_its_own():
    from ifmi.backend.relative_pose import _epipolar_noise_evidence, _epipolar_noise_sigma

    rng = np.random.default_rng(4)
    # 100 measurements of noise 1e-3 against a prior of 4e-3 worth 20: the F test rejects pooling.
    many = _epipolar_noise_evidence(np.abs(rng.normal(0.0, 1e-3, 100)), 6e-3, 1)
    assert _epipolar_noise_sigma(many, 6e-3, prior=(4e-3, 20.0)) == _epipolar_noise_sigma(many, 6e-3)
    # Eight measurements (three degrees of freedom) cannot tell noise half the prior's from it: pooled.
    few = _epipolar_noise_evidence(np.abs(rng.normal(0.0, 1e-3, 8)), 6e-3, 1)
    assert _epipolar_noise_sigma(few, 6e-3, prior=(2e-3, 20.0)) > 1.3 * _epipolar_noise_sigma(few, 6e-3)


@pytest.mark.parametrize("field, value", [("noise_prior_rms_rad", 0.0), ("noise_prior_rms_rad", -1e-3),
                                          ("noise_prior_measurements", -1.0)])
def test_noise_prior_options_are_checked(field, value):
    with pytest.raises(ValueError, match="noise_prior"):
        RelativePoseOptions(ransac_threshold_rad=6e-3, **{field: value})


def test_translation_prior_weighs_the_scores_by_twice_its_log_odds():
    from ifmi.backend.relative_pose import ModelSelection

    # The homography scores 1 below the rotation model: chosen without a prior. A prior of 0.2 adds
    # -2 log(0.25) = 2.77 to the translated scores: the rotation model; a prior of 0.7 keeps the choice.
    evidence = dict(gric_rotation=100.0, gric_5pt=104.0, gric_homography=99.0)
    assert ModelSelection(**evidence).prefers_translation
    turning = ModelSelection(**evidence, translation_prior=0.2)
    assert not turning.prefers_translation and turning.evidence_prefers_translation
    assert ModelSelection(**evidence, translation_prior=0.7).prefers_translation
    # The prior's log odds decide exactly at the margin: 2 log(p / (1 - p)) = -1 at p = 1 / (1 + e^0.5).
    edge = 1.0 / (1.0 + np.exp(0.5))
    assert ModelSelection(**evidence, translation_prior=edge * 1.001).prefers_translation
    assert not ModelSelection(**evidence, translation_prior=edge * 0.999).prefers_translation


def test_translation_prior_of_a_turning_sequence_settles_pure_rotations():
    # Eight correspondences: without a prior chance hands 3 of 100 pure rotations to the 5-point
    # model. After ten pairs that showed no translation (prior 1 / 12) none of them, while a 5 cm
    # step, whose parallax is clear, still takes the 5-point model (measured: 99 of 100 either way).
    counts = {}
    for prior in (None, 1.0 / 12.0):
        options = RelativePoseOptions(ransac_threshold_rad=6e-3, translation_prior=prior)
        for translation_m in (0.0, 0.05):
            models = [relative_pose_from_rays(*_two_view(seed, translation_m=translation_m, n=8)[:2],
                                              options=options)[1].model for seed in range(100)]
            counts[prior, translation_m] = models.count("5pt")
    assert counts[None, 0.0] >= 2 and counts[1.0 / 12.0, 0.0] == 0
    assert counts[None, 0.05] >= 98 and counts[1.0 / 12.0, 0.05] >= 98


@pytest.mark.parametrize("value", [0.0, 1.0, -0.2, 1.5])
def test_translation_prior_is_checked(value):
    with pytest.raises(ValueError, match="translation_prior must be in"):
        RelativePoseOptions(ransac_threshold_rad=6e-3, translation_prior=value)


def test_forced_five_point_model_and_its_evidence():
    rays_a, rays_b, rotation = _two_view(0, translation_m=0.0)
    pose, info = relative_pose_from_rays(rays_a, rays_b, options=RelativePoseOptions(
        ransac_threshold_rad=6e-3, five_point_only=True))
    assert info.success and info.model == "5pt"
    assert info.selection.gric_5pt > info.selection.gric_rotation  # forced against the evidence
    assert set(info.selection.columns()) == {"gric_rotation", "gric_5pt", "gric_homography", "parallax_rad",
                                             "selection_sigma_rad", "noise_rms_rad", "noise_measurements",
                                             "translation_prior"}


def _floor_view(seed: int, *, step_m: float = 0.02, height_m: float = 0.4, n: int = 150,
                noise_rad: float = 0.0):
    """Rays of ``n`` points of a floor ``height_m`` below camera a, seen 20 to 70 degrees off the
    nadir over three quarters of the azimuths (a wide view with a sector hidden), and from camera
    b one ``step_m`` along the floor and turned by a known rotation; seeded ray noise
    ``noise_rad`` per axis on camera a. Returns rays a, rays b, ``R_ab`` and ``t_ab``."""
    rng = np.random.default_rng(seed)
    off_nadir = np.arccos(rng.uniform(np.cos(np.radians(70.0)), np.cos(np.radians(20.0)), n))
    azimuth = rng.uniform(0.0, 1.5 * np.pi, n)
    rays_a = np.stack([np.sin(off_nadir) * np.cos(azimuth), np.sin(off_nadir) * np.sin(azimuth),
                       -np.cos(off_nadir)], axis=1)
    points_a = rays_a * (height_m / np.cos(off_nadir))[:, None]
    rotation = Rotation.from_rotvec([0.02, -0.03, 0.2]).as_matrix()
    translation = step_m * np.array([np.cos(seed), np.sin(seed), 0.0])
    points_b = (points_a - translation) @ rotation  # X_a = R_ab X_b + t_ab
    rays_b = points_b / np.linalg.norm(points_b, axis=1, keepdims=True)
    if noise_rad:
        rays_a = rays_a + rng.normal(0.0, noise_rad, rays_a.shape)
        rays_a /= np.linalg.norm(rays_a, axis=1, keepdims=True)
    return rays_a, rays_b, rotation, translation


def test_homography_shows_the_coherent_parallax_of_a_step_over_a_plane():
    # A floor 1.3 m below a camera with ray noise 2e-3 rad: a 1 cm step moves the rays by at most
    # 7.7e-3 rad, mostly below the noise of one correspondence, so the 5-point model's own score
    # beats the rotation model's on 9 of these 20 seeds only (measured). The parallax is the same
    # flow over all 300 rays, which the homography explains for five parameters more: it beats the
    # rotation model on every seed, and the 5-point model is chosen. The rotation model's
    # rotation, which absorbs the flow, is off by 4.1-5.6 mrad; the 5-point model's by a median of
    # 0.7 mrad (measured).
    options = RelativePoseOptions(ransac_threshold_rad=6e-3)
    chosen, rotation_only = [], []
    for seed in range(20):
        rays_a, rays_b, rotation, _ = _floor_view(seed, step_m=0.01, height_m=1.3, n=300, noise_rad=2e-3)
        pose, info = relative_pose_from_rays(rays_a, rays_b, options=options)
        assert info.model == "5pt" and info.selection.gric_homography < info.selection.gric_rotation
        chosen.append(geodesic_angle(rotation, pose.rotation))
        forced = relative_pose_from_rays(rays_a, rays_b, options=replace(options, rotation_only=True))[0]
        rotation_only.append(geodesic_angle(rotation, forced.rotation))
    assert np.median(chosen) < 0.5 * np.median(rotation_only)


def test_homography_does_not_take_a_pure_rotation_over_a_plane():
    # Without a step the homography is the rotation with five idle parameters: it never wins.
    options = RelativePoseOptions(ransac_threshold_rad=6e-3)
    for seed in range(20):
        rays_a, rays_b, _, _ = _floor_view(seed, step_m=0.0, height_m=1.3, n=300, noise_rad=2e-3)
        info = relative_pose_from_rays(rays_a, rays_b, options=options)[1]
        assert info.model == "rotation" and info.selection.gric_homography > info.selection.gric_rotation


def _plane_twin(rotation, translation, normal_a, distance_a):
    """The other motion of a plane's two-fold ambiguity (the plane ``n_a . X_a = d_a`` in camera a):
    the decomposition of the homography ``R + t n_b^T / d_b`` of the plane in camera b whose
    rotation is farthest from ``rotation``."""
    import cv2

    normal_b, distance_b = rotation.T @ normal_a, distance_a - normal_a @ translation
    homography = rotation + np.outer(translation, normal_b) / distance_b
    _, rotations, translations, _ = cv2.decomposeHomographyMat(homography, np.eye(3))
    k = max(range(len(rotations)), key=lambda i: geodesic_angle(rotations[i], rotation))
    return rotations[k], translations[k][:, 0]


def test_floor_twin_fits_the_epipolar_constraints_but_puts_points_behind_the_cameras():
    # The ambiguity itself: both motions explain every epipolar constraint of the floor exactly.
    # Over the whole floor around the nadir the twin, which moves the camera towards the floor,
    # must put a part of it behind the cameras (in camera a, a ray on the far side of its rotated
    # partner from the epipole) whichever way its translation points.
    rays_a, rays_b, rotation, translation = _floor_view(0)
    twin_rotation, twin_translation = _plane_twin(rotation, translation, np.array([0.0, 0.0, -1.0]), 0.4)
    assert geodesic_angle(twin_rotation, rotation) > 0.02  # the twin's rotation, tens of mrad off
    assert epipolar_angles(rays_a, rays_b, twin_rotation[None], twin_translation[None]).max() < 1e-9
    turned = rays_b @ twin_rotation.T
    for sign in (1.0, -1.0):
        t = sign * twin_translation
        toward = rays_a @ t - np.sum(rays_a * turned, axis=1) * (turned @ t)
        assert np.mean(toward < 0) > 0.2
    # The true motion puts none behind.
    turned = rays_b @ rotation.T
    assert np.all(rays_a @ translation - np.sum(rays_a * turned, axis=1) * (turned @ translation) > 0)


@pytest.mark.parametrize("noise_rad", [5e-4, 1e-3])
def test_floor_seen_all_around_gives_the_true_rotation_not_its_twin(noise_rad):
    # A 2 cm step 0.4 m above the floor: the twin's rotation is about 50 mrad off. The 5-point
    # model counts the twin's points behind the cameras against it, so the true motion wins on
    # every seed, with the model selection (a parallax of up to 50 mrad against 1 mrad of noise
    # or less: the 5-point model) and forced. Measured with the plain epipolar angle as the
    # residual: the twin on 3 of these 20 seeds at either noise.
    options = RelativePoseOptions(ransac_threshold_rad=3e-3)
    for seed in range(20):
        rays_a, rays_b, rotation, _ = _floor_view(seed, noise_rad=noise_rad)
        for forced in (False, True):
            pose, info = relative_pose_from_rays(rays_a, rays_b, options=replace(options, five_point_only=forced))
            assert info.success and info.model == "5pt"
            assert geodesic_angle(pose.rotation, rotation) < 3 * noise_rad


@pytest.mark.parametrize("translation_m, model", [(0.0, "rotation"), (0.1, "5pt")])
def test_model_choice_holds_when_the_noise_fills_the_threshold(translation_m, model):
    # Ray noise as large as the inlier threshold (6e-3 rad per axis): the inliers' epipolar angles
    # spread evenly up to it and show no peak of noise. A 10 cm step at 5 m (a parallax of up to
    # 20 mrad, three thresholds) is still the 5-point model on every seed, and a pure rotation the
    # rotation model. Measured with the noise taken as ten thresholds when it cannot be measured:
    # 3 of 10 translated pairs taken for rotations, 13 mrad RMS off.
    options = RelativePoseOptions(ransac_threshold_rad=6e-3)
    for seed in range(10):
        rays_a, rays_b, rotation = _two_view(seed, translation_m=translation_m, noise_rad=6e-3)
        pose, info = relative_pose_from_rays(rays_a, rays_b, options=options)
        assert info.success and info.model == model
        assert info.selection.noise_sigma_rad <= 6e-3
        assert geodesic_angle(pose.rotation, rotation) < 0.02


def _far_and_near(seed: int, *, far: int = 7, near: int = 3, noise_rad: float = 1e-4):
    """Rays of ``far`` points 1 km away and ``near`` points 0.5 m away (random directions), seen
    from two cameras 5 cm apart along x, camera a turned by a known rotation, seeded ray noise
    ``noise_rad`` per axis on camera a. Only the near points show parallax (up to 0.1 rad)."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(far + near, 3))
    rays_b = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    depths = np.r_[np.full(far, 1000.0), np.full(near, 0.5)]
    rotation = Rotation.from_rotvec([0.03, -0.02, 0.25]).as_matrix()
    points_a = (rays_b * depths[:, None]) @ rotation.T + np.array([0.05, 0.0, 0.0])
    rays_a = points_a / np.linalg.norm(points_a, axis=1, keepdims=True) + rng.normal(0.0, noise_rad, points_a.shape)
    return rays_a / np.linalg.norm(rays_a, axis=1, keepdims=True), rays_b, rotation


def test_preferred_model_without_enough_inliers_gives_way_to_the_other():
    # Seven far points and three near ones: GRIC prefers the rotation model (its seven inliers
    # explain most of the pair at a lower cost), but seven inliers are fewer than min_inliers (8),
    # while the 5-point model keeps all ten. The pair is solved with the 5-point model, as the forced
    # 5-point run solves it, instead of failing. Measured before: every seed failed.
    options = RelativePoseOptions(ransac_threshold_rad=2e-3)
    for seed in range(10):
        rays_a, rays_b, rotation = _far_and_near(seed)
        pose, info = relative_pose_from_rays(rays_a, rays_b, options=options)
        assert info.selection.gric_rotation < info.selection.gric_5pt
        assert info.success and info.model == "5pt" and info.n_inliers >= options.min_inliers
        forced_pose, _ = relative_pose_from_rays(rays_a, rays_b, options=replace(options, five_point_only=True))
        np.testing.assert_array_equal(pose.rotation, forced_pose.rotation)
        assert geodesic_angle(pose.rotation, rotation) < 1e-3


def test_preferred_model_keeps_the_pair_when_its_own_consensus_holds():
    # The other side: with twelve far points the rotation model keeps twelve inliers, enough, and
    # stays the choice GRIC made; with the rotation model forced, it is never exchanged either.
    options = RelativePoseOptions(ransac_threshold_rad=2e-3)
    for seed in range(10):
        rays_a, rays_b, _ = _far_and_near(seed, far=12)
        _, info = relative_pose_from_rays(rays_a, rays_b, options=options)
        assert info.selection.gric_rotation < info.selection.gric_5pt
        assert info.success and info.model == "rotation"
        rays_a, rays_b, _ = _far_and_near(seed)
        _, forced = relative_pose_from_rays(rays_a, rays_b, options=replace(options, rotation_only=True))
        assert not forced.success and forced.model == "rotation" and forced.reason.startswith("too few inliers")


def _ground_band_tiles(seed: int, *, step_m: float, tiles: int = 18, size: int = 5, noise_rad: float = 1e-3,
                       loose: int = 0, loose_factor: float = 1.0):
    """Tile-like ray groups of a catadioptric mirror band: ``tiles`` groups of ``size`` rays 0.2 to
    0.9 rad below the horizon, all around, seeing a ground plane 1.6 m below; camera a is moved
    ``step_m`` along x and turned by a known rotation. Each group's rays in camera a share one seeded
    error of ``noise_rad`` per axis (a tile's registration error), the first ``loose`` groups one
    ``loose_factor`` times larger (loosely registered tiles); camera b's rays are exact."""
    rng = np.random.default_rng(seed)
    azimuth = rng.uniform(-np.pi, np.pi, (tiles, 1)) + rng.normal(scale=0.02, size=(tiles, size))
    elevation = rng.uniform(-0.9, -0.2, (tiles, 1)) + rng.normal(scale=0.02, size=(tiles, size))
    rays_b = np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                       np.sin(elevation)], axis=-1)
    points_b = rays_b * (1.6 / -rays_b[..., 2:])
    rotation = Rotation.from_rotvec([0.01, -0.02, 0.2]).as_matrix()
    points_a = points_b @ rotation.T + np.array([step_m, 0.0, 0.0])
    scale = np.full((tiles, 1, 1), noise_rad)
    scale[:loose] *= loose_factor
    rays_a = points_a / np.linalg.norm(points_a, axis=-1, keepdims=True) + rng.normal(size=(tiles, 1, 3)) * scale
    rays_a /= np.linalg.norm(rays_a, axis=-1, keepdims=True)
    return rays_a.reshape(-1, 3), rays_b.reshape(-1, 3), rotation


def test_ground_band_tiles_choose_the_model_on_both_sides_of_the_boundary():
    # 18 tiles of five rays, 1 mrad of error per tile against an 8 mrad threshold (iFMI's regime).
    # Without translation: the rotation model on every seed. A 2 cm step at 1.6 m moves the rays by
    # 5 mrad (median; 2 to 9 mrad), of which a rotation cannot absorb the part that varies around the
    # band: the 5-point model on every seed. Measured: 0 and 20 of 20 seeds 5-point.
    options = RelativePoseOptions(ransac_threshold_rad=8e-3)
    for step_m, model in ((0.0, "rotation"), (0.02, "5pt")):
        for seed in range(20):
            rays_a, rays_b, rotation = _ground_band_tiles(seed, step_m=step_m)
            pose, info = relative_pose_from_rays(rays_a, rays_b, options=options, rays_per_measurement=5)
            assert info.success and info.model == model
            assert geodesic_angle(pose.rotation, rotation) < 5e-3


def test_loosely_registered_tiles_without_translation_keep_the_rotation_model():
    # Pure rotation, tiles registered to 0.3 mrad but four of the 18 six times worse (1.8 mrad), as
    # iFMI's tiles are on the 0 cm sets. The 5-point model's free translation direction and depths
    # absorb much of those four errors; GRIC counts a residual beyond two noise levels per dimension
    # as an outlier of fixed cost, so they do not buy it the pair. Measured: rotation on all 30
    # seeds; with the residuals capped at the inlier thresholds instead (their squares in units of
    # the noise estimate, 38 and more), 18 of 30 were taken for 5-point motion.
    options = RelativePoseOptions(ransac_threshold_rad=8e-3)
    for seed in range(30):
        rays_a, rays_b, _ = _ground_band_tiles(seed, step_m=0.0, noise_rad=3e-4, loose=4, loose_factor=6.0)
        _, info = relative_pose_from_rays(rays_a, rays_b, options=options, rays_per_measurement=5)
        assert info.success and info.model == "rotation"


def test_parallax_a_rotation_absorbs_is_left_to_the_rotation_model():
    # Where the boundary lies: a 1 cm step moves the rays of the band by 2.6 mrad (median), but a rotation
    # about a horizontal axis absorbs most of it; what it leaves is near the tile noise (1 mrad), and
    # GRIC keeps the rotation model on most seeds, although that rotation carries the absorbed
    # parallax as a bias (2.7 mrad RMS against the 5-point model's 1.4; over a sequence the bias adds
    # up, the noise does not). Weighed with the true noise instead of its estimate, GRIC still keeps
    # the rotation on 7 of 20 seeds. Measured: rotation on 13 of 20 seeds.
    options = RelativePoseOptions(ransac_threshold_rad=8e-3)
    chosen, errors = [], {"rotation": [], "5pt": []}
    for seed in range(20):
        rays_a, rays_b, rotation = _ground_band_tiles(seed, step_m=0.01)
        chosen.append(relative_pose_from_rays(rays_a, rays_b, options=options, rays_per_measurement=5)[1].model)
        for model, forced in (("rotation", replace(options, rotation_only=True)),
                              ("5pt", replace(options, five_point_only=True))):
            pose, _ = relative_pose_from_rays(rays_a, rays_b, options=forced, rays_per_measurement=5)
            errors[model].append(geodesic_angle(pose.rotation, rotation))
    rms = {model: np.sqrt(np.mean(np.square(values))) for model, values in errors.items()}
    assert chosen.count("rotation") >= 8
    assert rms["rotation"] > 1.5 * rms["5pt"]


def test_batched_5_point_samples_are_those_of_one_choice_call_each():
    # The batched sampler consumes the generator as Generator.choice does, call after call (from
    # any state of its 32-bit buffer), so RANSAC draws the same samples as with choice.
    from ifmi.backend.relative_pose import samples_without_replacement

    for seed in range(50):
        for n in (6, 9, 105, 10000, 10001, 30000):
            one, batched = np.random.default_rng(seed), np.random.default_rng(seed)
            one.integers(0, 9, size=seed % 3)
            batched.integers(0, 9, size=seed % 3)
            expected = np.array([one.choice(n, 5, replace=False) for _ in range(7)])
            samples = samples_without_replacement(batched, n, 5, 7)
            assert np.array_equal(samples, expected)
            assert one.integers(0, 1000) == batched.integers(0, 1000)
            assert all(len(set(row)) == 5 for row in samples.tolist()) and 0 <= samples.min() <= samples.max() < n
