"""Motion flow: pixel pairs from tile motions, in the panorama and the omni image.

For each kept tile the flow equation (:func:`ifmi.spectral.fourier_mellin.transform_points`)
maps a few points ``q`` of tile b (its centre and points around it) to
``M(q)`` in tile a; adding the tile's origin gives panorama ``(row, col)``
pairs, which the panorama mapping turns into omni-image pixels and rays.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ifmi.spectral.fourier_mellin import TileMotion, transform_points
from ifmi.spectral.tiling import TileLayout
from ifmi.geometry.camera import pixels_from_rays
from ifmi.spectral.panorama import PanoramaMapping, panorama_pixels_from_rays, rays_from_panorama_pixels

__all__ = ["FlowPairs", "flow_sample_points", "points_on_centroids", "flow_from_tile_motion",
           "flow_from_placements", "pairs_with_rays_a"]


@dataclass(frozen=True)
class FlowPairs:
    """Corresponding points of two frames.

    Attributes
    ----------
    panorama_a, panorama_b : (M, 2) ndarray
        Panorama ``(row, col)`` in frame a and b (columns in ``[0, width)``).
    pixels_a, pixels_b : (M, 2) ndarray
        Omni-image ``(row, col)``.
    rays_a, rays_b : (M, 3) ndarray
        Unit rays.
    tile_index : (M,) int ndarray
        Tile each pair comes from.
    """

    panorama_a: np.ndarray
    panorama_b: np.ndarray
    pixels_a: np.ndarray
    pixels_b: np.ndarray
    rays_a: np.ndarray
    rays_b: np.ndarray
    tile_index: np.ndarray


def flow_sample_points(tile_size: int, *, points_per_tile: int = 5, spread: float = 0.25) -> np.ndarray:
    """Points of a tile at which the flow is sampled, tile ``(row, col)``.

    Parameters
    ----------
    tile_size : int
    points_per_tile : int, keyword-only
        1 (centre), 5 (centre and four diagonal points) or 9 (3 x 3 grid).
    spread : float, keyword-only
        Offset of the outer points from the centre as a fraction of the tile size.

    Returns
    -------
    (K, 2) ndarray
    """
    c = (tile_size - 1) / 2.0
    delta = spread * tile_size
    if points_per_tile == 1:
        offsets = np.zeros((1, 2))
    elif points_per_tile == 5:
        offsets = np.array([[0, 0], [-1, -1], [-1, 1], [1, -1], [1, 1]], dtype=float) * delta
    elif points_per_tile == 9:
        g = np.array([-1.0, 0.0, 1.0]) * delta
        offsets = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    else:
        raise ValueError(f"points_per_tile must be 1, 5 or 9, got {points_per_tile}")
    return offsets + c


def flow_from_tile_motion(motion: TileMotion, layout: TileLayout, mapping: PanoramaMapping, *,
                          points_b: np.ndarray, origins_b: np.ndarray | None = None) -> FlowPairs:
    """Pixel and ray pairs of the valid tiles.

    Parameters
    ----------
    motion : TileMotion
        Registration of frame b's tiles against frame a's.
    layout : TileLayout
    mapping : PanoramaMapping
    points_b : (K, 2) or (T, K, 2) ndarray, keyword-only
        Tile-b points (tile ``(row, col)``) of :func:`flow_sample_points`,
        the same for every tile or one set per tile (:func:`points_on_centroids`).
    origins_b : (T, 2) ndarray, optional, keyword-only
        Panorama ``(row, col)`` of tile b's first pixel when tile b was cut
        elsewhere than tile a (motion prediction); default the layout's.

    Returns
    -------
    FlowPairs
    """
    keep = np.flatnonzero(motion.valid)
    points_b = _kept_points(points_b, keep)
    k = points_b.shape[-2]
    origins = layout.origins[keep].astype(np.float64)
    origins_b = origins if origins_b is None else np.asarray(origins_b, dtype=np.float64)[keep]
    in_a = transform_points(points_b, motion.scale[keep], motion.angle_rad[keep],
                            motion.translation[keep], layout.tile_size)
    pano_a = (in_a + origins[:, None, :]).reshape(-1, 2)
    pano_b = (np.broadcast_to(points_b, in_a.shape) + origins_b[:, None, :]).reshape(-1, 2)
    return _flow_pairs(pano_a, pano_b, mapping, np.repeat(keep, k))


def points_on_centroids(points: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """Sample points of each tile moved onto its energy centroid.

    Parameters
    ----------
    points : (K, 2) ndarray
        Tile ``(row, col)`` points of :func:`flow_sample_points` (around the tile centre).
    centroids : (T, 2) ndarray
        ``(row, col)`` of each tile's centroid, pixels from its centre
        (:attr:`ifmi.spectral.fourier_mellin.TileSpectra.centroid`).

    Returns
    -------
    (T, K, 2) ndarray
    """
    return np.asarray(points, dtype=np.float64)[None] + np.asarray(centroids, dtype=np.float64)[:, None, :]


def _kept_points(points: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Points ``(K, 2)`` shared by all tiles, or the kept tiles' rows of per-tile points ``(T, K, 2)``."""
    points = np.asarray(points, dtype=np.float64)
    return points[keep] if points.ndim == 3 else points


def _flow_pairs(pano_a: np.ndarray, pano_b: np.ndarray, mapping: PanoramaMapping,
                tile_index: np.ndarray) -> FlowPairs:
    """FlowPairs of panorama point pairs (columns wrapped into ``[0, width)`` in place)."""
    pano_a[:, 1] = np.mod(pano_a[:, 1], mapping.width)
    pano_b[:, 1] = np.mod(pano_b[:, 1], mapping.width)
    # Both frames' points in one call each (the omni pixels are those of the rays).
    rays = rays_from_panorama_pixels(mapping, np.concatenate([pano_a, pano_b]))
    pixels = pixels_from_rays(mapping.model, rays)
    m = len(pano_a)
    return FlowPairs(panorama_a=pano_a, panorama_b=pano_b, pixels_a=pixels[:m], pixels_b=pixels[m:],
                     rays_a=rays[:m], rays_b=rays[m:], tile_index=tile_index)


def pairs_with_rays_a(pairs: FlowPairs, rays_a: np.ndarray, mapping: PanoramaMapping) -> FlowPairs:
    """``pairs`` with frame a's points moved onto ``rays_a``; their panorama and omni pixels follow.

    Parameters
    ----------
    pairs : FlowPairs
    rays_a : (M, 3) ndarray
        Unit rays, one per pair.
    mapping : PanoramaMapping
    """
    return replace(pairs, rays_a=rays_a, panorama_a=panorama_pixels_from_rays(mapping, rays_a),
                   pixels_a=pixels_from_rays(mapping.model, rays_a))


def flow_from_placements(offsets_a: np.ndarray, linear_a: np.ndarray, offsets_b: np.ndarray,
                         linear_b: np.ndarray, valid: np.ndarray, mapping: PanoramaMapping, *,
                         points: np.ndarray, tile_size: int, curvature_a: np.ndarray | None = None,
                         curvature_b: np.ndarray | None = None) -> FlowPairs:
    """Pixel and ray pairs of tiles placed in both frames.

    A tile placed at ``(o, L)`` in a panorama holds the panorama point
    ``o + L (p - c)`` at tile point ``p`` (``c`` the tile centre); when the
    registration has aligned the two tiles, the same tile point is the same
    scene point in both frames.

    Parameters
    ----------
    offsets_a, offsets_b : (T, 2) ndarray
        Panorama ``(row, col)`` of the tile centres in frame a and b.
    linear_a, linear_b : (T, 2, 2) ndarray
        Panorama ``(row, col)`` per tile ``(row, col)`` step.
    valid : (T,) bool ndarray
        Tiles to use.
    mapping : PanoramaMapping
    points : (K, 2) or (T, K, 2) ndarray, keyword-only
        Tile ``(row, col)`` points of :func:`flow_sample_points`, the same
        for every tile or one set per tile (:func:`points_on_centroids`).
    tile_size : int, keyword-only
    curvature_a, curvature_b : (T, 2, 2, 2) ndarray, optional, keyword-only
        Second-order terms ``Q`` of the placements: tile point ``u`` (from the
        centre) is at ``o + L u + (u^T Q_0 u, u^T Q_1 u)``; default none.

    Returns
    -------
    FlowPairs
    """
    keep = np.flatnonzero(valid)
    u = _kept_points(points, keep) - (tile_size - 1) / 2.0
    u = np.broadcast_to(u, (len(keep),) + u.shape[-2:])

    def panorama(offsets, linear, curvature):
        offsets = np.asarray(offsets, dtype=np.float64)[keep]
        linear = np.asarray(linear, dtype=np.float64)[keep]
        placed = offsets[:, None, :] + np.einsum("tij,tkj->tki", linear, u)
        if curvature is not None:
            placed += np.einsum("tki,toij,tkj->tko", u, np.asarray(curvature, dtype=np.float64)[keep], u)
        return placed.reshape(-1, 2)

    return _flow_pairs(panorama(offsets_a, linear_a, curvature_a), panorama(offsets_b, linear_b, curvature_b),
                       mapping, np.repeat(keep, u.shape[1]))
