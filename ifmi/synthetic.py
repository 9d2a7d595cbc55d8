"""Exact synthetic omni images without a renderer, for tests and benchmarks.

A textured environment at infinity is stored as an equirectangular image
(rows: elevation from +90 to -90 degrees, columns: azimuth 0 to 360 degrees
about the world z axis). An omni image of a camera with orientation ``R_0k``
(camera-k directions to world = camera-0 directions) looks up, for every
pixel, the environment along ``R_0k @ rays_from_pixels(pixel)``. With the
environment at infinity only the rotation matters, so the ground truth is
exact up to the bilinear interpolation of the environment.

The texture is a mosaic of scikit-image's bundled photographs plus seeded
band-limited noise; scikit-image is needed only here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.spatial.transform import Rotation

from ifmi.geometry.camera import OcamModel, paracatadioptric_model, rays_from_pixels
from ifmi.io.atomic import atomic_write_bytes
from ifmi.io.calib import write_calib
from ifmi.io.tum import Trajectory, write_tum

__all__ = [
    "example_omni_model",
    "example_band_px",
    "environment_texture",
    "omni_from_environment",
    "rotation_sequence",
    "SyntheticSequence",
    "synthetic_sequence",
    "write_synthetic_dataset",
]

# Bundled scikit-image photographs (no download needed) used for the mosaic.
_PHOTOS = ("camera", "brick", "grass", "gravel", "astronaut", "coffee", "rocket", "chelsea",
           "moon", "immunohistochemistry", "coins", "clock")


# Example camera: a paraboloid mirror whose horizon is imaged at this fraction of the image
# side, and the sensor-radius band (fractions of the image height) that its mirror fills,
# as on a typical catadioptric camera (black centre: the camera's own reflection).
_EXAMPLE_HORIZON_FRACTION = 5 / 16
_EXAMPLE_BAND_FRACTIONS = (0.12, 0.47)


def example_omni_model(size: int) -> OcamModel:
    """Paracatadioptric camera of a ``size`` x ``size`` image, horizon at 5/16 of the side (pixels)."""
    return paracatadioptric_model((size, size), horizon_radius_px=size * _EXAMPLE_HORIZON_FRACTION)


def example_band_px(model: OcamModel) -> tuple[float, float]:
    """Sensor-radius band ``(inner, outer)`` in pixels imaged by :func:`example_omni_model`'s mirror."""
    inner, outer = _EXAMPLE_BAND_FRACTIONS
    return inner * model.height, outer * model.height


def environment_texture(*, height: int = 512, seed: int = 0, noise_level: float = 0.25) -> np.ndarray:
    """Equirectangular environment texture, float32 gray in [0, 255].

    Parameters
    ----------
    height : int, keyword-only
        Rows (180 degrees); the width is twice the height (360 degrees).
    seed : int, keyword-only
        Seed of the photo arrangement and the noise.
    noise_level : float, keyword-only
        Weight of the band-limited noise blended into the photos (0..1).

    Returns
    -------
    (height, 2 * height) float32 ndarray
    """
    import skimage.data
    from skimage.color import rgb2gray

    rng = np.random.default_rng(seed)
    width = 2 * height
    cell = height // 2
    rows, cols = height // cell, width // cell
    order = rng.permutation(rows * cols) % len(_PHOTOS)
    canvas = np.zeros((rows * cell, cols * cell), dtype=np.float32)
    for i in range(rows):
        for j in range(cols):
            photo = np.asarray(getattr(skimage.data, _PHOTOS[order[i * cols + j]])())
            if photo.ndim == 3:
                photo = rgb2gray(photo[..., :3]) * 255.0
            photo = cv2.resize(photo.astype(np.float32), (cell, cell), interpolation=cv2.INTER_AREA)
            if rng.random() < 0.5:
                photo = photo[:, ::-1]
            canvas[i * cell:(i + 1) * cell, j * cell:(j + 1) * cell] = photo
    canvas = cv2.resize(canvas, (width, height), interpolation=cv2.INTER_LINEAR)
    noise = rng.normal(size=(height, width)).astype(np.float32)
    noise = gaussian_filter(noise, 1.5, mode="wrap")
    noise = (noise - noise.mean()) / (noise.std() + 1e-12) * 40.0 + 128.0
    texture = (1.0 - noise_level) * canvas + noise_level * noise
    return np.clip(texture, 0.0, 255.0).astype(np.float32)


def omni_from_environment(environment: np.ndarray, model: OcamModel, rotation: np.ndarray, *,
                          band_px: tuple[float, float] | None = None) -> np.ndarray:
    """Omni image of the environment seen by a camera with orientation ``rotation``.

    Parameters
    ----------
    environment : (He, 2 He) float32 ndarray
        Equirectangular texture of :func:`environment_texture`.
    model : OcamModel
    rotation : (3, 3) ndarray
        Maps camera directions to world directions.
    band_px : (float, float), optional, keyword-only
        Sensor-radius band ``(inner, outer)`` in pixels that the mirror
        images; pixels outside are black (central reflection, outside the
        mirror). Default: everything is imaged.

    Returns
    -------
    (H, W) uint8 ndarray
    """
    h, w = model.size
    grid = np.stack(np.mgrid[0:h, 0:w], axis=-1).astype(np.float64)
    rays = rays_from_pixels(model, grid) @ np.asarray(rotation, dtype=np.float64).T
    he, we = environment.shape
    elevation = np.arcsin(np.clip(rays[..., 2], -1.0, 1.0))
    azimuth = np.arctan2(rays[..., 1], rays[..., 0])
    map_rows = ((np.pi / 2 - elevation) / np.pi * he - 0.5).astype(np.float32)
    map_cols = (np.mod(azimuth, 2 * np.pi) / (2 * np.pi) * we - 0.5).astype(np.float32)
    image = cv2.remap(environment, map_cols, map_rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    if band_px is not None:
        from ifmi.geometry.camera import radius_from_pixels

        radius = radius_from_pixels(model, grid)
        image[(radius < band_px[0]) | (radius > band_px[1])] = 0.0
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def rotation_sequence(n_frames: int, *, max_step_rad: float = 0.03, max_tilt_rad: float = 0.25,
                      seed: int = 0) -> np.ndarray:
    """Smooth random orientations ``R_0k`` starting at the identity.

    Yaw drifts with steps up to ``max_step_rad``; roll and pitch follow
    smooth random curves bounded by ``max_tilt_rad``.

    Parameters
    ----------
    n_frames : int
    max_step_rad : float, keyword-only
        Largest per-frame change of each angle, radians.
    max_tilt_rad : float, keyword-only
        Bound of roll and pitch, radians.
    seed : int, keyword-only

    Returns
    -------
    (n_frames, 3, 3) ndarray
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames, dtype=np.float64)
    yaw_rate = rng.uniform(0.4, 1.0) * max_step_rad * rng.choice([-1.0, 1.0])
    yaw = yaw_rate * t + 0.3 * max_step_rad * np.sin(t * rng.uniform(0.05, 0.2))
    tilt = []
    for _ in range(2):
        freq = rng.uniform(0.5, 1.0) * max_step_rad / max_tilt_rad
        phase = rng.uniform(0, 2 * np.pi)
        tilt.append(max_tilt_rad * (np.sin(freq * t + phase) - np.sin(phase)))
    ypr = np.stack([yaw - yaw[0], tilt[0], tilt[1]], axis=1)
    rotations = Rotation.from_euler("ZYX", ypr).as_matrix()
    return rotations[0].T @ rotations


@dataclass(frozen=True)
class SyntheticSequence:
    """Synthetic omni images with exact orientations.

    Attributes
    ----------
    model : OcamModel
    images : tuple of (H, W) uint8 ndarray
    rotations : (N, 3, 3) ndarray
        ``R_0k``.
    """

    model: OcamModel
    images: tuple
    rotations: np.ndarray

    @property
    def trajectory(self) -> Trajectory:
        n = len(self.images)
        return Trajectory(timestamps=np.arange(n, dtype=np.float64), positions=np.zeros((n, 3)),
                          rotations=self.rotations)


def synthetic_sequence(model: OcamModel, n_frames: int, *, seed: int = 0, max_step_rad: float = 0.03,
                       max_tilt_rad: float = 0.25, noise_std: float = 0.0,
                       band_px: tuple[float, float] | None = None,
                       environment_height: int = 512) -> SyntheticSequence:
    """A sequence of omni images of a random smooth rotation.

    Parameters
    ----------
    model : OcamModel
    n_frames : int
    seed : int, keyword-only
        Seeds the texture, the motion and the image noise.
    max_step_rad, max_tilt_rad : float, keyword-only
        See :func:`rotation_sequence`.
    noise_std : float, keyword-only
        Standard deviation of Gaussian gray-level noise added per image.
    band_px : (float, float), optional, keyword-only
        Imaged sensor-radius band; outside is black.
    environment_height : int, keyword-only
        Rows of the environment texture.

    Returns
    -------
    SyntheticSequence
    """
    environment = environment_texture(height=environment_height, seed=seed)
    rotations = rotation_sequence(n_frames, max_step_rad=max_step_rad, max_tilt_rad=max_tilt_rad,
                                  seed=seed + 1)
    rng = np.random.default_rng(seed + 2)
    images = []
    for rotation in rotations:
        image = omni_from_environment(environment, model, rotation, band_px=band_px)
        if noise_std > 0:
            noisy = image.astype(np.float32) + rng.normal(0.0, noise_std, image.shape).astype(np.float32)
            image = np.clip(np.round(noisy), 0, 255).astype(np.uint8)
        images.append(image)
    return SyntheticSequence(model=model, images=tuple(images), rotations=rotations)


def write_synthetic_dataset(path: str | os.PathLike, sequence: SyntheticSequence, *,
                            groundtruth: bool = True) -> Path:
    """Write a DATASET folder (calib, PNG images, optional ground truth).

    Returns
    -------
    Path
        The dataset folder.
    """
    root = Path(path)
    (root / "images").mkdir(parents=True, exist_ok=True)
    write_calib(root / "calib_results.txt", sequence.model)
    for k, image in enumerate(sequence.images):
        ok, data = cv2.imencode(".png", image)
        if not ok:
            raise RuntimeError(f"PNG encoding failed for frame {k}")
        atomic_write_bytes(root / "images" / f"{k:06d}.png", data.tobytes())
    if groundtruth:
        write_tum(root / "groundtruth.txt", sequence.trajectory, header="synthetic ground truth: T_0k")
    return root
