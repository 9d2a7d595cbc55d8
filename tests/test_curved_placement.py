"""Tiles cut along the predicted map's curvature, its composition along a track, and the refit pass."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.spectral.fourier_mellin import FourierMellin
from ifmi.spectral.flow import flow_from_placements
import ifmi.spectral.ifmi_front_end
from ifmi.spectral.ifmi_front_end import CoarseOptions, IfmiConfig, IfmiFrontEnd, RefinementOptions
from ifmi.spectral.tiling import TilingConfig
from ifmi.spectral.panorama import PanoramaConfig, panorama_pixels_from_rays, rays_from_panorama_pixels

from tile_checks import kept_tiles_rotation_error

pytest.importorskip("skimage")
from ifmi.synthetic import environment_texture, omni_from_environment  # noqa: E402

MODEL = paracatadioptric_model((256, 256), horizon_radius_px=80.0, center=(130.3, 126.1),
                               affine=(1.002, 0.003, -0.002))
BAND = (30.0, 125.0)
# Curved placements without refit passes on this small panorama.
CURVED = IfmiConfig(panorama=PanoramaConfig(width=512), refinement=RefinementOptions(min_width_sharp=0, refit_passes=0),
                    coarse=CoarseOptions(enabled=False))
AFFINE = IfmiConfig(panorama=PanoramaConfig(width=512), refinement=RefinementOptions(curved_placement=False),
                    coarse=CoarseOptions(enabled=False))
# Rotations with a large tilt (the curvature of the panorama warp grows with it).
TILTS = [Rotation.from_rotvec(v).as_matrix() for v in ([0.08, -0.06, 0.03], [-0.07, 0.05, -0.1], [0.05, 0.09, 0.2])]


@pytest.fixture(scope="module")
def environment():
    return environment_texture(height=512, seed=3)


def _front_end(config, frame):
    fe = IfmiFrontEnd(MODEL, config)
    fe.prepare(frame)
    return fe


def _wrapped(d, width):
    d = np.array(d)
    d[..., 1] = np.mod(d[..., 1] + width / 2, width) - width / 2
    return d


def test_second_order_term_follows_the_exact_warp_and_composes(environment):
    fe = _front_end(CURVED, omni_from_environment(environment, MODEL, np.eye(3), band_px=BAND))
    offsets, linear = fe._layout_placement
    rotation = TILTS[0]
    offsets_b, linear_b = fe.predicted_placements(offsets, linear, rotation)
    curvature = fe.predicted_curvature(offsets, linear, None, rotation)
    half = (fe.layout.tile_size - 1) / 2.0
    grid = np.array([[i, j] for i in (-1, 0, 1) for j in (-1, 0, 1)]) * half
    in_a = offsets[:, None] + grid
    exact = panorama_pixels_from_rays(fe.mapping, rays_from_panorama_pixels(fe.mapping, in_a) @ rotation)
    affine = offsets_b[:, None] + np.einsum("tij,kj->tki", linear_b, grid)
    quadratic = affine + np.einsum("ki,toij,kj->tko", grid, curvature, grid)
    width = fe.mapping.width
    affine_error = np.abs(_wrapped(exact - affine, width)).max()
    quadratic_error = np.abs(_wrapped(exact - quadratic, width)).max()
    # Measured: 0.35 px left by the affine map at the tile corners, 0.02 px by the quadratic one.
    assert affine_error > 0.2
    assert quadratic_error < 0.1 * affine_error
    # Two steps composed along a track give the one-step term of the whole rotation.
    first = Rotation.from_rotvec([0.03, -0.02, 0.01]).as_matrix()
    second = first.T @ rotation
    o1, l1 = fe.predicted_placements(offsets, linear, first)
    q1 = fe.predicted_curvature(offsets, linear, None, first)
    q2 = fe.predicted_curvature(o1, l1, q1, second)
    # (Measured: 0.1 % apart; the central differences also see third-order terms.)
    assert np.abs(q2 - curvature).max() < 1e-2 * np.abs(curvature).max()


def test_resampling_along_the_curvature_reads_the_quadratic_place():
    # On a linear ramp, bilinear interpolation is exact: each tile pixel reads its own source row.
    n = 16
    engine = FourierMellin(n, 1)
    rows = np.arange(200, dtype=np.float32)[:, None] * np.ones((1, 200), dtype=np.float32)
    offsets = np.array([[100.25, 90.5]])
    linear = np.eye(2)[None]
    curvature = np.zeros((1, 2, 2, 2))
    curvature[0, 0] = [[0.01, 0.002], [0.002, -0.004]]
    tiles = engine.resample_placed(rows, offsets, linear, interpolation="linear", curvature=curvature)[0]
    u = np.arange(n) - (n - 1) / 2.0
    ur, uc = np.meshgrid(u, u, indexing="ij")
    expected = offsets[0, 0] + ur + 0.01 * ur ** 2 + 2 * 0.002 * ur * uc - 0.004 * uc ** 2
    assert np.abs(tiles - expected).max() < 0.02  # OpenCV's 1/32 pixel sub-sample grid


def test_flow_points_include_the_curvature(environment):
    fe = _front_end(CURVED, omni_from_environment(environment, MODEL, np.eye(3), band_px=BAND))
    offsets, linear = fe._layout_placement
    curvature = np.zeros((len(offsets), 2, 2, 2))
    curvature[:, 1, 1, 1] = 0.01
    points = np.array([[7.5, 7.5], [7.5, 12.5]])  # the centre of a 16 px tile and 5 px right of it
    valid = np.zeros(len(offsets), bool)
    valid[3] = True
    flat = flow_from_placements(offsets, linear, offsets, linear, valid, fe.mapping, points=points, tile_size=16)
    curved = flow_from_placements(offsets, linear, offsets, linear, valid, fe.mapping, points=points,
                                  tile_size=16, curvature_b=curvature)
    shift = _wrapped(panorama_pixels_from_rays(fe.mapping, curved.rays_b)
                     - panorama_pixels_from_rays(fe.mapping, flat.rays_b), fe.mapping.width)
    assert np.allclose(shift, [[0.0, 0.0], [0.0, 0.25]], atol=1e-6)


def _rotation_error(config, frames, rotation):
    return kept_tiles_rotation_error(MODEL, config, frames, rotation)


def test_curved_tiles_remove_the_bias_of_an_affine_cut(environment):
    # The exact rotation as the prediction: what is left is the registration's own error. Tiles of
    # an eighth of the panorama's width make the bias of an affine cut (it grows with the square of
    # the tile's share of the circle) stand out from the interpolation errors of these small frames.
    tiling = TilingConfig(tile_size=64)
    curved, affine = replace(CURVED, tiling=tiling), replace(AFFINE, tiling=tiling)
    errors = {"curved": 0.0, "affine": 0.0}
    for rotation in TILTS:
        frames = [omni_from_environment(environment, MODEL, r, band_px=BAND) for r in (np.eye(3), rotation)]
        errors["curved"] += _rotation_error(curved, frames, rotation)
        errors["affine"] += _rotation_error(affine, frames, rotation)
    # Measured: 3.5e-4 against 1.9e-3 rad summed over the three rotations.
    assert errors["curved"] < 0.35 * errors["affine"]


def test_curvature_applies_at_any_width_unless_turned_off(environment):
    frames = [omni_from_environment(environment, MODEL, r, band_px=BAND) for r in (np.eye(3), TILTS[0])]
    # Below min_width_sharp (1536 px by default): that width gates the kernel and landmark rays only.
    for config, expected in ((IfmiConfig(panorama=PanoramaConfig(width=512)), True), (AFFINE, False)):
        fe = IfmiFrontEnd(MODEL, config)
        a, b = fe.prepare(frames[0]), fe.prepare(frames[1])
        fe.keep_tracking(b, fe.tiles_at(a, b, TILTS[0]))
        assert (b.tracked.curvature is not None) == expected


def test_refit_pass_corrects_a_wrong_prediction(environment):
    frames = [omni_from_environment(environment, MODEL, r, band_px=BAND) for r in (np.eye(3), TILTS[0])]
    wrong = TILTS[0] @ Rotation.from_rotvec([0.02, -0.015, 0.0]).as_matrix()  # a tilt 1.3 px off
    refit = IfmiConfig(panorama=PanoramaConfig(width=512), refinement=RefinementOptions(min_width_sharp=0),
                       coarse=CoarseOptions(enabled=False))
    fe = IfmiFrontEnd(MODEL, refit)
    a, b = fe.prepare(frames[0]), fe.prepare(frames[1])
    fe.keep_tracking(b, fe.tiles_at(a, b, wrong))
    single = IfmiFrontEnd(MODEL, CURVED)
    a1, b1 = single.prepare(frames[0]), single.prepare(frames[1])
    single.keep_tracking(b1, single.tiles_at(a1, b1, wrong))
    exact = single.predicted_curvature(*single._layout_placement, None, TILTS[0])
    # The refit takes the tiles' shape from their own rotation, not from the wrong prediction.
    assert np.abs(b.tracked.curvature - exact).max() < 0.5 * np.abs(b1.tracked.curvature - exact).max()


@pytest.mark.parametrize("field, value", [("refit_passes", -1), ("min_width_sharp", -5),
                                          # 10**20 passes were accepted and the estimate never ended
                                          ("refit_passes", 10 ** 20)])
def test_invalid_refit_options_are_rejected(field, value):
    with pytest.raises(ValueError, match="refit_passes"):
        RefinementOptions(**{field: value})


def _resample_count(fe, monkeypatch):
    calls = []
    original = fe.engine.resample_placed
    monkeypatch.setattr(fe.engine, "resample_placed", lambda *a, **k: calls.append(1) or original(*a, **k))
    return calls


def test_a_close_prediction_is_refined_once_on_the_refitted_shape(environment, monkeypatch):
    frames = [omni_from_environment(environment, MODEL, r, band_px=BAND) for r in (np.eye(3), TILTS[0])]
    wrong = TILTS[0] @ Rotation.from_rotvec([0.02, -0.015, 0.0]).as_matrix()  # tiles 1.3 px off
    refit = IfmiConfig(panorama=PanoramaConfig(width=512), refinement=RefinementOptions(min_width_sharp=0),
                       coarse=CoarseOptions(enabled=False))
    placements = {}
    for name, single_max_px in (("gated", 0.5), ("twice", 0.0)):  # 0: the passes always run twice
        monkeypatch.setattr(ifmi.spectral.ifmi_front_end, "_SINGLE_REFINEMENT_MAX_PX", single_max_px)
        for prior, label in ((TILTS[0], "close"), (wrong, "far")):
            fe = IfmiFrontEnd(MODEL, refit)
            a, b = fe.prepare(frames[0]), fe.prepare(frames[1])
            calls = _resample_count(fe, monkeypatch)
            placements[name, label] = fe.tiles_at(a, b, prior).placed.offsets
            # The search pass, then one refinement pass per shape the tiles were cut with.
            assert len(calls) == (2 if (name, label) == ("gated", "close") else 3), (name, label)
    # Far off, both refine twice; they differ only in the search pass's sub-pixel fit (phase plane
    # against parabolic peak), which the passes take out to about a hundredth of a pixel
    # (measured: median 5e-4 px, largest 0.013 px).
    assert np.abs(placements["gated", "far"] - placements["twice", "far"]).max() < 0.02
    # One pass from a close prediction is about as good as two: summed over the three tilts
    # (measured: 6.86e-4 against 6.70e-4 rad; single pairs differ either way, 0.99x to 1.56x).
    gated = twice_sum = 0.0
    for rotation in TILTS:
        frames = [omni_from_environment(environment, MODEL, r, band_px=BAND) for r in (np.eye(3), rotation)]
        monkeypatch.setattr(ifmi.spectral.ifmi_front_end, "_SINGLE_REFINEMENT_MAX_PX", 0.5)
        gated += _rotation_error(refit, frames, rotation)
        monkeypatch.setattr(ifmi.spectral.ifmi_front_end, "_SINGLE_REFINEMENT_MAX_PX", 0.0)
        twice_sum += _rotation_error(refit, frames, rotation)
    assert gated < 1.25 * twice_sum


