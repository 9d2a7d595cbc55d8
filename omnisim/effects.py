"""Sensor effects on rendered frames: exposure changes, Gaussian noise, JPEG compression.

All effects are seeded per frame, so a frame can be re-rendered alone (when
resuming) and come out identical.
"""

from __future__ import annotations

import numpy as np

from .config import EffectsSettings

__all__ = ["exposure_gains", "srgb_uint8_from_linear", "linear_from_srgb_uint8", "apply_effects"]


def exposure_gains(n: int, settings: EffectsSettings, *, seed: int) -> np.ndarray:
    """Per-frame exposure multipliers (n,): a random walk in stops, frame 0 at gain 1.

    Steps are uniform in ``±exposure_step_stops``; the walk is clipped to
    ``±exposure_stops``. All ones when ``exposure_stops`` is 0.
    """
    if settings.exposure_stops <= 0 or n < 1:
        return np.ones(n)
    rng = np.random.default_rng([seed, 0xE4])
    steps = rng.uniform(-settings.exposure_step_stops, settings.exposure_step_stops, size=n - 1)
    stops = np.zeros(n)
    for k, step in enumerate(steps, start=1):
        stops[k] = np.clip(stops[k - 1] + step, -settings.exposure_stops, settings.exposure_stops)
    return 2.0 ** stops


def srgb_uint8_from_linear(image: np.ndarray, *, gain: float = 1.0) -> np.ndarray:
    """Linear RGB (H,W,3) float -> sRGB-encoded uint8 (H,W,3), after multiplying by ``gain``."""
    x = np.clip(np.nan_to_num(np.asarray(image, dtype=np.float64) * gain, nan=0.0), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def linear_from_srgb_uint8(image: np.ndarray) -> np.ndarray:
    """sRGB-encoded uint8 image (any shape) -> linear intensity in [0, 1], float64 (inverse of the above)."""
    x = np.asarray(image, dtype=np.float64) / 255.0
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4))


def apply_effects(image: np.ndarray, settings: EffectsSettings, *, seed: int, frame: int) -> np.ndarray:
    """Add noise and JPEG artefacts to an 8-bit RGB frame (H,W,3) uint8; returns a new array."""
    out = np.asarray(image)
    if settings.noise_sigma > 0:
        rng = np.random.default_rng([seed, 0x401, frame])
        noisy = out.astype(np.float64) + rng.normal(0.0, settings.noise_sigma, size=out.shape)
        out = np.clip(np.round(noisy), 0, 255).astype(np.uint8)
    if settings.jpeg_quality > 0:
        import cv2

        ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(settings.jpeg_quality)])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1]
    return np.ascontiguousarray(out)
