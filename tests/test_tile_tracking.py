"""Affine tile placements, their prediction under a rotation, and tile tracking between pairs."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.spectral.fourier_mellin import compose_placement, motion_from_placement, placement_from_motion
from ifmi.spectral import pair_pipeline as pair_pipeline
from ifmi.spectral.ifmi_front_end import IfmiConfig, IfmiFrontEnd, RecoveryOptions, RefinementOptions, TrackingOptions
from ifmi.spectral.panorama import PanoramaConfig, panorama_pixels_from_rays, rays_from_panorama_pixels

pytest.importorskip("skimage")
from ifmi.synthetic import environment_texture, omni_from_environment  # noqa: E402

MODEL = paracatadioptric_model((256, 256), horizon_radius_px=80.0, center=(130.3, 126.1),
                               affine=(1.002, 0.003, -0.002))
BAND = (30.0, 125.0)
# The tracking mechanisms on affine cuts, each measured alone (curved cuts and their refit pass,
# on by default, are tested in test_curved_placement.py).
CONFIG = IfmiConfig(panorama=PanoramaConfig(width=512), refinement=RefinementOptions(curved_placement=False))
# A frame-to-frame step of about 3.5 degrees (4-5 panorama pixels), mostly about the mirror axis.
STEP = Rotation.from_rotvec([0.01, -0.01, 0.06]).as_matrix()


@pytest.fixture(scope="module")
def clean_frames():
    environment = environment_texture(height=512, seed=3)
    return [omni_from_environment(environment, MODEL, r, band_px=BAND) for r in (np.eye(3), STEP, STEP @ STEP)]


def test_placement_round_trip_and_composition():
    rng = np.random.default_rng(0)
    t, n = 7, 32
    origins = rng.uniform(0, 100, (t, 2))
    scale, angle = np.exp(rng.uniform(-0.2, 0.2, t)), rng.uniform(-np.pi, np.pi, t)
    translation = rng.uniform(-5, 5, (t, 2))
    offsets, linear = placement_from_motion(origins, scale, angle, translation, n)
    s2, a2, t2 = motion_from_placement(origins, offsets, linear, n)
    assert np.allclose(s2, scale) and np.allclose(a2, angle) and np.allclose(t2, translation)
    # Two residual steps compose like one: scales multiply, angles add, t of the last step.
    d_scale, d_angle, d_t = np.exp(rng.uniform(-0.1, 0.1, t)), rng.uniform(-0.3, 0.3, t), rng.uniform(-1, 1, (t, 2))
    o3, l3 = compose_placement(offsets, linear, d_scale, d_angle, d_t)
    expected_t = d_scale[:, None] * np.stack([np.cos(d_angle) * translation[:, 0] - np.sin(d_angle) * translation[:, 1],
                                              np.sin(d_angle) * translation[:, 0] + np.cos(d_angle) * translation[:, 1]],
                                             axis=1) + d_t
    o4, l4 = placement_from_motion(origins, scale * d_scale, angle + d_angle, expected_t, n)
    assert np.allclose(o3, o4) and np.allclose(l3, l4)


def test_affine_prediction_follows_the_exact_panorama_warp(clean_frames):
    fe = IfmiFrontEnd(MODEL, CONFIG)
    fe.prepare(clean_frames[0])
    offsets, linear = fe._layout_placement
    rotation = Rotation.from_rotvec([0.04, -0.03, 0.05]).as_matrix()
    offsets_b, linear_b = fe.predicted_placements(offsets, linear, rotation)
    half = (fe.layout.tile_size - 1) / 2.0
    corners = np.array([[-1, -1], [-1, 1], [1, -1], [1, 1]]) * half
    in_a = offsets[:, None] + np.einsum("tij,kj->tki", linear, corners)
    exact = panorama_pixels_from_rays(fe.mapping, rays_from_panorama_pixels(fe.mapping, in_a) @ rotation)
    width = fe.mapping.width

    def error(lin):
        d = exact - (offsets_b[:, None] + np.einsum("tij,kj->tki", lin, corners))
        d[..., 1] = np.mod(d[..., 1] + width / 2, width) - width / 2
        return np.abs(d).max()

    # The similarity part of the same Jacobian, which cannot follow the warp's shear.
    a = (linear_b[:, 0, 0] + linear_b[:, 1, 1]) / 2
    b = (linear_b[:, 0, 1] - linear_b[:, 1, 0]) / 2
    similarity = np.stack([np.stack([a, b], -1), np.stack([-b, a], -1)], -2)
    # Measured: 0.19 px against 0.34 px at the tile corners (second-order terms remain).
    assert error(linear_b) < 0.25
    assert error(linear_b) < 0.7 * error(similarity)


def test_recut_tracked_tiles_are_the_pixels_the_residual_was_measured_on(clean_frames):
    fe = IfmiFrontEnd(MODEL, replace(CONFIG, tracking=replace(CONFIG.tracking, anchor_templates=False)))
    s0, s1 = fe.prepare(clean_frames[0]), fe.prepare(clean_frames[1])
    fe.keep_tracking(s1, fe.tiles_at(s0, s1, STEP))
    tracked = s1.tracked
    pad = np.array([0.0, fe._pad])
    again = fe.engine.resample_placed(s1.padded_panorama, tracked.offsets + pad, tracked.linear,
                                      curvature=tracked.curvature)
    assert np.allclose(again, tracked.tiles, atol=1e-3)
    offsets, _, spectra, n_new = fe.reference_tiles(s1)
    assert n_new < fe.layout.count // 2
    kept = ~np.isclose(offsets, fe._layout_placement[0]).all(axis=1)
    assert kept.sum() == fe.layout.count - n_new
    assert np.allclose(spectra.spectrum[kept], tracked.spectra.spectrum[kept])


def test_anchored_tiles_keep_the_first_frames_template_at_the_found_placement(clean_frames):
    fe = IfmiFrontEnd(MODEL, CONFIG)
    assert CONFIG.tracking.anchor_templates
    s0, s1 = fe.prepare(clean_frames[0]), fe.prepare(clean_frames[1])
    match = fe.tiles_at(s0, s1, STEP)
    fe.keep_tracking(s1, match)
    _, _, placed, _ = match.offsets_a, match.linear_a, match.placed, match.n_new
    offsets, linear, spectra, n_new = fe.reference_tiles(s1)
    assert n_new == (~placed.valid).sum() and n_new < fe.layout.count // 2
    kept = placed.valid
    assert np.allclose(offsets[kept], placed.offsets[kept]) and np.allclose(linear[kept], placed.linear[kept])
    assert np.array_equal(spectra.spectrum[kept], s0.spectra.spectrum[kept])
    assert np.allclose(offsets[~kept], fe._layout_placement[0][~kept])


def test_anchored_templates_keep_a_middle_frames_errors_out_of_later_frames(clean_frames):
    # A template re-cut from frame 1 carries its placement error (and resampling blur) into
    # frame 2; a template kept from frame 0 is found in frame 2 from frame 2's pixels only, so
    # its placement there does not depend on frame 1, noisy or not.
    def placement_error_in_frame_2(anchor, middle):
        fe = IfmiFrontEnd(MODEL, replace(CONFIG, tracking=replace(CONFIG.tracking, anchor_templates=anchor)))
        states = [fe.prepare(image) for image in (clean_frames[0], middle, clean_frames[2])]
        truth_2 = fe.predicted_placements(*fe.predicted_placements(*fe._layout_placement, STEP), STEP)[0]
        match = fe.tiles_at(states[0], states[1], STEP)
        fe.keep_tracking(states[1], match)
        _, _, placed_1, _ = match.offsets_a, match.linear_a, match.placed, match.n_new
        match = fe.tiles_at(states[1], states[2], STEP)
        fe.keep_tracking(states[2], match)
        _, _, placed_2, _ = match.offsets_a, match.linear_a, match.placed, match.n_new
        d = placed_2.offsets - truth_2
        d[:, 1] = np.mod(d[:, 1] + fe.mapping.width / 2, fe.mapping.width) - fe.mapping.width / 2
        return d[placed_1.valid & placed_2.valid]

    rng = np.random.default_rng(0)
    noisy = np.clip(np.round(clean_frames[1] + rng.normal(0.0, 20.0, clean_frames[1].shape)), 0, 255)
    rms = {(anchor, kind): np.sqrt(np.mean(placement_error_in_frame_2(anchor, middle) ** 2))
           for anchor in (True, False)
           for kind, middle in (("clean", clean_frames[1]), ("noisy", noisy.astype(np.uint8)))}
    # Measured (px): anchored 0.049 clean / 0.042 noisy; re-cut 0.165 / 0.136.
    assert rms[True, "noisy"] < 1.5 * rms[True, "clean"]
    for kind in ("clean", "noisy"):
        assert rms[False, kind] > 2.0 * rms[True, kind]


@pytest.mark.parametrize("track", [True, False])
def test_tracking_makes_a_frames_noise_cancel_between_its_two_pairs(clean_frames, track):
    # Only the middle frame is noisy, so every tile's placement error in pair (0, 1) and in
    # pair (1, 2) comes from that frame's noise. With tracked tiles the same pixels enter both
    # pairs and their errors are nearly opposite; with new layout tiles in frame 1 the pixels
    # differ by the motion and the errors are much less related.
    fe = IfmiFrontEnd(MODEL, replace(CONFIG, tracking=replace(CONFIG.tracking, track_tiles=track)))
    correlations = []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        noisy = np.clip(np.round(clean_frames[1] + rng.normal(0.0, 20.0, clean_frames[1].shape)), 0, 255)
        states = [fe.prepare(image) for image in (clean_frames[0], noisy.astype(np.uint8), clean_frames[2])]
        errors, valid = [], []
        for a, b in ((0, 1), (1, 2)):
            match = fe.tiles_at(states[a], states[b], STEP)
            fe.keep_tracking(states[b], match)
            offsets_a, linear_a, placed, _ = match.offsets_a, match.linear_a, match.placed, match.n_new
            truth, _ = fe.predicted_placements(offsets_a, linear_a, STEP)
            d = placed.offsets - truth
            d[:, 1] = np.mod(d[:, 1] + fe.mapping.width / 2, fe.mapping.width) - fe.mapping.width / 2
            errors.append(d)
            valid.append(placed.valid)
        both = valid[0] & valid[1]
        correlations.append(np.corrcoef(errors[0][both].ravel(), errors[1][both].ravel())[0, 1])
    # Measured: -0.95, -0.91, -0.91 tracked; -0.60, -0.27, -0.71 with layout tiles.
    if track:
        assert np.mean(correlations) < -0.8
    else:
        assert np.mean(correlations) > -0.7


def test_distortion_limit_is_validated():
    with pytest.raises(ValueError, match="max_tile_distortion"):
        TrackingOptions(max_tile_distortion=1.0)


def test_layout_tiles_of_a_frame_are_cut_across_the_seam(clean_frames):
    from ifmi.spectral.tiling import TilingConfig, tiles_from_panorama
    from ifmi.spectral.panorama import panorama_image_from_omni_image

    # 40 px tiles at half overlap on a 512 px wide panorama: the last column of tiles wraps.
    fe = IfmiFrontEnd(MODEL, replace(CONFIG, tiling=TilingConfig(tile_size=40, overlap=0.5)))
    state = fe.prepare(clean_frames[0])
    assert (fe.layout.origins[:, 1] + fe.layout.tile_size > fe.mapping.width).any()
    # The front end remaps the frame as float (no rounding to whole gray levels).
    panorama = panorama_image_from_omni_image(fe.mapping, clean_frames[0].astype(np.float32))
    expected = tiles_from_panorama(panorama, fe.layout)
    assert np.array_equal(state.layout_tiles(), expected)
    some = np.arange(fe.layout.count) % 3 == 0
    assert np.array_equal(state.layout_tiles(some), expected[some])


def test_dense_retry_registers_a_denser_layout_and_leaves_frame_bs_tracked_tiles(clean_frames):
    from ifmi.backend.relative_pose import rotation_from_rays
    from ifmi.geometry.rotations import geodesic_angle

    # Forced on every pair (fraction 1): the half-overlap layout's tiles, cut anew from frame a,
    # are found where the true rotation puts them and give the rays; frame b keeps the regular
    # layout's tracked tiles for the next pair.
    fe = IfmiFrontEnd(MODEL, replace(CONFIG, recovery=replace(CONFIG.recovery, dense_retry_fraction=1.0)))
    s0, s1 = fe.prepare(clean_frames[0]), fe.prepare(clean_frames[1])
    offsets_a, linear_a, placed = fe.register_dense(s0, s1, rotation=STEP)
    assert fe.dense_layout.count > 3 * fe.layout.count
    truth, _ = fe.predicted_placements(offsets_a, linear_a, STEP)
    d = placed.offsets - truth
    d[:, 1] = np.mod(d[:, 1] + fe.mapping.width / 2, fe.mapping.width) - fe.mapping.width / 2
    # Measured: all 128 tiles kept, placed within 0.31 px of the truth.
    assert placed.valid.mean() > 0.8 and np.abs(d[placed.valid]).max() < 0.5
    corr = fe.correspondences(s0, s1, prior_rotation=STEP)
    kept = corr.diagnostics["n_tiles_kept_dense"]
    assert kept > 3 * corr.diagnostics["n_tiles_kept"] * 0.8
    assert len(corr.rays_a) == kept * corr.rays_per_measurement
    assert len(s1.tracked.offsets) == fe.layout.count
    # Measured: 1.7e-4 rad (the one-pixel angle of the 512 px panorama is 1.2e-2 rad).
    assert geodesic_angle(rotation_from_rays(corr.rays_a, corr.rays_b), STEP) < 1e-3
    # Without the retry the regular tiles give the rays.
    plain = IfmiFrontEnd(MODEL, replace(CONFIG, recovery=replace(CONFIG.recovery, dense_retry_fraction=0.0)))
    corr = plain.correspondences(plain.prepare(clean_frames[0]), plain.prepare(clean_frames[1]), prior_rotation=STEP)
    assert "n_tiles_kept_dense" not in corr.diagnostics
    assert len(corr.rays_a) == corr.diagnostics["n_tiles_kept"] * corr.rays_per_measurement


def test_dense_retry_options_are_validated():
    with pytest.raises(ValueError, match="dense_retry_fraction"):
        RecoveryOptions(dense_retry_fraction=1.5)
    with pytest.raises(ValueError, match="dense_overlap"):
        RecoveryOptions(dense_overlap=1.0)


def test_a_weak_pair_is_registered_again_at_the_solved_rotation_and_both_rays_averaged(clean_frames):
    from ifmi.front_end import Correspondences
    from ifmi.backend.relative_pose import rotation_from_rays
    from ifmi.geometry.rotations import geodesic_angle

    # Forced (fraction 1): the reference's tiles are registered a second time where the given
    # R_ab puts them, here 0.02 rad (1.6 panorama pixels) off the truth; the tiles measure the
    # rest, and each frame-b ray comes back as the mean of its two registrations.
    fe = IfmiFrontEnd(MODEL, replace(CONFIG, refinement=replace(CONFIG.refinement, reregister_fraction=1.0), recovery=replace(CONFIG.recovery, dense_retry_fraction=0.0)))
    s0, s1 = fe.prepare(clean_frames[0]), fe.prepare(clean_frames[1])
    first = fe.correspondences(s0, s1, prior_rotation=STEP)
    solved = STEP @ Rotation.from_rotvec([0.0, 0.0, 0.02]).as_matrix()
    spy = IfmiFrontEnd(MODEL, replace(CONFIG, refinement=replace(CONFIG.refinement, reregister_fraction=1.0), recovery=replace(CONFIG.recovery, dense_retry_fraction=0.0)))
    p0, p1 = spy.prepare(clean_frames[0]), spy.prepare(clean_frames[1])
    spy.correspondences(p0, p1, prior_rotation=STEP)
    match = spy.tiles_at(p0, p1, solved)
    placed = match.placed
    first = _matched(fe, s0, s1)
    refined, kept = pair_pipeline.refined(fe, s0, s1, first, solved)
    refined = refined.correspondences
    first = first.correspondences
    # Frame b would keep the second registration's tiles (placed at the better rotation).
    assert np.array_equal(kept.tracked_valid, placed.valid) and np.allclose(kept.placed.offsets, placed.offsets)
    assert refined.diagnostics["n_tiles_kept_reregistered"] == placed.valid.sum() == fe.layout.count
    assert refined.diagnostics["n_tiles_kept"] == first.diagnostics["n_tiles_kept"] == fe.layout.count
    # Every tile kept twice: the same matches of frame a, frame b's rays between the two registrations.
    assert np.array_equal(refined.rays_a, first.rays_a) and np.array_equal(refined.pixels_a, first.pixels_a)
    moved = np.linalg.norm(refined.rays_b - first.rays_b, axis=1)
    assert moved.max() > 1e-4
    # Measured: 4.2e-4 rad from the first registration, 4.0e-4 averaged with the second
    # (one panorama pixel: 1.2e-2 rad).
    assert geodesic_angle(rotation_from_rays(refined.rays_a, refined.rays_b), STEP) < 1e-3
    # Nor when the solved rotation moves the tiles by under reregister_min_px (0.3 px; 0.02 rad: 1.6 px).
    first = _matched(fe, s0, s1)
    assert pair_pipeline.refined(fe, s0, s1, first, first.rotation) == (None, None)
    nudged = first.rotation @ Rotation.from_rotvec([0.0, 0.0, 0.003]).as_matrix()
    assert pair_pipeline.refined(fe, s0, s1, first, nudged) == (None, None)
    failed = replace(first, correspondences=Correspondences.failed("no tiles"))
    assert pair_pipeline.refined(fe, s0, s1, failed, STEP) == (None, None)


def _matched(fe, state_a, state_b):
    """The pair's stages up to its rays (:func:`ifmi.spectral.pair_pipeline.matched`) at the prediction ``STEP``."""
    return pair_pipeline.matched(fe, state_a, state_b, STEP)


def test_reregister_fraction_is_validated():
    with pytest.raises(ValueError, match="expected 0 <= reregister_fraction <= 1 and reregister_min_px >= 0, "
                                         "got 1.5, 0.3"):
        RefinementOptions(reregister_fraction=1.5)
    with pytest.raises(ValueError, match="got 0.6, -1"):
        RefinementOptions(reregister_min_px=-1)


def test_averaged_correspondences_mean_the_rays_of_frame_b_matched_twice():
    from ifmi.front_end import Correspondences
    from ifmi.spectral.ifmi_front_end import averaged_correspondences

    def rays(angles):
        return np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)

    # Two tiles of 2 flow points each; the second registration lost tile 0 and kept a new tile 2.
    pixels_a = np.array([[0.0, 0.0], [0.0, 1.0], [5.0, 0.0], [5.0, 1.0], [9.0, 0.0], [9.0, 1.0]])
    angles_a = np.arange(6) * 0.3
    first = Correspondences(pixels_a[:4], pixels_a[:4] + 1.0, rays(angles_a[:4]), rays(angles_a[:4] + 0.01),
                            {"n": 1}, rays_per_measurement=2)
    second = Correspondences(pixels_a[2:], pixels_a[2:] + 2.0, rays(angles_a[2:]), rays(angles_a[2:] + 0.03),
                             {"n": 2}, rays_per_measurement=2)
    merged = averaged_correspondences(first, second)
    assert np.array_equal(merged.pixels_a, pixels_a) and merged.diagnostics == {"n": 1}
    assert merged.rays_per_measurement == 2
    expected = angles_a + np.array([0.01, 0.01, 0.02, 0.02, 0.03, 0.03])  # the mean of two unit rays bisects them
    np.testing.assert_allclose(merged.rays_b, rays(expected), atol=1e-12)
    np.testing.assert_allclose(merged.pixels_b, pixels_a + np.array([1, 1, 1.5, 1.5, 2, 2])[:, None])
    np.testing.assert_array_equal(merged.rays_a, rays(angles_a))
