"""A plain feature pipeline as a reference method: what a competent user writes in a few lines.

OpenCV ORB with 3000 keypoints on the camera's whole valid image (less the
black pixels of the first frame, such as a catadioptric camera's own
reflection, and a margin of half a descriptor patch), brute-force Hamming
matching with Lowe's ratio test at 0.8, rays through the dataset's camera
model. It is an ifmi method through the front-end contract
(:mod:`ifmi.front_end`), so the shared back end and chaining solve its pairs
as those of every method; benchmarks compare the project's own ORB and AKAZE
defaults with it. Use it by its import path with this folder on PYTHONPATH::

    ifmi estimate DATASET --method reference_pipeline:reference_front_end --out ref.txt
"""

import cv2
import numpy as np

from ifmi.geometry.camera import rays_from_pixels, valid_mask
from ifmi.features import eroded_mask, match_descriptors
from ifmi.front_end import Correspondences
from ifmi.spectral.panorama import gray_from_image

FEATURES = 3000  # ORB keypoints per image
RATIO = 0.8  # Lowe's ratio test on Hamming distances
MARGIN_PX = 15  # half of ORB's 31-pixel descriptor patch: windows stay inside the valid image
MIN_MATCHES = 8  # fewer matches fail the frame pair


class ReferenceFrontEnd:
    """ORB keypoints on the valid image, ratio-test matching (see the module docstring)."""

    def __init__(self, model):
        self.model, self.mask = model, None
        self.orb = cv2.ORB_create(nfeatures=FEATURES)

    def _mask(self, gray):
        """Valid pixels of the camera model that are not black in the first image, eroded by the margin."""
        return eroded_mask(valid_mask(self.model) & (gray > 0), MARGIN_PX)

    def prepare(self, image):
        """``(pixels (N, 2) (row, col), rays (N, 3), descriptors (N, 32) uint8)`` of one image."""
        gray = np.clip(gray_from_image(image), 0, 255).astype(np.uint8)
        if self.mask is None:
            self.mask = self._mask(gray)
        keypoints, descriptors = self.orb.detectAndCompute(gray, self.mask)
        pixels = np.array([kp.pt[::-1] for kp in keypoints], dtype=float).reshape(-1, 2)  # (row, col)
        rays = rays_from_pixels(self.model, pixels) if len(pixels) else np.zeros((0, 3))
        return pixels, rays, descriptors

    def correspondences(self, state_a, state_b):
        """Ratio-test matches of frame a's keypoints against frame b's (:class:`ifmi.front_end.Correspondences`)."""
        (pixels_a, rays_a, desc_a), (pixels_b, rays_b, desc_b) = state_a, state_b
        if desc_a is None or desc_b is None or min(len(desc_a), len(desc_b)) < 2:
            return Correspondences.failed("too few keypoints")
        pairs = match_descriptors(desc_a, desc_b, ratio=RATIO, cross_check=False)
        if len(pairs) < MIN_MATCHES:
            return Correspondences.failed(f"too few matches ({len(pairs)} < {MIN_MATCHES})")
        ia, ib = pairs.T
        return Correspondences(pixels_a[ia], pixels_b[ib], rays_a[ia], rays_b[ib], {"n_matches": len(pairs)})


def reference_front_end(model, config):
    """Factory of the front-end contract: the plain ORB reference pipeline (``config`` is not used)."""
    return ReferenceFrontEnd(model)
