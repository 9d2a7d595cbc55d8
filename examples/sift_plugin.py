"""An ifmi method from outside the project: SIFT keypoints (OpenCV) in the panorama's band.

Use it by its import path (this folder on PYTHONPATH), e.g.
``ifmi estimate DATASET --method sift_plugin:sift_front_end --out sift.txt``, or
register it from a package's ``pyproject.toml``::

    [project.entry-points."ifmi.methods"]
    sift = "sift_plugin:sift_front_end"
"""

import cv2
import numpy as np

from ifmi.geometry.camera import rays_from_pixels
from ifmi.front_end import Correspondences
from ifmi.spectral.panorama import band_mask, gray_from_image, panorama_mapping

RATIO = 0.75  # Lowe's ratio test on L2 descriptor distances
MARGIN_PX = 8  # keypoints this far inside the band's edges (static borders never match)
MIN_MATCHES = 8  # fewer matches fail the frame pair


class SiftFrontEnd:
    def __init__(self, model, config):
        self.model, self.panorama, self.mask = model, config.ifmi.panorama, None
        self.sift, self.matcher = cv2.SIFT_create(), cv2.BFMatcher(cv2.NORM_L2)

    def prepare(self, image):
        gray = np.clip(gray_from_image(image), 0, 255).astype(np.uint8)
        if self.mask is None:  # the pixels of the panorama's band (any camera model), from frame 0
            mapping = panorama_mapping(self.model, gray, config=self.panorama)
            self.mask = band_mask(mapping, margin_px=MARGIN_PX).astype(np.uint8) * 255
        keypoints, descriptors = self.sift.detectAndCompute(gray, self.mask)
        pixels = np.array([kp.pt[::-1] for kp in keypoints], dtype=float).reshape(-1, 2)  # (row, col)
        return pixels, rays_from_pixels(self.model, pixels), descriptors

    def correspondences(self, state_a, state_b):
        (pixels_a, rays_a, desc_a), (pixels_b, rays_b, desc_b) = state_a, state_b
        if desc_a is None or desc_b is None or min(len(desc_a), len(desc_b)) < 2:
            return Correspondences.failed("too few keypoints")
        pairs = [(m[0].queryIdx, m[0].trainIdx) for m in self.matcher.knnMatch(desc_a, desc_b, k=2)
                 if len(m) == 2 and m[0].distance < RATIO * m[1].distance]
        if len(pairs) < MIN_MATCHES:
            return Correspondences.failed(f"too few matches ({len(pairs)} < {MIN_MATCHES})")
        ia, ib = np.array(pairs).T
        return Correspondences(pixels_a[ia], pixels_b[ib], rays_a[ia], rays_b[ib],
                               {"n_matches": len(pairs)})


def sift_front_end(model, config):
    """SIFT keypoints in the panorama's band (OpenCV), L2 ratio-test matching."""
    return SiftFrontEnd(model, config)
