"""Motion flow: the flow equation against directly warped points; pixels and rays of flow pairs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model, rays_from_pixels
from ifmi.spectral.flow import flow_from_tile_motion, flow_sample_points, pairs_with_rays_a
from ifmi.spectral.fourier_mellin import FourierMellin, FourierMellinConfig, TileMotion, transform_points
from ifmi.spectral.tiling import TilingConfig, tile_layout
from ifmi.spectral.panorama import PanoramaConfig, panorama_mapping

MODEL = paracatadioptric_model((200, 220), horizon_radius_px=60.0, center=(99.0, 111.5),
                               affine=(1.003, 0.004, -0.002))


def test_flow_points_follow_a_global_similarity():
    skimage_data = pytest.importorskip("skimage.data")
    image = np.asarray(skimage_data.camera(), dtype=np.float32)
    n = 128
    # Global motion b(x) = a(G(x)), G(x) = s R (x - x0) + x0 + T, about x0.
    s, angle, x0, shift = 1.02, np.radians(3.0), np.array([256.0, 256.0]), np.array([1.5, -2.0])
    rot = s * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    rows, cols = np.mgrid[0:512, 0:512].astype(np.float64)
    pts = np.stack([rows, cols], axis=-1) - x0
    src = pts @ rot.T + x0 + shift
    moved = cv2.remap(image, src[..., 1].astype(np.float32), src[..., 0].astype(np.float32),
                      cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    origins = np.array([[150, 130], [200, 250], [260, 180]])
    engine = FourierMellin(n, len(origins), config=FourierMellinConfig(refine_passes=2))
    a = np.stack([image[r:r + n, c:c + n] for r, c in origins])
    b = np.stack([moved[r:r + n, c:c + n] for r, c in origins])
    motion = engine.register(engine.spectra(a), engine.spectra(b), moved, origins)
    q = flow_sample_points(n, points_per_tile=9, spread=0.25)
    in_a = transform_points(q, motion.scale, motion.angle_rad, motion.translation, n) + origins[:, None]
    direct = (origins[:, None] + q - x0) @ rot.T + x0 + shift
    # Points 32 px from the tile centre: an angle error of 0.1 deg and a scale error of 0.2 %
    # move them by 0.06 px each.
    assert np.max(np.abs(in_a - direct)) < 0.15


def test_flow_pairs_of_a_column_shift_are_a_rotation_about_z():
    mapping = panorama_mapping(MODEL, config=PanoramaConfig(width=256, radius_min_px=25, radius_max_px=95))
    layout = tile_layout((mapping.height, mapping.width), config=TilingConfig(tile_size=32))
    t = layout.count
    d = 3.25
    motion = TileMotion(scale=np.ones(t), angle_rad=np.zeros(t), translation=np.tile([0.0, d], (t, 1)),
                        peak_ratio=np.full(t, 5.0), peak_to_noise=np.full(t, 20.0),
                        peak_value=np.ones(t), rotation_peak_ratio=np.full(t, 5.0),
                        valid=np.arange(t) % 3 != 0, reason=np.where(np.arange(t) % 3 != 0, 0, 2))
    pairs = flow_from_tile_motion(motion, layout, mapping, points_b=flow_sample_points(32))
    assert len(pairs.rays_a) == 5 * int(motion.valid.sum())
    assert set(pairs.tile_index) == set(np.flatnonzero(motion.valid))
    yaw = d * 2 * np.pi / mapping.width
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    assert np.allclose(pairs.rays_a, pairs.rays_b @ rz.T, atol=1e-9)
    # Omni pixels lift to the same rays (inverse polynomial fitted to 1e-4 px).
    assert np.allclose(rays_from_pixels(MODEL, pairs.pixels_a), pairs.rays_a, atol=1e-5)
    assert np.all(pairs.panorama_a[:, 1] < mapping.width) and np.all(pairs.panorama_a[:, 1] >= 0)


def test_moved_rays_carry_their_panorama_and_omni_pixels():
    mapping = panorama_mapping(MODEL, config=PanoramaConfig(width=256, radius_min_px=25, radius_max_px=95))
    layout = tile_layout((mapping.height, mapping.width), config=TilingConfig(tile_size=32))
    t = layout.count
    motion = TileMotion(scale=np.ones(t), angle_rad=np.zeros(t), translation=np.tile([0.5, 2.0], (t, 1)),
                        peak_ratio=np.full(t, 5.0), peak_to_noise=np.full(t, 20.0),
                        peak_value=np.ones(t), rotation_peak_ratio=np.full(t, 5.0),
                        valid=np.ones(t, bool), reason=np.zeros(t, int))
    pairs = flow_from_tile_motion(motion, layout, mapping, points_b=flow_sample_points(32))
    # Frame a's points moved by half a panorama column of yaw: rays, panorama and omni pixels agree.
    yaw = 0.5 * 2 * np.pi / mapping.width
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    moved = pairs_with_rays_a(pairs, pairs.rays_a @ rz.T, mapping)
    assert np.allclose(moved.rays_a, pairs.rays_a @ rz.T, atol=1e-15)
    assert np.allclose(moved.panorama_a[:, 0], pairs.panorama_a[:, 0], atol=1e-9)
    assert np.allclose(np.mod(moved.panorama_a[:, 1] - pairs.panorama_a[:, 1], mapping.width), 0.5, atol=1e-9)
    assert np.allclose(rays_from_pixels(MODEL, moved.pixels_a), moved.rays_a, atol=1e-5)
    assert moved.rays_b is pairs.rays_b and moved.pixels_b is pairs.pixels_b


def test_bad_points_per_tile_is_rejected():
    with pytest.raises(ValueError, match="points_per_tile"):
        flow_sample_points(32, points_per_tile=4)
