"""Panorama from an omni image, with the exact pixel mapping both ways.

Instead of a plain polar unwarp around the image centre, the panorama samples
the camera's rays on a regular (elevation, azimuth) grid and projects them
with the calibration (``pixels_from_rays``):

* column ``j`` is the azimuth ``phi = 2 pi j / W`` of the ray about the
  mirror axis z (``phi = atan2(y, x)``, x along image rows);
* row ``i`` is the elevation ``theta = theta_top - i * theta_step`` of the
  ray above the x-y plane, row 0 the highest elevation of the band.

This handles a non-identity affine part and an off-centre distortion centre
exactly, and it makes the panorama an equirectangular image of the sphere
band: a rotation about z is an exact horizontal shift, and a small tilt moves
each small tile almost rigidly, unlike a plain polar unwarp whose radial
scale follows the mirror's distortion.

Pixel coordinates are ``(row, col)``, 0-based, pixel centres at integers, in
both the omni image and the panorama.

Other camera models (:mod:`ifmi.geometry.camera_models`: Kalibr fisheyes, pinhole,
equirectangular) are sampled the same way along their own rays: azimuth and
elevation are taken about the model's ``panorama_axis`` (its optical axis,
or up for an equirectangular camera), and the band of elevations follows
from the model's valid region and field of view instead of a radius band.
A fisheye looking along z sees elevations from ``90 deg - FOV/2`` (below the
horizon when the field of view exceeds 180 degrees) up to the band's inner
edge, at ``min_radius_fraction`` of the way out from the axis. See
:func:`off_axis_band`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Sequence

import cv2
import numpy as np

from ifmi.geometry.camera import (INVERSE_CHECK_INNER_FRACTION, OcamModel, angles_from_axis, angular_pixel_size,
                     elevation_from_radius, inverse_round_trip_error, pixel_offsets_from_sensor, pixels_from_rays,
                     pixels_from_sensor, rays_from_pixels)

__all__ = [
    "PanoramaConfig",
    "PanoramaMapping",
    "radius_band",
    "inverse_polynomial_error",
    "panorama_config_with_band",
    "off_axis_band",
    "lit_off_axis_band",
    "panorama_axis_rotation",
    "band_mask",
    "angular_pixel_size_in_band",
    "panorama_mapping",
    "panorama_shape",
    "panorama_image_from_omni_image",
    "rays_from_panorama_pixels",
    "omni_pixels_from_panorama_pixels",
    "panorama_pixels_from_omni_pixels",
    "panorama_pixels_from_rays",
    "gray_from_image",
    "denoised_gray_from_image",
    "PANORAMA_INTERPOLATIONS",
]

# Azimuths and radii of the coarse polar profile used to find the imaged band.
_PROFILE_AZIMUTHS = 256
_PROFILE_RADII = 256
# Aperture (pixels) of the median filter applied before the band is detected.
_NOISE_MEDIAN_PX = 5
# Brightest level of the 8-bit images the band is judged on.
_MAX_GRAY_LEVEL = 255
# OpenCV kernels the panorama can be resampled with, by name.
PANORAMA_INTERPOLATIONS = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC, "lanczos4": cv2.INTER_LANCZOS4}
# Off-axis angles and azimuths probed to find the band a general camera model images fully.
_BAND_ANGLES = 721
_BAND_AZIMUTHS = 360


@dataclass(frozen=True)
class PanoramaConfig:
    """Panorama geometry.

    Attributes
    ----------
    width : int or None
        Panorama width in pixels (360 degrees of azimuth). ``None``: the
        circumference of the band's middle radius in the omni image, which
        neither under- nor oversamples it (about 1024 for 512 x 512 images),
        rounded to a multiple of 64 and capped at ``max_auto_width``.
    max_auto_width : int
        Cap of the automatic width: larger images are downsampled, which
        keeps the time per frame bounded. 2048 keeps 1024 x 1024 images at
        their resolution (on sharp 1024 px images a 1024 px panorama had
        three times the frame-to-frame error).
    height : int or None
        Panorama height in pixels; ``None`` makes pixels square at the band's
        elevation closest to the horizon.
    radius_min_px, radius_max_px : float or None
        Sensor-radius band (pixels, after removing the affine part) to
        unwarp; ``None`` detects it (see :func:`radius_band`).
    min_radius_fraction : float
        Detected inner radius is at least this fraction of the outer radius,
        which keeps out the camera's own reflection and the strongly
        oversampled centre.
    dark_level : float
        Gray level (0..255) under which a pixel counts as outside the mirror.
    rim_lit_fraction : float
        A ring counts as dark (outside the mirror, or the camera's own
        reflection) when fewer than this fraction of its pixels are lit, in
        the median over the frames judged. Dark objects (clothing, shadows,
        the operator) cover part of a ring, rarely all of it; the rim and
        the central reflection cover all of it.
    min_band_fraction : float
        A detected band narrower than this fraction of the calibration's
        band is not trusted: the calibration's band is used, with a warning.
    margin_px : float
        Band shrink at both detected edges, pixels.
    """

    width: int | None = None
    height: int | None = None
    radius_min_px: float | None = None
    radius_max_px: float | None = None
    min_radius_fraction: float = 0.3
    dark_level: float = 12.0
    rim_lit_fraction: float = 0.1
    min_band_fraction: float = 0.25
    margin_px: float = 2.0
    max_auto_width: int = 2048

    def __post_init__(self) -> None:
        if (self.width is not None and self.width < 8) or (self.height is not None and self.height < 8) \
                or self.max_auto_width < 64:
            raise ValueError(f"panorama size must be >= 8 px (max_auto_width >= 64), got width={self.width}, "
                             f"height={self.height}, max_auto_width={self.max_auto_width}")
        lo, hi = self.radius_min_px, self.radius_max_px
        if (lo is not None and lo < 0) or (hi is not None and hi <= 0) or (
                lo is not None and hi is not None and lo >= hi):
            raise ValueError(f"expected 0 <= radius_min_px < radius_max_px, got {lo}, {hi}")
        if not 0 <= self.min_radius_fraction < 1:
            raise ValueError(f"min_radius_fraction must be in [0, 1), got {self.min_radius_fraction}")
        if not 0 < self.rim_lit_fraction < 1 or not 0 <= self.min_band_fraction < 1:
            raise ValueError("expected 0 < rim_lit_fraction < 1 and 0 <= min_band_fraction < 1, got "
                             f"{self.rim_lit_fraction}, {self.min_band_fraction}")
        if not 0 <= self.dark_level < _MAX_GRAY_LEVEL:
            raise ValueError(f"dark_level must be a gray level in [0, {_MAX_GRAY_LEVEL}), got {self.dark_level}")
        if not (0 <= self.margin_px and np.isfinite(self.margin_px)):
            raise ValueError(f"margin_px must be finite and >= 0, got {self.margin_px}")


@dataclass(frozen=True)
class PanoramaMapping:
    """Sampling grid of a panorama.

    Attributes
    ----------
    model : OcamModel
    width, height : int
        Panorama size in pixels.
    elevation_top_rad : float
        Elevation of row 0, radians.
    elevation_step_rad : float
        Elevation decrease per row, radians (> 0).
    radius_band_px : (float, float)
        Sensor radii of the band's inner and outer edge, pixels (OCamCalib
        models; NaN for other models, whose band is ``off_axis_band_rad``).
    map_rows, map_cols : (height, width) float32 ndarray
        Omni-image ``(row, col)`` sampled by each panorama pixel (remap maps).
    fixed_maps : tuple of ndarray
        The same maps in OpenCV's fixed-point form (faster remapping).
    camera_from_panorama : (3, 3) ndarray or None
        Rotation from the panorama's frame (z the azimuth axis) to the
        camera frame; None is the identity (OCamCalib: the mirror axis z).
    """

    model: OcamModel
    width: int
    height: int
    elevation_top_rad: float
    elevation_step_rad: float
    radius_band_px: tuple
    map_rows: np.ndarray
    map_cols: np.ndarray
    fixed_maps: tuple = ()
    camera_from_panorama: np.ndarray | None = None


def gray_from_image(image: np.ndarray) -> np.ndarray:
    """Gray uint8/float image of an (H, W) gray or (H, W, 3) RGB image (ITU-R 601 luma)."""
    image = np.asarray(image)
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    if image.ndim == 3 and image.shape[2] == 1:
        return image[..., 0]
    raise ValueError(f"expected an image of shape (H, W) or (H, W, 3), got {image.shape}")


def denoised_gray_from_image(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 gray of ``image`` ((H, W) or (H, W, 3)) after a median filter: what pixels are
    judged lit or dark on (the mirror band, the mirror rim).

    Median filtering removes isolated noisy pixels (sensor noise in the black regions, JPEG
    ringing) before rings are judged; the band's edges move by less than a pixel.
    """
    return cv2.medianBlur(np.clip(gray_from_image(image), 0, _MAX_GRAY_LEVEL).astype(np.uint8), _NOISE_MEDIAN_PX)


def _inscribed_radius(model: OcamModel) -> float:
    """Largest sensor radius whose whole circle lies inside the image."""
    phi = np.linspace(0.0, 2 * np.pi, 1440, endpoint=False)
    offsets = pixel_offsets_from_sensor(model, np.stack([np.cos(phi), np.sin(phi)], axis=-1))
    drow, dcol = offsets[:, 0], offsets[:, 1]
    radii = []
    for delta, centre, size in ((drow, model.center[0], model.height), (dcol, model.center[1], model.width)):
        with np.errstate(divide="ignore"):
            upper = np.where(delta > 0, (size - 1 - centre) / delta, np.inf)
            lower = np.where(delta < 0, (0 - centre) / delta, np.inf)
        radii.append(np.minimum(upper, lower))
    return float(max(0.0, np.min(np.minimum(*radii))))


def _monotonic_radius(model: OcamModel, limit: float) -> float:
    """Largest radius <= limit up to which elevation grows with radius."""
    r = np.linspace(0.0, limit, 2048)
    theta = elevation_from_radius(np.asarray(model.pol), r)
    grows = np.diff(theta) > 0
    if grows.all():
        return limit
    return float(r[int(np.argmin(grows))])


def _ring_maps(model: OcamModel, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Remap maps ``(cols, rows)`` float32 of ``_PROFILE_AZIMUTHS`` points on each sensor ring of ``radii``."""
    phi = np.linspace(0.0, 2 * np.pi, _PROFILE_AZIMUTHS, endpoint=False)
    sensor = np.stack([radii[:, None] * np.cos(phi)[None], radii[:, None] * np.sin(phi)[None]], axis=-1)
    pixels = pixels_from_sensor(model, sensor).astype(np.float32)
    return np.ascontiguousarray(pixels[..., 1]), np.ascontiguousarray(pixels[..., 0])


def _ring_lit_fractions(ring_maps: tuple[np.ndarray, np.ndarray], image: np.ndarray,
                        dark_level: float) -> np.ndarray:
    """Fraction of each ring's pixels (:func:`_ring_maps`) brighter than ``dark_level`` (median-filtered image)."""
    gray = denoised_gray_from_image(image).astype(np.float32)
    ring = cv2.remap(gray, *ring_maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    return (ring > dark_level).mean(axis=1)


def radius_band(model: OcamModel, image: np.ndarray | None = None, *,
                config: PanoramaConfig = PanoramaConfig(), frames: Sequence[np.ndarray] = ()) -> tuple[float, float]:
    """Sensor-radius band ``(r_min, r_max)`` in pixels that the mirror images.

    The calibration's band runs from ``config.min_radius_fraction`` of the
    outer radius to the largest circle inside the image (and inside the
    calibration's monotonic range). With images (``image`` and/or
    ``frames``), the outer radius shrinks to the last lit ring (black
    outside the mirror) and the inner radius grows past a dark central disk
    (the camera's reflection). A ring is dark when fewer than
    ``config.rim_lit_fraction`` of its pixels are brighter than
    ``config.dark_level``, in the median over the frames; so a dark object
    crossing the ring, or a dark-clothed operator filling part of it, does
    not end the band. Rings are judged on median-filtered images, so noisy
    pixels in the black regions do not count as lit. A detected band
    narrower than ``config.min_band_fraction`` of the calibration's falls
    back to the calibration's band with a warning. Explicit radii in
    ``config`` override the detection.

    Parameters
    ----------
    model : OcamModel
    image : (H, W) or (H, W, 3) ndarray, optional
    config : PanoramaConfig, keyword-only
    frames : sequence of (H, W) or (H, W, 3) ndarray, keyword-only
        More frames of the sequence to judge the rings on.

    Returns
    -------
    (float, float)
        Inner and outer sensor radius, pixels.
    """
    if config.radius_min_px is not None and config.radius_max_px is not None:
        # Both radii given: nothing to detect or derive.
        return _checked_band(float(config.radius_min_px), float(config.radius_max_px))
    outer = _monotonic_radius(model, _inscribed_radius(model))
    calib_inner = config.min_radius_fraction * outer
    inner = 0.0
    images = ([] if image is None else [image]) + list(frames)
    if images:
        radii = np.linspace(0.0, outer, _PROFILE_RADII)
        ring_maps = _ring_maps(model, radii)
        lit_fraction = np.median([_ring_lit_fractions(ring_maps, im, config.dark_level) for im in images],
                                 axis=0)
        detected = _band_from_lit_rings(lit_fraction >= config.rim_lit_fraction, radii, config.margin_px)
        if detected is None or detected[1] - max(detected[0], calib_inner) < \
                config.min_band_fraction * (outer - calib_inner):
            warnings.warn(f"no clear mirror band in the image (detected {detected}); using the "
                          f"calibration's band {calib_inner:.1f}..{outer:.1f} px", stacklevel=2)
        else:
            inner, outer = detected[0], min(outer, detected[1])
    inner = max(inner, config.min_radius_fraction * outer)
    if config.radius_min_px is not None:
        inner = float(config.radius_min_px)
    if config.radius_max_px is not None:
        outer = float(config.radius_max_px)
    return _checked_band(inner, outer)


def inverse_polynomial_error(model: OcamModel) -> tuple[float, float]:
    """Largest round-trip error of the inverse polynomial over the image band.

    For sensor radii ``r`` across the band the direct polynomial gives the
    ray elevation ``theta(r)``; the inverse polynomial should give back
    ``invpol(theta(r)) = r``. The band runs from a tenth of the outer radius
    to the largest circle inside the image within the range where
    ``theta`` grows with ``r`` (where an inverse exists).

    Returns
    -------
    error_px : float
        ``max |invpol(theta(r)) - r|``, sensor pixels (image pixels up to
        the affine part, which is close to the identity).
    radius_px : float
        The radius where it occurs.

    Raises
    ------
    ValueError
        The model images no band (``theta`` does not grow from the centre).
    """
    inner, outer = radius_band(model, config=PanoramaConfig(min_radius_fraction=INVERSE_CHECK_INNER_FRACTION))
    return inverse_round_trip_error(model, inner, outer)


def _checked_band(inner: float, outer: float) -> tuple[float, float]:
    if not 0 <= inner < outer:
        raise ValueError(f"empty radius band: inner {inner:.1f} px >= outer {outer:.1f} px")
    return inner, outer


def band_needs_frames(model, *, config: PanoramaConfig) -> bool:
    """Whether :func:`panorama_config_with_band` would look at frames for ``model`` and ``config``.

    Only an OCamCalib model's band is detected in the images, and only the
    radii ``config`` leaves open (None); other models' bands follow from
    the model (:func:`off_axis_band`). Callers use it to skip reading frames.
    """
    open_radius = config.radius_min_px is None or config.radius_max_px is None
    return open_radius and isinstance(model, OcamModel)


def panorama_config_with_band(model: OcamModel, frames: Sequence[np.ndarray], *,
                              config: PanoramaConfig = PanoramaConfig()) -> PanoramaConfig:
    """``config`` with the radius band decided from several frames of a sequence.

    The band is :func:`radius_band` of all ``frames`` (rings judged on the
    median over the frames, calibration's band as fallback), written into
    ``radius_min_px`` and ``radius_max_px`` so that every method of a run
    uses it and it is saved with the run's configuration. Radii the
    configuration already fixes are kept; without frames ``config`` is
    returned unchanged.

    Parameters
    ----------
    model : OcamModel or CameraModel
        Other models than OCamCalib get ``config`` back unchanged: their
        band comes from their valid region (:func:`off_axis_band`).
    frames : sequence of (H, W) or (H, W, 3) ndarray
        A few frames spread over the sequence.
    config : PanoramaConfig, keyword-only

    Returns
    -------
    PanoramaConfig
    """
    if not len(frames) or not band_needs_frames(model, config=config):
        return config
    inner, outer = radius_band(model, frames[0], config=config, frames=frames[1:])
    return replace(config, radius_min_px=inner if config.radius_min_px is None else config.radius_min_px,
                   radius_max_px=outer if config.radius_max_px is None else config.radius_max_px)


def _band_from_lit_rings(lit: np.ndarray, radii: np.ndarray, margin: float) -> tuple[float, float] | None:
    """Inner and outer radius of the lit rings connected to the first one, or None if none is lit."""
    if not lit.any():
        return None
    first = int(np.argmax(lit))
    last = int(len(lit) - 1 - np.argmax(lit[::-1]))
    # The inner edge is the end of the dark disk around the centre, the outer edge the last
    # lit ring that is connected to it.
    dark_after = np.flatnonzero(~lit[first:])
    if dark_after.size:
        last = min(last, first + int(dark_after[0]) - 1)
    inner = float(radii[first]) + margin if first > 0 else 0.0
    outer = float(radii[last]) - margin if last < len(lit) - 1 else float(radii[-1])
    return inner, outer


def _ocam_panorama_grid(model: OcamModel, image: np.ndarray | None, config: PanoramaConfig) -> tuple:
    """``((inner, outer), (theta_lo, theta_hi), (width, height))`` of an OCamCalib panorama: its radius
    band (pixels), the elevations of the band's edges (radians) and its size (pixels)."""
    inner, outer = radius_band(model, image, config=config)
    pol = np.asarray(model.pol)
    theta_lo, theta_hi = (float(v) for v in elevation_from_radius(pol, np.array([inner, outer])))
    if theta_hi < theta_lo:
        theta_lo, theta_hi = theta_hi, theta_lo
    # Sensor radius ~ image pixels (the affine part is close to the identity).
    width, height = _panorama_size(config, np.pi * (inner + outer), theta_lo, theta_hi)
    return (inner, outer), (theta_lo, theta_hi), (width, height)


def panorama_shape(model, *, config: PanoramaConfig = PanoramaConfig()) -> tuple[int, int]:
    """``(height, width)`` of the panorama :func:`panorama_mapping` builds for ``model`` without an image,
    in pixels; for an OCamCalib model without building its remap maps.

    Parameters
    ----------
    model : OcamModel or another camera model (:mod:`ifmi.geometry.camera_models`)
    config : PanoramaConfig, keyword-only

    Returns
    -------
    (int, int)
    """
    if not isinstance(model, OcamModel):
        mapping = _model_panorama_mapping(model, config)
        return mapping.height, mapping.width
    width, height = _ocam_panorama_grid(model, None, config)[2]
    return height, width


def panorama_mapping(model: OcamModel, image: np.ndarray | None = None, *,
                     config: PanoramaConfig = PanoramaConfig()) -> PanoramaMapping:
    """Build the panorama's sampling grid (remap maps) for ``model``.

    Parameters
    ----------
    model : OcamModel
    image : (H, W) or (H, W, 3) ndarray, optional
        A frame used to detect the imaged radius band.
    config : PanoramaConfig, keyword-only

    Returns
    -------
    PanoramaMapping
    """
    if not isinstance(model, OcamModel):
        return _model_panorama_mapping(model, config)
    (inner, outer), (theta_lo, theta_hi), (width, height) = _ocam_panorama_grid(model, image, config)
    # Row centres at integers: row 0 at theta_hi, row height-1 at theta_lo.
    step = (theta_hi - theta_lo) / max(height - 1, 1)
    rows = np.arange(height)
    cols = np.arange(width)
    theta = theta_hi - rows * step
    phi = cols * (2 * np.pi / width)
    # world2cam of the grid's rays (cos(theta) cos(phi), cos(theta) sin(phi), sin(theta)):
    # every ray of a row has elevation theta and so one sensor radius rho = invpol(theta),
    # and its sensor point is rho (cos(phi), sin(phi)); this is pixels_from_rays, separated.
    rho = np.polynomial.polynomial.polyval(theta, model.invpol)
    sensor = np.stack([rho[:, None] * np.cos(phi)[None], rho[:, None] * np.sin(phi)[None]], axis=-1)
    pixels = pixels_from_sensor(model, sensor).astype(np.float32)
    map_rows, map_cols = np.ascontiguousarray(pixels[..., 0]), np.ascontiguousarray(pixels[..., 1])
    return PanoramaMapping(
        model=model, width=width, height=height, elevation_top_rad=theta_hi,
        elevation_step_rad=step, radius_band_px=(inner, outer), map_rows=map_rows,
        map_cols=map_cols, fixed_maps=cv2.convertMaps(map_cols, map_rows, cv2.CV_16SC2))


def panorama_image_from_omni_image(mapping: PanoramaMapping, image: np.ndarray, *,
                                   interpolation: str = "linear") -> np.ndarray:
    """Resample an omni image into the panorama (float32).

    The kernel matters on sharp images: bilinear interpolation at a
    fractional position ``t`` shifts a texture of frequency ``w`` by
    ``atan2(t sin w, 1 - t + t cos w) / w - t`` pixels (0.045 px at
    ``w = pi/2``, ``t = 1/4``), a shift fixed in the omni image that moving
    content picks up differently in every frame; the 8x8 Lanczos kernel
    keeps it far smaller at about eight times the cost.

    Parameters
    ----------
    mapping : PanoramaMapping
    image : (H, W) or (H, W, 3) ndarray
        Omni image of the size the mapping's calibration names; RGB is
        converted to gray.
    interpolation : {"linear", "cubic", "lanczos4"}, keyword-only
        OpenCV kernel (:data:`PANORAMA_INTERPOLATIONS`); default bilinear.

    Returns
    -------
    (height, width) float32 ndarray
    """
    if not isinstance(mapping, PanoramaMapping):
        raise TypeError(f"expected a PanoramaMapping as the first argument, got {type(mapping).__name__}")
    if interpolation not in PANORAMA_INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {sorted(PANORAMA_INTERPOLATIONS)}, got {interpolation!r}")
    gray = gray_from_image(image)
    if gray.shape != mapping.model.size:
        raise ValueError(f"expected an image of size {mapping.model.size}, got {gray.shape}")
    if gray.dtype != np.uint8:
        gray = gray.astype(np.float32, copy=False)
    map1, map2 = mapping.fixed_maps or (mapping.map_cols, mapping.map_rows)
    if getattr(mapping.model, "wraps_columns", False):
        gray, map1 = _wrapped_seam(gray, map1)
    pano = cv2.remap(gray, map1, map2, PANORAMA_INTERPOLATIONS[interpolation], borderMode=cv2.BORDER_REPLICATE)
    return pano.astype(np.float32, copy=False)


def _wrapped_seam(gray: np.ndarray, map1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A 360-degree image with its last column before the first and its first after the last, and ``map1`` shifted.

    Samples within half a pixel of the seam (columns in ``[-0.5, 0)`` or
    ``(W - 1, W - 0.5]``) then interpolate across it instead of repeating the
    edge column. ``map1`` is a float column map or OpenCV's fixed-point
    ``(col, row)`` integer pairs: either way the columns move by one.
    """
    padded = cv2.copyMakeBorder(gray, 0, 0, 1, 1, cv2.BORDER_WRAP)
    if map1.ndim == 3:  # fixed-point maps: integer (col, row) pairs, the fraction is in map2
        shifted = map1.copy()
        shifted[..., 0] += 1
        return padded, shifted
    return padded, map1 + np.float32(1.0)


def rays_from_panorama_pixels(mapping: PanoramaMapping, pano_pixels: np.ndarray) -> np.ndarray:
    """Unit rays of panorama pixels (exact; columns wrap around 360 degrees).

    Parameters
    ----------
    mapping : PanoramaMapping
    pano_pixels : (..., 2) array_like
        Panorama ``(row, col)``, sub-pixel allowed.

    Returns
    -------
    (..., 3) ndarray
    """
    pano_pixels = np.asarray(pano_pixels, dtype=np.float64)
    theta = mapping.elevation_top_rad - pano_pixels[..., 0] * mapping.elevation_step_rad
    phi = pano_pixels[..., 1] * (2 * np.pi / mapping.width)
    ct = np.cos(theta)
    rays = np.empty(theta.shape + (3,))
    np.multiply(ct, np.cos(phi), out=rays[..., 0])
    np.multiply(ct, np.sin(phi), out=rays[..., 1])
    rays[..., 2] = np.sin(theta)
    if mapping.camera_from_panorama is not None:
        rays = rays @ mapping.camera_from_panorama.T
    return rays


def panorama_pixels_from_rays(mapping: PanoramaMapping, rays: np.ndarray) -> np.ndarray:
    """Panorama ``(row, col)`` of rays; columns in ``[0, width)``.

    Parameters
    ----------
    mapping : PanoramaMapping
    rays : (..., 3) array_like
        Directions in the camera frame (need not be normalised).

    Returns
    -------
    (..., 2) ndarray
        Rows outside ``[0, height - 1]`` are outside the band.
    """
    rays = np.asarray(rays, dtype=np.float64)
    if mapping.camera_from_panorama is not None:
        rays = rays @ mapping.camera_from_panorama
    theta = np.arctan2(rays[..., 2], np.hypot(rays[..., 0], rays[..., 1]))
    phi = np.mod(np.arctan2(rays[..., 1], rays[..., 0]), 2 * np.pi)
    row = (mapping.elevation_top_rad - theta) / mapping.elevation_step_rad
    col = np.mod(phi * mapping.width / (2 * np.pi), mapping.width)
    return np.stack([row, col], axis=-1)


def omni_pixels_from_panorama_pixels(mapping: PanoramaMapping, pano_pixels: np.ndarray) -> np.ndarray:
    """Omni-image ``(row, col)`` of panorama ``(row, col)`` (sub-pixel, exact).

    Parameters
    ----------
    mapping : PanoramaMapping
    pano_pixels : (..., 2) array_like

    Returns
    -------
    (..., 2) ndarray
    """
    return pixels_from_rays(mapping.model, rays_from_panorama_pixels(mapping, pano_pixels))


def panorama_pixels_from_omni_pixels(mapping: PanoramaMapping, omni_pixels: np.ndarray) -> np.ndarray:
    """Panorama ``(row, col)`` of omni-image ``(row, col)``; columns in ``[0, width)``.

    Parameters
    ----------
    mapping : PanoramaMapping
    omni_pixels : (..., 2) array_like

    Returns
    -------
    (..., 2) ndarray
        Rows outside ``[0, height - 1]`` are outside the band.
    """
    return panorama_pixels_from_rays(mapping, rays_from_pixels(mapping.model, omni_pixels))


def panorama_axis_rotation(model) -> np.ndarray:
    """Rotation (3, 3) from a panorama frame whose z is ``model``'s panorama axis to the camera frame.

    The axis is ``model.panorama_axis`` when the model names one (up for an
    equirectangular camera), else its ``optical_axis``. Columns of the
    result are the panorama frame's x, y, z in camera coordinates; for an
    axis along +z it is the identity, for -z a half turn about x.
    """
    axis = np.asarray(getattr(model, "panorama_axis", model.optical_axis), dtype=np.float64)
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = helper - z * (helper @ z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _circle_pixels(model, rotation: np.ndarray, angles: np.ndarray, azimuths: np.ndarray) -> np.ndarray:
    """Pixels ``(A, Z, 2)`` of the rays at off-axis ``angles`` (A,) and ``azimuths`` (Z,) about the axis."""
    sa, ca = np.sin(angles)[:, None], np.cos(angles)[:, None]
    local = np.stack([sa * np.cos(azimuths)[None], sa * np.sin(azimuths)[None],
                      np.broadcast_to(ca, (len(angles), len(azimuths)))], axis=-1)
    return model.pixels_from_rays(local @ rotation.T)


def _probed_rings(model, margin_px: float, *, columns_wrap: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rings of rays about ``model``'s panorama axis at off-axis angles from 0 to pi, as pixels.

    Returns
    -------
    angles : (A,) ndarray
        Off-axis angle of each ring, radians.
    pixels : (A, Z, 2) ndarray
        ``(row, col)`` of each ring's rays (NaN where the model cannot image one).
    ok : (A, Z) bool ndarray
        The pixel is valid and at least ``margin_px`` inside the image (pixel
        edges at -0.5 and size - 0.5); with ``columns_wrap`` the left and
        right edges are no border.
    """
    angles = np.linspace(0.0, np.pi, _BAND_ANGLES)
    azimuths = np.linspace(0.0, 2 * np.pi, _BAND_AZIMUTHS, endpoint=False)
    pixels = _circle_pixels(model, panorama_axis_rotation(model), angles, azimuths)
    m = margin_px
    m_col = -0.5 if columns_wrap else m
    with np.errstate(invalid="ignore"):
        ok = ((pixels[..., 0] >= m - 0.5) & (pixels[..., 0] <= model.height - 0.5 - m)
              & (pixels[..., 1] >= m_col - 0.5) & (pixels[..., 1] <= model.width - 0.5 - m_col))
    ok[ok] = model.valid_pixels(pixels[ok])
    return angles, pixels, ok


def off_axis_band(model, *, config: PanoramaConfig = PanoramaConfig()) -> tuple[float, float]:
    """Off-axis angles ``(inner, outer)`` (radians) of the band a non-OCamCalib model images fully.

    Rings of rays at a fixed angle from the panorama axis are probed from 0
    to pi; a ring counts when every ray of it projects to a valid pixel at
    least ``config.margin_px`` inside the image. The band is the longest run
    of such rings, trimmed so that its inner edge is at least
    ``config.min_radius_fraction`` of a right angle (nor of the run's
    extent) from the axis and its outer edge as far from the opposite pole:
    near either pole a panorama row would oversample a tiny circle. For a
    fisheye along z the outer edge is half its field of view (less than
    90 degrees below 180 degrees of view, more above it).

    Returns
    -------
    (float, float)
        Inner and outer angle from the axis, radians.
    """
    if config.radius_min_px is not None or config.radius_max_px is not None:
        raise ValueError("radius_min_px / radius_max_px apply to OCamCalib models only")
    # Columns of a 360-degree image wrap around, so its left and right edges are no border.
    angles, _, ok = _probed_rings(model, config.margin_px,
                                  columns_wrap=getattr(model, "wraps_columns", False))
    ring_ok = ok.all(axis=1)
    if not ring_ok.any():
        raise ValueError("the camera model images no full ring of rays about its axis")
    # Longest run of consecutive good rings.
    edges = np.diff(np.concatenate([[0], ring_ok.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    best = int(np.argmax(stops - starts))
    first, last = float(angles[starts[best]]), float(angles[stops[best]])
    pole_gap = config.min_radius_fraction * min(last, 0.5 * np.pi)
    inner = max(first, pole_gap)
    outer = min(last, np.pi - pole_gap)
    if not inner < outer:
        raise ValueError(f"empty band: inner {np.degrees(inner):.1f} deg >= outer {np.degrees(outer):.1f} deg")
    return inner, outer


def lit_off_axis_band(model, image: np.ndarray, *, margin_rad: float = 0.0,
                      config: PanoramaConfig = PanoramaConfig()) -> tuple[float, float]:
    """Off-axis angles ``(inner, outer)`` (radians) of the lit rings of an image of a non-OCamCalib model.

    The image counterpart of :func:`radius_band` for the models of
    :mod:`ifmi.geometry.camera_models`: rings of rays at a fixed angle from the
    panorama axis (:func:`panorama_axis_rotation`) are probed from 0 to pi,
    each on the pixels of it that lie inside the image and the model's
    valid region. A ring is lit when at least ``config.rim_lit_fraction``
    of those pixels are brighter than ``config.dark_level`` (median-filtered
    image, as for :func:`radius_band`). The band runs over the lit rings
    connected to the first lit one, so a fisheye's black surround beyond its
    image circle, which the model's valid region may include, is left out.

    Parameters
    ----------
    model : CameraModel
        Not an :class:`~ifmi.geometry.camera.OcamModel` (use :func:`radius_band`).
    image : (H, W) or (H, W, 3) ndarray
    margin_rad : float, keyword-only
        Taken off each edge of the band that is not the axis or its opposite
        pole, radians.
    config : PanoramaConfig, keyword-only

    Returns
    -------
    (float, float)

    Raises
    ------
    ValueError
        An OCamCalib model, or no lit ring in the image.
    """
    if isinstance(model, OcamModel):
        raise ValueError("expected a non-OCamCalib camera model, got an OcamModel (use radius_band)")
    # Points between the outermost pixel centres (margin 0.5 px), where the remap reads the image.
    angles, pixels, usable = _probed_rings(model, 0.5, columns_wrap=False)
    # Unusable points are sampled outside the image (black) and left out of the share.
    maps = np.where(usable[..., None], pixels, -1.0).astype(np.float32)
    lit = _ring_lit_fractions((np.ascontiguousarray(maps[..., 1]), np.ascontiguousarray(maps[..., 0])),
                              image, config.dark_level)
    count = usable.sum(axis=1)
    share = np.divide(lit * usable.shape[1], count, out=np.zeros(len(count)), where=count > 0)
    band = _band_from_lit_rings((share >= config.rim_lit_fraction) & (count > 0), angles, margin_rad)
    if band is None or not band[0] < band[1]:
        raise ValueError(f"no lit ring of rays about the camera's axis in the image (band {band})")
    return band


def _panorama_size(config: PanoramaConfig, circumference: float, theta_lo: float,
                   theta_hi: float) -> tuple[int, int]:
    if config.width is None:
        width = int(min(config.max_auto_width, max(64, 64 * round(circumference / 64))))
    else:
        width = int(config.width)
    if config.height is None:
        closest = 0.0 if theta_lo <= 0 <= theta_hi else min(abs(theta_lo), abs(theta_hi))
        height = int(round(width * (theta_hi - theta_lo) / (2 * np.pi * np.cos(closest))))
        height = max(8, min(height, width))
    else:
        height = int(config.height)
    return width, height


def _model_panorama_mapping(model, config: PanoramaConfig) -> PanoramaMapping:
    """Panorama grid of a non-OCamCalib model along its own rays (see :func:`off_axis_band`)."""
    inner, outer = off_axis_band(model, config=config)
    rotation = panorama_axis_rotation(model)
    # Image circumference of the band's middle ring sets the automatic width.
    ring = _circle_pixels(model, rotation, np.array([0.5 * (inner + outer)]),
                          np.linspace(0.0, 2 * np.pi, _BAND_AZIMUTHS + 1))[0]
    circumference = float(np.sum(np.hypot(*np.diff(ring, axis=0).T)))
    theta_lo, theta_hi = 0.5 * np.pi - outer, 0.5 * np.pi - inner
    width, height = _panorama_size(config, circumference, theta_lo, theta_hi)
    step = (theta_hi - theta_lo) / max(height - 1, 1)
    mapping = PanoramaMapping(
        model=model, width=width, height=height, elevation_top_rad=theta_hi, elevation_step_rad=step,
        radius_band_px=(float("nan"), float("nan")), map_rows=np.zeros((0, 0), np.float32),
        map_cols=np.zeros((0, 0), np.float32), camera_from_panorama=rotation)
    rows, cols = np.mgrid[0:height, 0:width]
    pixels = pixels_from_rays(model, rays_from_panorama_pixels(mapping, np.stack([rows, cols], axis=-1)))
    pixels = np.nan_to_num(pixels, nan=-1.0).astype(np.float32)
    map_rows, map_cols = np.ascontiguousarray(pixels[..., 0]), np.ascontiguousarray(pixels[..., 1])
    return replace(mapping, map_rows=map_rows, map_cols=map_cols,
                   fixed_maps=cv2.convertMaps(map_cols, map_rows, cv2.CV_16SC2))


def band_mask(mapping: PanoramaMapping, *, margin_px: float = 0.0) -> np.ndarray:
    """``(H, W)`` bool mask of the omni-image pixels (rows, cols) whose rays lie in the panorama's band.

    Pixels outside the model's valid region are excluded; the mask is
    eroded by ``margin_px`` pixels (a disc), so that a descriptor window
    around a kept pixel stays inside the band.
    """
    model = mapping.model
    rows, cols = np.mgrid[0:model.height, 0:model.width]
    pixels = np.stack([rows, cols], axis=-1).astype(np.float64)
    axis = np.array([0.0, 0.0, 1.0]) if mapping.camera_from_panorama is None \
        else mapping.camera_from_panorama[:, 2]
    theta = 0.5 * np.pi - angles_from_axis(rays_from_pixels(model, pixels), axis)
    bottom = mapping.elevation_top_rad - (mapping.height - 1) * mapping.elevation_step_rad
    with np.errstate(invalid="ignore"):
        mask = (theta <= mapping.elevation_top_rad) & (theta >= bottom) & model.valid_pixels(pixels)
    radius = int(np.ceil(margin_px))
    if radius > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        mask = cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
    return mask


# Panorama points (per axis) at which the pixel angle of a general model is measured.
_PIXEL_ANGLE_SAMPLES = 16
# OCamCalib models: sensor radii across the band, and azimuths on each radius's circle.
_PIXEL_SIZE_RADII = 64
_PIXEL_SIZE_AZIMUTHS = 8


def angular_pixel_size_in_band(model, *, config: PanoramaConfig = PanoramaConfig(),
                               band: tuple[float, float] | None = None) -> float:
    """Angle (radians) one image pixel subtends in the panorama band of a camera model.

    :func:`ifmi.geometry.camera.angular_pixel_size` is measured at sample points of
    the band. For an OCamCalib model they lie on the calibration's circles at
    sensor radii evenly spread over the band (through the affine part), and
    the result is the median over the radii of each circle's median; for
    other models they form a grid over the band (:func:`panorama_mapping` of
    the model alone) and the result is their median.

    Parameters
    ----------
    model : OcamModel or CameraModel
    config : PanoramaConfig, keyword-only
        Band settings (explicit radii, minimum inner fraction) of the default band.
    band : (float, float), optional, keyword-only
        OCamCalib only: ``(inner, outer)`` sensor radius in pixels; default
        :func:`radius_band` of the calibration alone.

    Returns
    -------
    float
    """
    if not isinstance(model, OcamModel):
        mapping = panorama_mapping(model, config=config)
        rows = np.linspace(0, mapping.height - 1, _PIXEL_ANGLE_SAMPLES).astype(int)
        cols = np.linspace(0, mapping.width - 1, _PIXEL_ANGLE_SAMPLES, endpoint=False).astype(int)
        base = np.stack([mapping.map_rows[np.ix_(rows, cols)], mapping.map_cols[np.ix_(rows, cols)]],
                        axis=-1).reshape(-1, 2).astype(np.float64)
        return float(np.nanmedian(angular_pixel_size(model, base)))
    if band is None:
        band = radius_band(model, config=config)
    inner, outer = (float(v) for v in band)
    if not 0 <= inner < outer:
        raise ValueError(f"expected a band 0 <= inner < outer, got {band}")
    radii = np.linspace(max(inner, 1.0), outer, _PIXEL_SIZE_RADII)
    angles = np.linspace(0.0, 2.0 * np.pi, _PIXEL_SIZE_AZIMUTHS, endpoint=False)
    sensor = np.stack([radii[:, None] * np.cos(angles)[None], radii[:, None] * np.sin(angles)[None]], axis=-1)
    per_radius = np.median(angular_pixel_size(model, pixels_from_sensor(model, sensor)), axis=1)
    return float(np.median(per_radius))
