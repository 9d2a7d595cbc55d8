"""Square sub-images (tiles) of a panorama, wrapping around the 360-degree seam.

Tiles are ``N x N`` with ``N`` given in pixels or as a fraction of the
panorama width. Neighbouring tiles overlap by ``overlap * N`` pixels. Along
the azimuth the tiles are spread evenly around the full circle, so the last
tile wraps over the seam into column 0; along the elevation they are centred
in the panorama's height.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = ["TilingConfig", "TileLayout", "tile_layout", "tiles_from_panorama", "tile_size_px", "tile_step_px",
           "tile_grid_shape", "MIN_TILE_SIZE_PX"]

# Smallest tile side in pixels: the Fourier-Mellin registration (ifmi.spectral.fourier_mellin.FourierMellin)
# needs at least 8 samples along each axis of a tile and of its log-polar grid.
MIN_TILE_SIZE_PX = 8


@dataclass(frozen=True)
class TilingConfig:
    """Tile size and overlap.

    Attributes
    ----------
    tile_size : float or None
        Tile side ``N``: pixels when >= 1 (at least :data:`MIN_TILE_SIZE_PX`;
        rounded to an even number, which suits the FFT), a fraction of the
        panorama width when < 1 (the tile it gives must have at least
        :data:`MIN_TILE_SIZE_PX` pixels too, checked against the camera by
        :func:`ifmi.spectral.config_limits.check_config_for_model`); ``None``
        is a 16th of the width, kept within 32..64 pixels (64 at the usual
        1024 px width: smaller tiles carry too little texture on noisy
        images, larger ones move less rigidly).
    overlap : float
        Fraction of a tile shared with its neighbour, in ``[0, 1)``. Near 1
        the step from tile to tile is a pixel or two and a frame gets tens
        of thousands of tiles; the estimate's entry points refuse more than
        :func:`ifmi.spectral.fourier_mellin.max_tile_count`
        (:func:`ifmi.spectral.config_limits.check_config_for_model`).
    """

    tile_size: float | None = None
    overlap: float = 0.0

    def __post_init__(self) -> None:
        size = self.tile_size
        if size is not None and not (math.isfinite(size) and (0 < size < 1 or size >= MIN_TILE_SIZE_PX)):
            raise ValueError(f"tile_size must be a fraction in (0, 1) of the panorama width or at least "
                             f"{MIN_TILE_SIZE_PX} px, got {size}")
        if not 0 <= self.overlap < 1:
            raise ValueError(f"overlap must be in [0, 1), got {self.overlap}")


@dataclass(frozen=True)
class TileLayout:
    """Where the tiles of a panorama are.

    Attributes
    ----------
    tile_size : int
        Tile side ``N`` in pixels.
    origins : (T, 2) int ndarray
        Panorama ``(row, col)`` of each tile's top-left pixel; columns are in
        ``[0, width)`` and the tile continues across the seam modulo ``width``.
    panorama_shape : (int, int)
        Panorama ``(height, width)``.
    grid_shape : (int, int)
        Number of tile rows and columns; tile ``t`` is at grid row
        ``t // columns``, grid column ``t % columns``.
    """

    tile_size: int
    origins: np.ndarray
    panorama_shape: tuple
    grid_shape: tuple

    @property
    def count(self) -> int:
        """Number of tiles ``T``."""
        return len(self.origins)

    @property
    def centers(self) -> np.ndarray:
        """(T, 2) panorama ``(row, col)`` of each tile's centre ``(N - 1) / 2`` (columns wrapped)."""
        c = (self.tile_size - 1) / 2.0
        centres = self.origins + c
        centres[:, 1] = np.mod(centres[:, 1], self.panorama_shape[1])
        return centres


# Range of the automatic tile side, pixels (see TilingConfig.tile_size).
_AUTO_TILE_RANGE = (32, 64)


def tile_size_px(tile_size: float | None, panorama_width: int) -> int:
    """Tile side in pixels (even) from a size in pixels (>= 1), a width fraction (< 1) or None (auto)."""
    if tile_size is None:
        return int(np.clip(2 * round(panorama_width / 32), *_AUTO_TILE_RANGE))
    size = tile_size * panorama_width if tile_size < 1 else tile_size
    return max(4, 2 * int(round(size / 2.0)))


def tile_step_px(tile_size: int, overlap: float) -> int:
    """Pixels from one tile's origin to its neighbour's: ``N (1 - overlap)``, rounded, at least 1."""
    return max(1, int(round(tile_size * (1.0 - overlap))))


def tile_grid_shape(panorama_shape: tuple[int, int], *, config: TilingConfig = TilingConfig()) -> tuple[int, int]:
    """Tile rows and columns of :func:`tile_layout`, without building the layout.

    Parameters
    ----------
    panorama_shape : (int, int)
        Panorama ``(height, width)`` in pixels.
    config : TilingConfig, keyword-only

    Returns
    -------
    (int, int)
        ``TileLayout.grid_shape``; the tile count is their product.

    Raises
    ------
    ValueError
        The tile is larger than the panorama.
    """
    height, width = (int(v) for v in panorama_shape)
    n = tile_size_px(config.tile_size, width)
    if n > height or n > width:
        raise ValueError(f"tile size {n} px does not fit the {height}x{width} panorama; "
                         f"expected at most {min(height, width)} px")
    step = tile_step_px(n, config.overlap)
    return 1 + (height - n) // step, max(1, int(round(width / step)))


def tile_layout(panorama_shape: tuple[int, int], *, config: TilingConfig = TilingConfig()) -> TileLayout:
    """Tile layout of a panorama.

    Parameters
    ----------
    panorama_shape : (int, int)
        Panorama ``(height, width)`` in pixels.
    config : TilingConfig, keyword-only

    Returns
    -------
    TileLayout
    """
    height, width = (int(v) for v in panorama_shape)
    n_rows, n_cols = tile_grid_shape((height, width), config=config)
    n = tile_size_px(config.tile_size, width)
    step = tile_step_px(n, config.overlap)
    top = (height - n - (n_rows - 1) * step) // 2
    col0 = np.round(np.arange(n_cols) * (width / n_cols)).astype(int)
    row0 = top + step * np.arange(n_rows)
    rows, cols = np.meshgrid(row0, col0, indexing="ij")
    origins = np.stack([rows.ravel(), cols.ravel()], axis=1)
    return TileLayout(tile_size=n, origins=origins, panorama_shape=(height, width),
                      grid_shape=(n_rows, n_cols))


def tiles_from_panorama(panorama: np.ndarray, layout: TileLayout, *, index: np.ndarray | None = None,
                        wrapped_columns: int = 0) -> np.ndarray:
    """Cut tiles of a panorama into one array.

    Parameters
    ----------
    panorama : (H, W + 2 P) ndarray
        The panorama, with ``P`` (``wrapped_columns``) columns wrapped onto each side.
    layout : TileLayout
    index : (T,) bool ndarray or (K,) int ndarray, optional, keyword-only
        The tiles to cut; default all.
    wrapped_columns : int, keyword-only
        ``P``; with ``P >= N`` the tiles that cross the seam are read from
        the wrapped columns, otherwise the panorama is wrapped here.

    Returns
    -------
    (K, N, N) ndarray
        Tile ``t`` is ``panorama[r:r+N, P + (c + arange(N)) % W]`` for origin ``(r, c)``.
    """
    height, width = layout.panorama_shape
    pad = int(wrapped_columns)
    if panorama.shape != (height, width + 2 * pad):
        raise ValueError(f"expected a panorama of shape {(height, width + 2 * pad)}, got {panorama.shape}")
    n = layout.tile_size
    origins = layout.origins if index is None else layout.origins[index]
    if pad < n:
        panorama = np.concatenate([panorama[:, pad:pad + width], panorama[:, pad:pad + n]], axis=1)
        pad = 0
    # One strided copy per tile from the view of all N x N windows (8x faster than gathering
    # every pixel by index for 128 tiles of 32 px).
    windows = sliding_window_view(panorama, (n, n))
    return windows[origins[:, 0], origins[:, 1] + pad]


