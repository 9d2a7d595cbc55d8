"""Tile layout with overlap and wrap around the 360-degree seam."""

from __future__ import annotations

import numpy as np
import pytest

from ifmi.spectral.fourier_mellin import FourierMellin, FourierMellinConfig, max_tile_count
from ifmi.spectral.tiling import (TilingConfig, tile_grid_shape, tile_layout,
                         tile_size_px, tiles_from_panorama)


def test_non_overlapping_tiles_cover_the_circle():
    layout = tile_layout((100, 640), config=TilingConfig(tile_size=64))
    assert layout.tile_size == 64
    assert layout.grid_shape == (1, 10)
    assert np.array_equal(layout.origins[:, 1], np.arange(10) * 64)
    assert np.all(layout.origins[:, 0] == 18)  # centred: (100 - 64) // 2


def test_overlap_halves_the_step_and_wraps():
    layout = tile_layout((128, 512), config=TilingConfig(tile_size=64, overlap=0.5))
    assert layout.grid_shape == (3, 16)
    cols = layout.origins[:16, 1]
    assert np.array_equal(np.diff(cols), np.full(15, 32))
    # The last tile starts at 480 and continues over the seam into columns 0..31.
    assert cols[-1] + layout.tile_size > 512
    assert np.array_equal(np.unique(layout.origins[:, 0]), [0, 32, 64])


def test_seam_tile_content_wraps():
    pano = np.arange(64 * 300, dtype=np.float32).reshape(64, 300)
    layout = tile_layout(pano.shape, config=TilingConfig(tile_size=64, overlap=0.25))
    tiles = tiles_from_panorama(pano, layout)
    for tile, (r, c) in zip(tiles, layout.origins):
        expected = pano[r:r + 64][:, (c + np.arange(64)) % 300]
        assert np.array_equal(tile, expected)
    assert (layout.origins[:, 1] + 64 > 300).any()
    # The same tiles, some of them, from a panorama already wrapped by 70 or 10 columns a side.
    some = np.arange(layout.count) % 2 == 1
    for pad in (70, 10):
        padded = np.concatenate([pano[:, -pad:], pano, pano[:, :pad]], axis=1)
        assert np.array_equal(tiles_from_panorama(padded, layout, index=some, wrapped_columns=pad), tiles[some])


def test_panorama_of_the_wrong_shape_is_rejected():
    layout = tile_layout((64, 300), config=TilingConfig(tile_size=64))
    with pytest.raises(ValueError, match=r"expected a panorama of shape \(64, 440\)"):
        tiles_from_panorama(np.zeros((64, 300)), layout, wrapped_columns=70)


def test_fractional_tile_size():
    assert tile_size_px(0.1, 1024) == 102
    layout = tile_layout((128, 1024), config=TilingConfig(tile_size=0.1))
    assert layout.tile_size == 102
    assert np.allclose(layout.centers[:, 1], np.mod(layout.origins[:, 1] + 50.5, 1024))


def test_tile_larger_than_panorama_is_rejected():
    with pytest.raises(ValueError, match="does not fit"):
        tile_layout((40, 512), config=TilingConfig(tile_size=64))


def test_bad_overlap_is_rejected():
    with pytest.raises(ValueError, match="overlap"):
        TilingConfig(overlap=1.0)


def test_automatic_tile_size_follows_the_width():
    assert tile_size_px(None, 1024) == 64
    assert tile_size_px(None, 768) == 48
    assert tile_size_px(None, 256) == 32
    assert tile_layout((200, 1024), config=TilingConfig()).tile_size == 64


@pytest.mark.parametrize("shape, config", [((100, 640), TilingConfig(tile_size=64)),
                                           ((128, 512), TilingConfig(tile_size=64, overlap=0.5)),
                                           ((92, 512), TilingConfig(overlap=0.999)),
                                           ((128, 1024), TilingConfig(tile_size=0.1, overlap=0.3))])
def test_grid_shape_is_the_layouts(shape, config):
    assert tile_grid_shape(shape, config=config) == tile_layout(shape, config=config).grid_shape


def test_registration_refuses_more_tiles_than_its_memory_budget():
    # Before: any count was taken, and a near-1 overlap registered 31232 tiles of 32 px per frame (1.6 GiB).
    assert max_tile_count(32) == 12483 and max_tile_count(64) == 3120
    # A larger log-polar grid takes more memory per tile, so fewer tiles.
    assert max_tile_count(32, config=FourierMellinConfig(log_polar_angles=128, log_polar_radii=128)) == 2299
    FourierMellin(32, 12483)
    with pytest.raises(ValueError, match=r"^tile count must be from 1 to 12483 for 32 px tiles \(registering a "
                                         r"frame pair within 1 GiB\), got 31232$"):
        FourierMellin(32, 31232)
