"""Block-compression detection, and the registration's choice of the band-limited search by it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage import data as skimage_data

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.spectral.compression import MIN_BLOCK_EDGE_RATIO, block_edge_ratio, is_block_compressed
from ifmi.spectral.fourier_mellin import FourierMellinConfig
from ifmi.spectral.ifmi_front_end import IfmiFrontEnd


def _camera() -> np.ndarray:
    return np.asarray(skimage_data.camera(), dtype=np.float32)


def _jpeg(image: np.ndarray, quality: int) -> np.ndarray:
    ok, buffer = cv2.imencode(".jpg", np.clip(np.round(image), 0, 255).astype(np.uint8),
                              [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return cv2.imdecode(buffer, cv2.IMREAD_GRAYSCALE)


def _noisy(image: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    noisy = image + np.random.default_rng(seed).normal(0.0, sigma, image.shape)
    return np.clip(np.round(noisy), 0, 255).astype(np.uint8)


def test_an_uncompressed_photo_has_no_block_grid_even_under_noise():
    photo = _camera()
    # Measured: 1.042 clean, 1.026 and 1.011 with noise of 5 and 15 grey levels.
    for image in (photo, _noisy(photo, 5.0, 1), _noisy(photo, 15.0, 2)):
        ratio = block_edge_ratio(image)
        assert abs(ratio - 1.0) < 0.06, ratio
        assert not is_block_compressed(image)


@pytest.mark.parametrize("quality", [30, 50, 75])
def test_a_jpeg_photo_keeps_its_block_grid_wherever_the_frame_starts(quality):
    noisy = _noisy(_camera(), 5.0, 3)
    compressed = _jpeg(noisy, quality)
    # A crop moves the grid by 3 pixels: its phase is found, not assumed.
    for image in (compressed, compressed[3:, 5:]):
        # Measured: 1.76, 1.50 and 1.25 (quality 30, 50, 75); 1.75, 1.49 and 1.24 after the crop.
        assert block_edge_ratio(image) >= MIN_BLOCK_EDGE_RATIO + 0.05, (quality, block_edge_ratio(image))
        assert is_block_compressed(image)


def _inside_a_circle(image: np.ndarray) -> np.ndarray:
    rows, cols = np.mgrid[0:image.shape[0], 0:image.shape[1]]
    centre = (np.array(image.shape) - 1) / 2.0
    return np.where(np.hypot(rows - centre[0], cols - centre[1]) < 0.45 * min(image.shape), image, 0)


def test_the_mask_outside_a_mirror_does_not_decide_and_frames_without_a_grid_are_refused():
    noisy = _noisy(_camera(), 5.0, 4)
    # Measured: 1.05 masked clean, 1.41 masked through JPEG quality 50 (1.50 unmasked).
    assert not is_block_compressed(_inside_a_circle(noisy))
    assert is_block_compressed(_jpeg(_inside_a_circle(noisy), 50))
    assert block_edge_ratio(np.full((64, 64), 7.0)) == 1.0
    with pytest.raises(ValueError, match="at least 16 px"):
        block_edge_ratio(np.zeros((8, 64)))
    assert not is_block_compressed(np.zeros((8, 64)))


def _noisy_pair_fraction_after_setup(image: np.ndarray) -> float:
    model = paracatadioptric_model(image.shape, horizon_radius_px=0.3 * image.shape[0])
    front_end = IfmiFrontEnd(model)
    front_end.prepare(image)
    return front_end.engine.config.noisy_pair_fraction


def test_the_band_limited_search_is_set_up_for_compressed_captures_only():
    photo = _camera()
    default = FourierMellinConfig().noisy_pair_fraction
    assert default > 0
    # Clean, and through noise of 5 grey levels without compression: the phase-only search alone.
    assert _noisy_pair_fraction_after_setup(photo.astype(np.uint8)) == 0.0
    assert _noisy_pair_fraction_after_setup(_noisy(photo, 5.0, 5)) == 0.0
    # The same noisy frame through JPEG quality 50: pairs failing most tiles are searched again.
    assert _noisy_pair_fraction_after_setup(_jpeg(_noisy(photo, 5.0, 5), 50)) == default
