"""Feature front ends (ORB, AKAZE) for the comparison with iFMI.

Keypoints are detected on the omni image inside the mirror's image band (the
same radius band the iFMI front end unwarps), or optionally on the panorama
of that band. Binary descriptors are matched with a brute-force Hamming
matcher, two nearest neighbours and a ratio test (optionally mutual best
matches only). Matched keypoints are lifted to rays with the camera model;
the relative-pose back end and the odometry are those of every method
(:mod:`ifmi.pipeline`), so a comparison isolates the front end.

OpenCV reports keypoints as ``(x, y) = (col, row)``; everything leaving this
module is ``(row, col)``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Mapping

import cv2
import numpy as np

from ifmi.geometry.camera import OcamModel, radius_from_pixels, rays_from_pixels, valid_mask
from ifmi.front_end import Correspondences
from ifmi.options import check_finite_fields, options_from_dict

__all__ = [
    "DETECTORS",
    "FeatureConfig",
    "FeatureFrame",
    "FeatureFrontEnd",
    "create_detector",
    "eroded_mask",
    "match_descriptors",
    "orb_front_end",
    "akaze_front_end",
]

# Detector names accepted by FeatureFrontEnd.
DETECTORS = ("orb", "akaze")
# OpenCV's own default keypoint count of ORB, used when n_features is 0.
ORB_DEFAULT_FEATURES = 500
# Most AKAZE sublevels per octave. Each holds a few full-size float images of its octave, so
# memory grows linearly with them (a million layers asks for hundreds of gigabytes); at 32 the
# scale step between sublevels (2^(1/32), 2 %) is already finer than the detector resolves.
_MAX_AKAZE_LAYERS = 32
# Largest FAST threshold of ORB, gray levels: a corner needs pixels brighter or darker than the
# centre by more than the threshold, and 8-bit images differ by at most 255.
_MAX_FAST_THRESHOLD = 254


@dataclass(frozen=True)
class FeatureConfig:
    """Options of the ORB and AKAZE front ends.

    Defaults are OpenCV's standard settings with 3000 features and Lowe's
    ratio 0.8, a FAST threshold for low-contrast images, and AKAZE's
    threshold lowered on a sequence whose first image gives too few keypoints.

    Attributes
    ----------
    n_features : int
        ORB: number of keypoints kept by the detector (0: OpenCV's default,
        500). AKAZE: keep the strongest ``n_features`` by response (0 keeps
        all).
    ratio : float
        Lowe ratio test: keep a match when its Hamming distance is below
        ``ratio`` times that of the second-best candidate; in (0, 1].
    cross_check : bool
        Also require the match to be the best one seen from frame b.
    on_panorama : bool
        Detect on the panorama of the mirror band instead of the omni image;
        keypoints are mapped back to omni pixels before lifting to rays.
    min_matches : int
        Fewer matches than this flags the pair as failed.
    orb_scale_factor, orb_levels, orb_edge_threshold, orb_patch_size, orb_fast_threshold
        ``cv2.ORB_create`` options (pyramid ratio, levels, border in pixels,
        descriptor patch in pixels, FAST threshold in gray levels): a scale
        factor above 1, at least one level, a border of at least 0 and a
        patch of at least 2 pixels, a threshold from 0 to 254. The FAST
        threshold only has to reject 8-bit quantisation and image noise;
        which corners are kept is the Harris ranking's choice within
        ``n_features``. OpenCV's 20 levels, set for photographs of full
        contrast, left a dim road seen by a downward fisheye with a tenth
        of the budget, so the default is 7.
    akaze_threshold : float
        ``cv2.AKAZE_create`` detector response threshold (OpenCV's default,
        set for photographs of full contrast).
    akaze_min_keypoints : int
        When the sequence's first image gives fewer keypoints than this at
        ``akaze_threshold`` (a dim or low-contrast scene: the response scales
        with the squared image gradient, so a road or floor at a third of
        the contrast gives a ninth of it and often no keypoint at all), the
        threshold is lowered once, for the whole sequence, to the response of
        the first image's ``akaze_min_keypoints``-th strongest keypoint. The
        default is OpenCV's default ORB keypoint count (500); 0 keeps
        ``akaze_threshold`` whatever the images. Weak keypoints are located
        worse, so the threshold is lowered only where the default finds too
        few, not for every sequence.
    akaze_min_threshold : float
        The threshold is never lowered below this (> 0): below it the
        detector keeps the noise of a flat image. An ``akaze_threshold`` at
        or below it is kept as given.
    akaze_octaves, akaze_octave_layers : int
        AKAZE scale space size (at least 1 of each, at most 32 layers per octave).
    radius_band : (2,) tuple of float or None
        Override of the mirror band ``(inner, outer)`` radius in sensor
        pixels; ``None`` uses the iFMI front end's default band for the
        calibration and images. OCamCalib models only: other models detect
        in their panorama's band (:func:`ifmi.spectral.panorama.band_mask`).
    mask_margin_px : float
        Keypoints are detected only this far (pixels) inside the band's
        edges, so no descriptor window reaches the black border or the
        camera's own reflection, which stay fixed in the image whatever the
        motion; the default is half of ORB's 31-pixel descriptor patch.
    """

    n_features: int = 3000
    ratio: float = 0.8
    cross_check: bool = False
    on_panorama: bool = False
    min_matches: int = 8
    orb_scale_factor: float = 1.2
    orb_levels: int = 8
    orb_edge_threshold: int = 31
    orb_patch_size: int = 31
    orb_fast_threshold: int = 7
    akaze_threshold: float = 1e-3
    akaze_min_keypoints: int = ORB_DEFAULT_FEATURES
    akaze_min_threshold: float = 1e-5
    akaze_octaves: int = 4
    akaze_octave_layers: int = 4
    mask_margin_px: float = 16.0
    radius_band: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.radius_band is not None:
            band = tuple(float(v) for v in self.radius_band)
            if len(band) != 2 or not 0 <= band[0] < band[1]:
                raise ValueError(f"radius_band must be (inner, outer) with 0 <= inner < outer, "
                                 f"got {self.radius_band}")
            object.__setattr__(self, "radius_band", band)
        if not 0 < self.ratio <= 1:
            raise ValueError(f"ratio must be in (0, 1], got {self.ratio}")
        if self.n_features < 0:
            raise ValueError(f"n_features must be >= 0, got {self.n_features}")
        if self.min_matches < 5:
            raise ValueError(f"min_matches must be >= 5 (the 5-point solver), got {self.min_matches}")
        if self.mask_margin_px < 0:
            raise ValueError(f"mask_margin_px must be >= 0, got {self.mask_margin_px}")
        if self.akaze_min_keypoints < 0:
            raise ValueError(f"akaze_min_keypoints must be >= 0, got {self.akaze_min_keypoints}")
        if not self.akaze_min_threshold > 0:
            raise ValueError(f"akaze_min_threshold must be > 0, got {self.akaze_min_threshold}")
        if self.akaze_octave_layers > _MAX_AKAZE_LAYERS:
            raise ValueError(f"akaze_octave_layers must be at most {_MAX_AKAZE_LAYERS} (scale steps of "
                             f"2^(1/{_MAX_AKAZE_LAYERS}) per sublevel), got {self.akaze_octave_layers}")
        self._check_detector_sizes()

    def _check_detector_sizes(self) -> None:
        """The lower bounds ``cv2.ORB_create`` and ``cv2.AKAZE_create`` assert (their failure was an
        OpenCV traceback at the first image), and the FAST threshold's range of gray levels."""
        check_finite_fields(self, ("orb_scale_factor",))
        if not self.orb_scale_factor > 1:
            raise ValueError(f"orb_scale_factor must be > 1 (the pyramid's ratio), got {self.orb_scale_factor}")
        minimums = {"orb_levels": 1, "orb_edge_threshold": 0, "orb_patch_size": 2, "orb_fast_threshold": 0,
                    "akaze_octaves": 1, "akaze_octave_layers": 1}
        for name, minimum in minimums.items():
            if getattr(self, name) < minimum:
                raise ValueError(f"{name} must be >= {minimum}, got {getattr(self, name)}")
        if self.orb_fast_threshold > _MAX_FAST_THRESHOLD:
            raise ValueError(f"orb_fast_threshold must be at most {_MAX_FAST_THRESHOLD} gray levels (8-bit "
                             f"images differ by at most 255), got {self.orb_fast_threshold}")

    def to_dict(self) -> dict:
        return {f.name: (list(getattr(self, f.name)) if isinstance(getattr(self, f.name), tuple)
                         else getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "FeatureConfig":
        """Inverse of :meth:`to_dict`; missing keys take defaults, values are type-checked."""
        return options_from_dict(cls, data, what="features")


@dataclass(frozen=True)
class FeatureFrame:
    """Per-frame state of a feature front end.

    Attributes
    ----------
    pixels : (N, 2) ndarray
        Keypoint positions, omni-image ``(row, col)``.
    rays : (N, 3) ndarray
        Unit rays of ``pixels``.
    descriptors : (N, D) uint8 ndarray
        Binary descriptors (ORB: 32 bytes, AKAZE MLDB: 61 bytes).
    """

    pixels: np.ndarray
    rays: np.ndarray
    descriptors: np.ndarray

    def __len__(self) -> int:
        return len(self.pixels)


def create_detector(detector: str, config: FeatureConfig, *, akaze_threshold: float | None = None):
    """OpenCV ORB or AKAZE detector configured from ``config``.

    ``akaze_threshold``, when given, replaces ``config.akaze_threshold``.
    """
    if detector == "orb":
        return cv2.ORB_create(nfeatures=config.n_features or ORB_DEFAULT_FEATURES,
                              scaleFactor=config.orb_scale_factor, nlevels=config.orb_levels,
                              edgeThreshold=config.orb_edge_threshold,
                              patchSize=config.orb_patch_size,
                              fastThreshold=config.orb_fast_threshold)
    if detector == "akaze":
        threshold = config.akaze_threshold if akaze_threshold is None else akaze_threshold
        return cv2.AKAZE_create(threshold=threshold, nOctaves=config.akaze_octaves,
                                nOctaveLayers=config.akaze_octave_layers)
    raise ValueError(f"unknown detector {detector!r}; expected one of {DETECTORS}")


def match_descriptors(desc_a: np.ndarray, desc_b: np.ndarray, *, ratio: float,
                      cross_check: bool) -> np.ndarray:
    """Match binary descriptors by Hamming distance with a ratio test.

    Parameters
    ----------
    desc_a : (Na, D) uint8 ndarray
    desc_b : (Nb, D) uint8 ndarray
    ratio : float, keyword-only
        Keep a match whose distance is below ``ratio`` times the second-best.
    cross_check : bool, keyword-only
        Keep only matches that are also the best from ``desc_b``'s side.

    Returns
    -------
    (M, 2) ndarray of int
        Index pairs ``(i_a, i_b)``.
    """
    if len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    knn = matcher.knnMatch(desc_a, desc_b, k=2)
    pairs = [(m[0].queryIdx, m[0].trainIdx) for m in knn
             if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    out = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if cross_check and len(out):
        back = matcher.match(desc_b, desc_a)
        best_a_of_b = np.full(len(desc_b), -1, dtype=np.int64)
        for m in back:
            best_a_of_b[m.queryIdx] = m.trainIdx
        out = out[best_a_of_b[out[:, 1]] == out[:, 0]]
    return out


class FeatureFrontEnd:
    """ORB or AKAZE front end (see the module docstring).

    Parameters
    ----------
    model : OcamModel or ifmi.geometry.camera.CameraModel
        Calibration of the images; keypoints are lifted to rays through it.
    detector : {"orb", "akaze"}
    config : FeatureConfig, keyword-only
    panorama : ifmi.spectral.panorama.PanoramaConfig, optional, keyword-only
        Band detection and panorama geometry, shared with the iFMI front end
        so that every method sees the same part of the image.

    Attributes
    ----------
    detector_threshold : float or None
        AKAZE: the response threshold in use, ``config.akaze_threshold``
        until the first image settles it (``FeatureConfig.akaze_min_keypoints``);
        reported with every pair's diagnostics. ORB: ``None``.
    """

    def __init__(self, model: OcamModel, detector: str, *,
                 config: FeatureConfig = FeatureConfig(), panorama=None) -> None:
        from ifmi.spectral.panorama import PanoramaConfig

        if detector not in DETECTORS:
            raise ValueError(f"unknown detector {detector!r}; expected one of {DETECTORS}")
        self.model = model
        self.detector_name = detector
        self.config = config
        self.panorama_config = panorama if panorama is not None else PanoramaConfig()
        self._detector = create_detector(detector, config)
        # AKAZE's threshold is settled on the first image (see FeatureConfig.akaze_min_keypoints).
        self._threshold_settled = detector != "akaze" or config.akaze_min_keypoints == 0
        self.detector_threshold = config.akaze_threshold if detector == "akaze" else None
        self._mask: np.ndarray | None = None
        self._band: tuple[float, float] | None = config.radius_band
        self._mapping = None

    # -- mirror band ----------------------------------------------------------------------------
    def band(self, image: np.ndarray) -> tuple[float, float]:
        """``(inner, outer)`` sensor radius of the mirror band in pixels (fixed on first use).

        Detected from the first image with :func:`ifmi.spectral.panorama.radius_band`,
        unless ``config.radius_band`` sets it.
        """
        if self._band is None:
            from ifmi.spectral.panorama import radius_band

            self._band = tuple(float(v) for v in radius_band(self.model, image,
                                                             config=self.panorama_config))
        return self._band

    def mask(self, image: np.ndarray) -> np.ndarray:
        """``(H, W)`` uint8 detection mask (fixed on first use): 255 where keypoints are detected.

        OCamCalib models: the mirror band. Other models: the model's whole
        valid image, less the pixels that are black in ``image``; both
        ``config.mask_margin_px`` inside their edges.
        """
        if self._mask is None and not isinstance(self.model, OcamModel):
            # Other models: the whole valid image of the model less the pixels black in the first
            # image (outside the lens's image circle), eroded so that no descriptor window reaches them.
            from ifmi.spectral.panorama import gray_from_image

            self._mask = eroded_mask(valid_mask(self.model) & (gray_from_image(image) > 0),
                                      self.config.mask_margin_px)
        if self._mask is None:
            inner, outer = self.band(image)
            h, w = self.model.size
            rows, cols = np.mgrid[0:h, 0:w]
            r = radius_from_pixels(self.model, np.stack([rows, cols], axis=-1))
            margin = self.config.mask_margin_px
            self._mask = np.where((r >= inner + margin) & (r <= outer - margin),
                                  255, 0).astype(np.uint8)
        return self._mask

    # -- front-end protocol ---------------------------------------------------------------------
    def prepare(self, image: np.ndarray) -> FeatureFrame:
        """Detect keypoints and compute descriptors of one omni image.

        Parameters
        ----------
        image : (H, W) or (H, W, 3) uint8 ndarray
            Omni image of the calibration's size.

        Returns
        -------
        FeatureFrame
        """
        from ifmi.spectral.panorama import gray_from_image

        gray = gray_from_image(image)
        if gray.shape != tuple(self.model.size):
            raise ValueError(f"expected an image of {self.model.size} (rows, cols), got {gray.shape}")
        if gray.dtype != np.uint8:
            gray = np.clip(gray, 0, 255).astype(np.uint8)
        if self.config.on_panorama:
            pixels, descriptors = self._detect_on_panorama(gray)
        else:
            pixels, descriptors = self._detect(gray, self.mask(gray))
        rays = rays_from_pixels(self.model, pixels) if len(pixels) else np.zeros((0, 3))
        return FeatureFrame(pixels=pixels, rays=rays, descriptors=descriptors)

    def correspondences(self, state_a: FeatureFrame, state_b: FeatureFrame):
        """Match frame a's keypoints against frame b's.

        Returns
        -------
        ifmi.pipeline.Correspondences
            Flagged as failed when fewer than ``config.min_matches`` survive.
        """
        pairs = match_descriptors(state_a.descriptors, state_b.descriptors,
                                  ratio=self.config.ratio, cross_check=self.config.cross_check)
        diagnostics = {"n_keypoints_a": len(state_a), "n_keypoints_b": len(state_b),
                       "n_matches": int(len(pairs))}
        if self.detector_threshold is not None:
            diagnostics["detector_threshold"] = self.detector_threshold
        if len(pairs) < self.config.min_matches:
            return Correspondences.failed(
                f"too few matches ({len(pairs)} < {self.config.min_matches})", diagnostics)
        ia, ib = pairs[:, 0], pairs[:, 1]
        return Correspondences(pixels_a=state_a.pixels[ia], pixels_b=state_b.pixels[ib],
                               rays_a=state_a.rays[ia], rays_b=state_b.rays[ib],
                               diagnostics=diagnostics, success=True, reason="")

    # -- detection ------------------------------------------------------------------------------
    def _settle_threshold(self, gray: np.ndarray, mask: np.ndarray | None, found: int) -> bool:
        """Lower AKAZE's threshold for the sequence if the first image gave too few keypoints
        (``found`` at the configured threshold); True when the detector changed."""
        self._threshold_settled = True
        config = self.config
        if config.akaze_threshold <= config.akaze_min_threshold or found >= config.akaze_min_keypoints:
            return False
        low = create_detector("akaze", config, akaze_threshold=config.akaze_min_threshold)
        response = np.sort([kp.response for kp in low.detect(gray, mask)])[::-1]
        threshold = config.akaze_min_threshold
        if len(response) >= config.akaze_min_keypoints:
            threshold = max(threshold, float(response[config.akaze_min_keypoints - 1]))
        self.detector_threshold = threshold
        self._detector = create_detector("akaze", config, akaze_threshold=threshold)
        return True

    def _detect(self, gray: np.ndarray, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        keypoints, descriptors = self._detector.detectAndCompute(gray, mask)
        if not self._threshold_settled and self._settle_threshold(gray, mask, len(keypoints)):
            keypoints, descriptors = self._detector.detectAndCompute(gray, mask)
        if descriptors is None or not keypoints:
            return np.zeros((0, 2)), np.zeros((0, 32), dtype=np.uint8)
        xy = np.array([kp.pt for kp in keypoints], dtype=np.float64)
        if (self.detector_name == "akaze" and self.config.n_features
                and len(keypoints) > self.config.n_features):
            response = np.array([kp.response for kp in keypoints])
            keep = np.sort(np.argsort(-response, kind="stable")[: self.config.n_features])
            xy, descriptors = xy[keep], descriptors[keep]
        # OpenCV (x, y) = (col, row) -> (row, col).
        return xy[:, ::-1].copy(), descriptors

    def _detect_on_panorama(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from ifmi.spectral.panorama import omni_pixels_from_panorama_pixels, panorama_image_from_omni_image

        mapping = self._panorama_mapping(gray)
        panorama = np.clip(panorama_image_from_omni_image(mapping, gray) + 0.5, 0, 255).astype(np.uint8)
        pano_pixels, descriptors = self._detect(panorama, None)
        if not len(pano_pixels):
            return pano_pixels, descriptors
        return omni_pixels_from_panorama_pixels(mapping, pano_pixels), descriptors

    def _panorama_mapping(self, gray: np.ndarray):
        """The band's panorama (built on first use): OCamCalib from the radius band, others from the model."""
        from dataclasses import replace

        from ifmi.spectral.panorama import panorama_mapping

        if self._mapping is None:
            config = self.panorama_config
            if isinstance(self.model, OcamModel):
                inner, outer = self.band(gray)
                config = replace(config, radius_min_px=inner, radius_max_px=outer)
            self._mapping = panorama_mapping(self.model, gray, config=config)
        return self._mapping


def eroded_mask(mask: np.ndarray, margin_px: float) -> np.ndarray:
    """A detection mask: ``mask`` eroded by a disc of ``margin_px`` pixels, so that no descriptor
    window reaches its edge.

    Parameters
    ----------
    mask : (H, W) bool ndarray
        Pixels where keypoints may lie.
    margin_px : float
        Radius of the disc, pixels (rounded up; 0 keeps ``mask`` as it is).

    Returns
    -------
    (H, W) uint8 ndarray
        255 where a keypoint may lie, else 0 (the mask OpenCV's detectors take).
    """
    radius = int(np.ceil(margin_px))
    keep = mask.astype(np.uint8)
    if radius > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        keep = cv2.erode(keep, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return keep * 255


def _feature_config(config) -> FeatureConfig:
    """The feature options of an :class:`ifmi.pipeline.EstimateConfig` (``None``: defaults)."""
    return FeatureConfig() if config.features is None else config.features


def _panorama_config(config):
    """The iFMI panorama settings, which also give the feature front ends their band."""
    return config.ifmi.panorama


def orb_front_end(model: OcamModel, config) -> FeatureFrontEnd:
    """Registry factory: ORB front end from an :class:`ifmi.pipeline.EstimateConfig`.

    The mirror band comes from the same panorama settings as the iFMI front end's.
    """
    return FeatureFrontEnd(model, "orb", config=_feature_config(config),
                           panorama=_panorama_config(config))


def akaze_front_end(model: OcamModel, config) -> FeatureFrontEnd:
    """Registry factory: AKAZE front end from an :class:`ifmi.pipeline.EstimateConfig`.

    The mirror band comes from the same panorama settings as the iFMI front end's.
    """
    return FeatureFrontEnd(model, "akaze", config=_feature_config(config),
                           panorama=_panorama_config(config))
