"""Exact synthetic omni images for tests: a textured sphere at infinity.

Every pixel of frame k shows the environment texture in the direction
``R_0k @ ray_k(pixel)``, so frames differ by a pure rotation known exactly.
The environment is an equirectangular strip made of scikit-image's bundled
photographs (azimuth along columns, elevation along rows).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ifmi.camera import paracatadioptric_model, radius_from_pixels, rays_from_pixels
from ifmi.io.calib import write_calib
from ifmi.io.tum import Trajectory, write_tum
from ifmi.rotations import matrix_from_rpy

# Elevation range (radians) covered by the texture strip's rows.
ELEVATION_RANGE = (np.deg2rad(-75.0), np.deg2rad(45.0))


def environment_texture(height: int = 360) -> np.ndarray:
    """``(height, ~6*height)`` uint8 equirectangular texture from bundled photographs."""
    from skimage import data

    tiles = []
    for name in ("astronaut", "coffee", "chelsea", "camera", "rocket", "motorcycle_left"):
        try:
            img = getattr(data, name)()
        except Exception:  # a photograph that is not bundled in this wheel
            continue
        if img.ndim == 3:
            img = cv2.cvtColor(img[..., :3], cv2.COLOR_RGB2GRAY)
        scale = height / img.shape[0]
        tiles.append(cv2.resize(img, (int(round(img.shape[1] * scale)), height),
                                interpolation=cv2.INTER_AREA))
    return np.ascontiguousarray(np.hstack(tiles))


def omni_model(size: int = 256):
    """Paracatadioptric camera of a ``size`` x ``size`` image, horizon at 5/16 of the width."""
    return paracatadioptric_model((size, size), horizon_radius_px=size * 5 / 16)


def mirror_band(model) -> tuple[float, float]:
    """Sensor radius band ``(inner, outer)`` the synthetic images fill (pixels)."""
    h = model.size[0]
    return 0.12 * h, 0.47 * h


def render_omni(model, rotation_0k: np.ndarray, texture: np.ndarray) -> np.ndarray:
    """Omni image ``(H, W)`` uint8 of the environment seen with orientation ``R_0k``."""
    h, w = model.size
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    pix = np.stack([rows, cols], axis=-1)
    rays = rays_from_pixels(model, pix) @ np.asarray(rotation_0k).T
    az = np.arctan2(rays[..., 1], rays[..., 0])
    el = np.arctan2(rays[..., 2], np.hypot(rays[..., 0], rays[..., 1]))
    th, tw = texture.shape
    map_x = ((az + np.pi) / (2 * np.pi) * tw - 0.5).astype(np.float32)
    lo, hi = ELEVATION_RANGE
    map_y = ((hi - el) / (hi - lo) * th - 0.5).astype(np.float32)
    image = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    inner, outer = mirror_band(model)
    r = radius_from_pixels(model, pix)
    image[(r < inner) | (r > outer)] = 0
    return image


def rotation_sequence(n: int, *, seed: int = 0, step_rad: float = 0.03) -> np.ndarray:
    """``(n, 3, 3)`` smooth random orientations ``R_0k``, frame 0 the identity."""
    rng = np.random.default_rng(seed)
    rates = rng.uniform(-1.0, 1.0, size=3) * step_rad
    k = np.arange(n)[:, None]
    rpy = rates * k + 0.5 * step_rad * np.sin(k * np.array([0.3, 0.5, 0.7]))
    rpy -= rpy[0]
    return matrix_from_rpy(rpy)


def write_dataset(folder: Path, *, n: int = 6, size: int = 160, seed: int = 0,
                  step_rad: float = 0.03) -> Path:
    """DATASET folder (calib, images, groundtruth) of a pure-rotation sequence."""
    folder = Path(folder)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    model = omni_model(size)
    write_calib(folder / "calib_results.txt", model)
    texture = environment_texture()
    rotations = rotation_sequence(n, seed=seed, step_rad=step_rad)
    for k, R in enumerate(rotations):
        cv2.imwrite(str(folder / "images" / f"{k:06d}.png"), render_omni(model, R, texture))
    write_tum(folder / "groundtruth.txt",
              Trajectory(np.arange(n, dtype=float), np.zeros((n, 3)), rotations))
    return folder
