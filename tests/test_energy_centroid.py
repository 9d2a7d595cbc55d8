"""Energy centroids of tiles: the point whose motion a tile registration measures."""

from __future__ import annotations

import cv2
import numpy as np

from ifmi.spectral.flow import flow_from_placements, flow_sample_points, points_on_centroids
from ifmi.spectral.fourier_mellin import FourierMellin, energy_centroids
from ifmi.spectral.phase_correlation import hann_window
from ifmi.geometry.camera import paracatadioptric_model
from ifmi.spectral.panorama import PanoramaConfig, panorama_mapping

N = 64
CENTRE = (N - 1) / 2.0


def test_centroid_of_point_energies_is_their_energy_weighted_mean():
    tiles = np.zeros((3, N, N))
    tiles[0, 10, 50] = 3.0  # one pixel: the centroid is that pixel
    tiles[1, 20, 20], tiles[1, 40, 30] = 1.0, -2.0  # energies 1 and 4
    centroids = energy_centroids(tiles)  # tile 2 has no energy
    assert np.allclose(centroids[0], [10 - CENTRE, 50 - CENTRE], atol=1e-12)
    assert np.allclose(centroids[1], (np.array([20, 20]) + 4 * np.array([40, 30])) / 5 - CENTRE, atol=1e-12)
    assert np.array_equal(centroids[2], [0.0, 0.0])


def test_spectra_carry_the_centroid_of_the_windowed_mean_free_tiles():
    rng = np.random.default_rng(3)
    texture = rng.normal(0.0, 20.0, (4, N, N))
    texture[:, :, : N // 2] *= 0.2  # less texture on the left half
    tiles = (100.0 + texture).astype(np.float32)
    engine = FourierMellin(N, 4)
    by_hand = (tiles - tiles.mean(axis=(1, 2), keepdims=True)) * hann_window((N, N))
    centroids = engine.spectra(tiles).centroid
    assert np.allclose(centroids, energy_centroids(by_hand), atol=1e-4)
    assert (centroids[:, 1] > 5.0).all() and (np.abs(centroids[:, 0]) < 2.0).all()
    assert np.array_equal(engine.spectra(tiles).rows(np.array([2, 0])).centroid, centroids[[2, 0]])


def _sheared_pair(g: float, blob_offset: np.ndarray, seed: int = 0):
    """Source a (textured only in a blob off the tile centre) and b(x) = a(x + f(x)) with the
    column flow f_c = g (row - row of the tile centre): it varies across the tile, as parallax does."""
    size, origin = 160, np.array([48, 48])
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.normal(0.0, 40.0, (size, size)).astype(np.float32), (0, 0), 1.2)
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float64)
    blob = origin + CENTRE + blob_offset
    mask = np.exp(-((rows - blob[0]) ** 2 + (cols - blob[1]) ** 2) / (2 * 6.0 ** 2))
    a = (128.0 + texture * mask).astype(np.float32)
    flow_c = g * (rows - origin[0] - CENTRE)
    b = cv2.remap(a, (cols + flow_c).astype(np.float32), rows.astype(np.float32), cv2.INTER_CUBIC,
                  borderMode=cv2.BORDER_REFLECT)
    return a, b, origin


def test_a_registration_measures_the_motion_at_the_energy_centroid():
    # The column flow grows by 0.04 px per row; the tile's texture sits 14 rows below its centre
    # (its windowed energy about 12), where the flow is about 0.5 px larger than at the centre.
    g = 0.04
    a, b, origin = _sheared_pair(g, np.array([14.0, -6.0]))
    engine = FourierMellin(N, 1)
    spectra_a = engine.spectra(a[origin[0]:origin[0] + N, origin[1]:origin[1] + N][None], with_descriptor=False)
    centre = origin + CENTRE
    placed = engine.register_placed(spectra_a, b, centre[None], np.eye(2)[None])
    centroid = placed.template_centroid[0]
    # The window pulls the centroid from the blob towards the tile centre.
    assert np.array_equal(centroid, spectra_a.centroid[0]) and 8.0 < centroid[0] < 14.0

    def seen_in_b(point_a):  # the b pixel x that shows a's point p: x + f(x) = p
        return point_a - np.array([0.0, g * (point_a[0] - centre[0])])

    # The measured placement puts a's centroid where b shows it, to within the flow's
    # second-order spread over the blob (0.015-0.045 px over four textures and two blob
    # positions); a's centre lands 0.37-0.50 px from where b shows it.
    assert np.abs(placed.offsets[0] + centroid - seen_in_b(centre + centroid)).max() < 0.05
    assert np.abs(placed.offsets[0] - seen_in_b(centre)).max() > 0.4


def test_flow_points_on_centroids_are_the_shared_points_moved_by_the_placement():
    model = paracatadioptric_model((200, 220), horizon_radius_px=60.0, center=(99.0, 111.5))
    mapping = panorama_mapping(model, config=PanoramaConfig(width=256, radius_min_px=25, radius_max_px=95))
    rng = np.random.default_rng(1)
    t = 6
    offsets_a = np.column_stack([rng.uniform(20, 40, t), rng.uniform(0, 256, t)])
    offsets_b = offsets_a + [0.5, 3.0]
    linear_a = np.eye(2) + rng.normal(0, 0.05, (t, 2, 2))
    linear_b = np.eye(2) + rng.normal(0, 0.05, (t, 2, 2))
    valid = np.array([True, True, False, True, True, False])
    centroids = rng.normal(0, 3, (t, 2))
    points = flow_sample_points(32)
    moved = flow_from_placements(offsets_a + np.einsum("tij,tj->ti", linear_a, centroids), linear_a,
                                 offsets_b + np.einsum("tij,tj->ti", linear_b, centroids), linear_b, valid,
                                 mapping, points=points, tile_size=32)
    per_tile = flow_from_placements(offsets_a, linear_a, offsets_b, linear_b, valid, mapping,
                                    points=points_on_centroids(points, centroids), tile_size=32)
    assert np.allclose(per_tile.panorama_a, moved.panorama_a, atol=1e-9)
    assert np.allclose(per_tile.panorama_b, moved.panorama_b, atol=1e-9)
    assert np.array_equal(per_tile.tile_index, np.repeat(np.flatnonzero(valid), len(points)))
