"""Camera-model protocol, and the OCamCalib (Scaramuzza) omnidirectional model.

Every camera model of the project (this OCamCalib model and the Kalibr and
equirectangular models of :mod:`ifmi.geometry.camera_models`) is a frozen object with

* ``size`` ``(height, width)``, ``height``, ``width``;
* ``rays_from_pixels(pixels)``: ``(..., 2)`` ``(row, col)`` -> ``(..., 3)``
  unit rays in the model's own camera frame (NaN outside its domain);
* ``pixels_from_rays(rays)``: ``(..., 3)`` -> ``(..., 2)`` ``(row, col)``
  (NaN for rays it cannot image);
* ``valid_pixels(pixels)``: ``(..., 2)`` -> ``(...,)`` bool, the valid image
  region;
* ``field_of_view_rad``: full angle of the cone about ``optical_axis`` that
  the valid region sees (above pi for fisheyes beyond 180 degrees);
* ``optical_axis``: ``(3,)`` camera-frame direction of the central ray;
* ``scaled(factor)``: the same camera at another resolution.

The module-level :func:`rays_from_pixels` and :func:`pixels_from_rays`
accept any model (see :class:`CameraModel`).

The OCamCalib model maps image pixels, given as ``(row, col)`` with 0-based integer pixel
centres, to unit rays in the camera frame and back:

* camera frame: x along image rows, y along image columns, z = x × y; for a
  catadioptric camera z is the mirror's symmetry axis;
* ``cam2world``: undo the affine sensor-to-image part around the centre, then
  the ray is ``(xp, yp, pol(r))`` with ``r = hypot(xp, yp)``;
* ``world2cam``: ``theta = atan2(z, hypot(x, y))``, ``rho = invpol(theta)``.

Polynomials are stored lowest degree first, as in ``calib_results.txt``.
This module is pure math: reading and writing calibration files lives in
:mod:`ifmi.io.calib`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = [
    "CameraModel",
    "OcamModel",
    "valid_mask",
    "measured_field_of_view",
    "angles_from_axis",
    "rays_from_pixels",
    "pixels_from_rays",
    "elevation_from_radius",
    "fit_inverse_polynomial",
    "model_from_direct_polynomial",
    "paracatadioptric_model",
    "max_image_radius",
    "radius_from_pixels",
    "sensor_from_pixels",
    "pixels_from_sensor",
    "pixel_offsets_from_sensor",
    "angular_pixel_size",
    "check_image_size",
    "check_affine",
    "check_center_inside",
    "inverse_round_trip_error",
    "MIN_IMAGE_SIDE_PX",
    "MAX_IMAGE_SIDE_PX",
    "AFFINE_MAX_DEVIATION",
    "INVERSE_TOLERANCE_PX",
    "INVERSE_CHECK_INNER_FRACTION",
]


@runtime_checkable
class CameraModel(Protocol):
    """What every camera model provides (see the module docstring)."""

    size: tuple[int, int]

    @property
    def height(self) -> int: ...

    @property
    def width(self) -> int: ...

    @property
    def optical_axis(self) -> np.ndarray: ...

    @property
    def field_of_view_rad(self) -> float: ...

    def rays_from_pixels(self, pixels) -> np.ndarray: ...

    def pixels_from_rays(self, rays) -> np.ndarray: ...

    def valid_pixels(self, pixels) -> np.ndarray: ...

    def scaled(self, factor: float) -> "CameraModel": ...


# Pixels whose lifted ray re-projects farther than this (px) are outside a model's valid region.
VALID_ROUND_TRIP_PX = 1e-3
# Smallest image side a calibration file may name, pixels: a panorama is at least 8 px
# on a side (ifmi.spectral.panorama.PanoramaConfig) and omnisim renders at least 8 px.
MIN_IMAGE_SIDE_PX = 8
# Largest image side a calibration file may name, pixels: the panorama's fixed-point remap
# maps (OpenCV CV_16SC2) hold pixel coordinates up to 32767.
MAX_IMAGE_SIDE_PX = 32768
# Largest accepted |c - 1|, |d| and |e| of OCamCalib's affine matrix [[c, d], [e, 1]]. It
# models the pixel aspect ratio and a slight sensor misalignment, so real calibrations are
# close to the identity (the published file of DESIGN.md: 0.045; this project's cameras:
# 0.02); 0.5 still admits pixel aspect ratios 0.5..1.5 (anamorphic video: 1.46) and keeps
# the matrix far from singular (c - d e >= 0.25).
AFFINE_MAX_DEVIATION = 0.5
# Largest accepted round-trip error of an OCamCalib inverse polynomial, pixels. OCamCalib
# fits its inverse to 0.01 px; printed files measure at most 0.004 px over the band (the
# DESIGN.md example 0.0024 px, six other published files 0.0014..0.0031 px, this project's
# own calibrations under 1e-4 px). The estimator places tiles to a few hundredths of a
# pixel, so an inverse off by more than a tenth of a pixel would bias its rays.
INVERSE_TOLERANCE_PX = 0.1
# The band of that check starts at this fraction of its outer radius. The centre of an omni
# image shows the camera itself, and OCamCalib's inverse is least accurate at -90 degrees
# (one published 33-coefficient file is 0.65 px off at the very centre, 0.004 px from a
# tenth of the radius out).
INVERSE_CHECK_INNER_FRACTION = 0.1
# Radii sampled across that band.
_INVERSE_CHECK_SAMPLES = 2048


def _image_grid(size: tuple[int, int]) -> np.ndarray:
    rows, cols = np.mgrid[0:size[0], 0:size[1]]
    return np.stack([rows, cols], axis=-1).astype(np.float64)


def valid_mask(model) -> np.ndarray:
    """``(H, W)`` bool mask of the valid image region of any camera model (rows, cols)."""
    return model.valid_pixels(_image_grid(model.size))


def angles_from_axis(rays: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Angle (radians) between ``(..., 3)`` rays and a ``(3,)`` axis; ``(...,)``; NaN stays NaN."""
    rays = np.asarray(rays, dtype=np.float64)
    norm = np.linalg.norm(rays, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.clip(rays @ np.asarray(axis, dtype=np.float64) / norm, -1.0, 1.0)
    return np.arccos(cosine)


def measured_field_of_view(model) -> float:
    """Twice the largest angle between ``model.optical_axis`` and a valid pixel's ray (radians).

    Every pixel centre of the image is lifted, so the value is exact to
    within the angle of half a pixel.
    """
    grid = _image_grid(model.size)
    valid = model.valid_pixels(grid)
    if not valid.any():
        raise ValueError("the camera model has no valid pixel in its image")
    angles = angles_from_axis(model.rays_from_pixels(grid[valid]), model.optical_axis)
    return float(2.0 * np.nanmax(angles))


class SizedImage:
    """Shared part of the camera models: an image of ``size`` = ``(height, width)`` pixels."""

    size: tuple[int, int]

    @property
    def height(self) -> int:
        """Image height in pixels (rows)."""
        return self.size[0]

    @property
    def width(self) -> int:
        """Image width in pixels (columns)."""
        return self.size[1]

    def inside_image(self, pixels: np.ndarray) -> np.ndarray:
        """``(...,)`` bool: ``(row, col)`` pixels ``(..., 2)`` in ``[-0.5, H - 0.5] x [-0.5, W - 0.5]``."""
        return ((pixels[..., 0] >= -0.5) & (pixels[..., 0] <= self.height - 0.5)
                & (pixels[..., 1] >= -0.5) & (pixels[..., 1] <= self.width - 0.5))


@dataclass(frozen=True)
class OcamModel(SizedImage):
    """Calibrated OCamCalib camera.

    Attributes
    ----------
    pol : tuple of float
        Direct polynomial (cam2world) coefficients, lowest degree first;
        ``z = pol(r)`` in sensor-plane pixel units.
    invpol : tuple of float
        Inverse polynomial (world2cam) coefficients, lowest degree first;
        ``rho = invpol(theta)`` with ``theta`` in radians.
    center : tuple of float
        Distortion centre ``(xc, yc)`` = ``(row, col)`` in pixels, 0-based.
    affine : tuple of float
        Affine parameters ``(c, d, e)``; ``(1, 0, 0)`` is an ideal sensor.
    size : tuple of int
        Image ``(height, width)`` in pixels.
    """

    pol: tuple[float, ...]
    invpol: tuple[float, ...]
    center: tuple[float, float]
    affine: tuple[float, float, float] = (1.0, 0.0, 0.0)
    size: tuple[int, int] = field(default=(0, 0))

    def __post_init__(self) -> None:
        object.__setattr__(self, "pol", tuple(float(v) for v in self.pol))
        object.__setattr__(self, "invpol", tuple(float(v) for v in self.invpol))
        object.__setattr__(self, "center", tuple(float(v) for v in self.center))
        object.__setattr__(self, "affine", tuple(float(v) for v in self.affine))
        object.__setattr__(self, "size", tuple(int(v) for v in self.size))
        if len(self.pol) < 1 or len(self.invpol) < 1:
            raise ValueError(
                f"polynomials need at least one coefficient, got pol={len(self.pol)}, "
                f"invpol={len(self.invpol)}"
            )
        if len(self.center) != 2 or len(self.affine) != 3 or len(self.size) != 2:
            raise ValueError(
                "expected center (row, col), affine (c, d, e), size (height, width); got "
                f"{len(self.center)}, {len(self.affine)}, {len(self.size)} values"
            )
        c, d, e = self.affine
        if abs(c - d * e) < 1e-12:
            raise ValueError(f"affine matrix is singular: c - d*e = {c - d * e}")
        if min(self.size) <= 0:
            raise ValueError(f"image size must be positive, got {self.size}")

    @property
    def optical_axis(self) -> np.ndarray:
        """(3,) ray of the distortion centre: ``(0, 0, sign pol(0))`` (the mirror axis)."""
        return np.array([0.0, 0.0, 1.0 if self.pol[0] >= 0 else -1.0])

    def rays_from_pixels(self, pixels) -> np.ndarray:
        """Unit rays ``(..., 3)`` of ``(row, col)`` pixels ``(..., 2)`` (:func:`rays_from_pixels`)."""
        return rays_from_pixels(self, pixels)

    def pixels_from_rays(self, rays) -> np.ndarray:
        """``(row, col)`` pixels ``(..., 2)`` of rays ``(..., 3)`` (:func:`pixels_from_rays`)."""
        return pixels_from_rays(self, rays)

    def valid_pixels(self, pixels) -> np.ndarray:
        """Valid image region: inside the image and within the calibration's invertible range.

        Parameters
        ----------
        pixels : (..., 2) array_like
            ``(row, col)``.

        Returns
        -------
        (...,) bool ndarray
            True inside the image whose sensor radius lies where the ray's
            elevation grows with the radius (the direct polynomial is
            invertible there) and whose ray re-projects onto it to 1e-3 px.
        """
        pixels = np.asarray(pixels, dtype=np.float64)
        inside = self.inside_image(pixels)
        back = pixels_from_rays(self, rays_from_pixels(self, pixels))
        close = np.hypot(back[..., 0] - pixels[..., 0], back[..., 1] - pixels[..., 1]) < VALID_ROUND_TRIP_PX
        return inside & (radius_from_pixels(self, pixels) <= self.monotonic_radius) & close

    @cached_property
    def monotonic_radius(self) -> float:
        """Largest sensor radius (px, up to the farthest image corner) where elevation still grows."""
        limit = max_image_radius(self.size, self.center, self.affine)
        r = np.linspace(0.0, limit, 4096)
        grows = np.diff(elevation_from_radius(np.asarray(self.pol), r)) > 0
        return limit if grows.all() else float(r[int(np.argmin(grows))])

    @cached_property
    def field_of_view_rad(self) -> float:
        """Full angle (radians) about :attr:`optical_axis` seen by the valid region."""
        return measured_field_of_view(self)

    def scaled(self, factor: float) -> "OcamModel":
        """Return the model of the same camera imaged at ``factor`` times the resolution.

        Pixel centres follow the 0-based convention, so the centre maps as
        ``(xc + 0.5) * factor - 0.5``.
        """
        if not factor > 0:
            raise ValueError(f"scale factor must be positive, got {factor}")
        pol = tuple(a * factor ** (1 - i) for i, a in enumerate(self.pol))
        invpol = tuple(a * factor for a in self.invpol)
        center = tuple((x + 0.5) * factor - 0.5 for x in self.center)
        size = (int(round(self.height * factor)), int(round(self.width * factor)))
        return replace(self, pol=pol, invpol=invpol, center=center, size=size)


def check_image_size(size) -> None:
    """Raise ``ValueError`` unless ``size`` is two integers from :data:`MIN_IMAGE_SIDE_PX` to :data:`MAX_IMAGE_SIDE_PX`.

    Parameters
    ----------
    size : (2,) sequence of int
        ``(height, width)`` or ``(width, height)``: both sides are bounded alike.
    """
    if not all(MIN_IMAGE_SIDE_PX <= side <= MAX_IMAGE_SIDE_PX for side in size):
        raise ValueError(f"expected image sides from {MIN_IMAGE_SIDE_PX} to {MAX_IMAGE_SIDE_PX} px, got "
                         f"{' x '.join(f'{side:.0f}' for side in size)}")


def check_affine(affine) -> None:
    """Raise ``ValueError`` unless OCamCalib's affine part ``(c, d, e)`` is close to the identity.

    ``|c - 1|``, ``|d|`` and ``|e|`` must be at most :data:`AFFINE_MAX_DEVIATION`
    (see there why).
    """
    c, d, e = (float(v) for v in affine)
    if not max(abs(c - 1.0), abs(d), abs(e)) <= AFFINE_MAX_DEVIATION:
        raise ValueError(f"expected an affine part close to the identity (|c - 1|, |d|, |e| at most "
                         f"{AFFINE_MAX_DEVIATION}; real sensors are within 0.05), got {c:g} {d:g} {e:g}")


def check_center_inside(center, size) -> None:
    """Raise ``ValueError`` unless the ``(row, col)`` centre lies inside an image of ``size`` ``(height, width)``.

    Inside means strictly between the outermost pixel centres, ``0 < row < H - 1``
    and ``0 < col < W - 1``, so that a circle about the centre fits in the image.
    """
    (row, col), (height, width) = center, size
    if not (0 < row < height - 1 and 0 < col < width - 1):
        raise ValueError(f"expected a point inside the {height}x{width} image (0 < row < {height - 1}, "
                         f"0 < col < {width - 1}), got {row:g} {col:g}")


def inverse_round_trip_error(model: OcamModel, inner: float, outer: float, *,
                             samples: int = _INVERSE_CHECK_SAMPLES) -> tuple[float, float]:
    """Largest ``|invpol(theta(r)) - r|`` of an OCamCalib model over sensor radii ``inner..outer``.

    Parameters
    ----------
    model : OcamModel
    inner, outer : float
        Sensor radii (pixels) of the band checked.
    samples : int, keyword-only
        Radii sampled evenly across the band.

    Returns
    -------
    error_px : float
        The largest round-trip error, pixels (inf where it is not finite).
    radius_px : float
        The radius where it occurs.
    """
    radii = np.linspace(inner, outer, samples)
    theta = elevation_from_radius(np.asarray(model.pol), radii)
    with np.errstate(all="ignore"):
        error = np.abs(np.polynomial.polynomial.polyval(theta, model.invpol) - radii)
    error = np.where(np.isfinite(error), error, np.inf)
    worst = int(np.argmax(error))
    return float(error[worst]), float(radii[worst])


def sensor_from_pixels(model: OcamModel, pixels) -> np.ndarray:
    """Sensor-plane points of pixels: the centre and the affine part removed.

    Parameters
    ----------
    model : OcamModel
    pixels : (..., 2) array_like
        ``(row, col)`` pixel coordinates.

    Returns
    -------
    (..., 2) ndarray
        ``(xp, yp)`` in pixels, the sensor point whose radius is the argument
        of the direct polynomial (inverse of :func:`pixels_from_sensor`).
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    c, d, e = model.affine
    dr = pixels[..., 0] - model.center[0]
    dc = pixels[..., 1] - model.center[1]
    inv_det = 1.0 / (c - d * e)
    xp = (dr - d * dc) * inv_det
    yp = (-e * dr + c * dc) * inv_det
    return np.stack([xp, yp], axis=-1)


def pixel_offsets_from_sensor(model: OcamModel, sensor) -> np.ndarray:
    """Affine part alone: ``(row, col)`` offsets from the distortion centre of sensor points.

    Parameters
    ----------
    model : OcamModel
    sensor : (..., 2) array_like
        ``(u, v)`` sensor-plane points in pixels.

    Returns
    -------
    (..., 2) ndarray
        ``(row - xc, col - yc)`` = ``(u c + v d, u e + v)`` in pixels.
    """
    sensor = np.asarray(sensor, dtype=np.float64)
    u, v = sensor[..., 0], sensor[..., 1]
    c, d, e = model.affine
    return np.stack([u * c + v * d, u * e + v], axis=-1)


def pixels_from_sensor(model: OcamModel, sensor) -> np.ndarray:
    """Pixels of sensor-plane points: OCamCalib's affine part and centre applied.

    Parameters
    ----------
    model : OcamModel
    sensor : (..., 2) array_like
        ``(u, v)`` sensor-plane points in pixels (``rho (cos phi, sin phi)``
        for a ray of azimuth ``phi`` imaged at sensor radius ``rho``).

    Returns
    -------
    (..., 2) ndarray
        ``(row, col)`` = ``(u c + v d + xc, u e + v + yc)``, 0-based pixels
        (inverse of :func:`sensor_from_pixels`).
    """
    # pixel_offsets_from_sensor plus the centre, written into one array (the same sums, in the same
    # order, without two interleaving stacks: a third of the time on a panorama's map).
    sensor = np.asarray(sensor, dtype=np.float64)
    u, v = sensor[..., 0], sensor[..., 1]
    c, d, e = model.affine
    pixels = np.empty(sensor.shape)
    pixels[..., 0] = u * c + v * d + model.center[0]
    pixels[..., 1] = u * e + v + model.center[1]
    return pixels


def radius_from_pixels(model: OcamModel, pixels: np.ndarray) -> np.ndarray:
    """Sensor-plane radius of pixels, after removing the affine part.

    Parameters
    ----------
    model : OcamModel
    pixels : (..., 2) array_like
        ``(row, col)`` pixel coordinates.

    Returns
    -------
    (...,) ndarray
        Radius ``r`` in pixels, the argument of the direct polynomial.
    """
    sensor = sensor_from_pixels(model, pixels)
    return np.hypot(sensor[..., 0], sensor[..., 1])


def rays_from_pixels(model: OcamModel, pixels: np.ndarray) -> np.ndarray:
    """Lift pixels to unit rays (OCamCalib ``cam2world``; other models: their own lifting).

    Parameters
    ----------
    model : OcamModel or CameraModel
    pixels : (..., 2) array_like
        ``(row, col)`` coordinates, 0-based, pixel centres at integers.

    Returns
    -------
    (..., 3) ndarray
        Unit rays ``(x, y, z)`` in the camera frame.
    """
    if not isinstance(model, OcamModel):
        return model.rays_from_pixels(pixels)
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.shape[-1:] != (2,):
        raise ValueError(f"expected pixels of shape (..., 2), got {pixels.shape}")
    sensor = sensor_from_pixels(model, pixels)
    xp, yp = sensor[..., 0], sensor[..., 1]
    r = np.hypot(xp, yp)
    zp = np.polynomial.polynomial.polyval(r, model.pol)
    rays = np.stack([xp, yp, zp], axis=-1)
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def pixels_from_rays(model: OcamModel, rays: np.ndarray) -> np.ndarray:
    """Project rays to pixels (OCamCalib ``world2cam``; other models: their own projection).

    Parameters
    ----------
    model : OcamModel or CameraModel
    rays : (..., 3) array_like
        Directions in the camera frame; need not be normalised.

    Returns
    -------
    (..., 2) ndarray
        ``(row, col)`` pixel coordinates. Rays along the z axis land on the
        centre.
    """
    if not isinstance(model, OcamModel):
        return model.pixels_from_rays(rays)
    rays = np.asarray(rays, dtype=np.float64)
    if rays.shape[-1:] != (3,):
        raise ValueError(f"expected rays of shape (..., 3), got {rays.shape}")
    x, y, z = rays[..., 0], rays[..., 1], rays[..., 2]
    norm = np.hypot(x, y)
    theta = np.arctan2(z, norm)
    rho = np.polynomial.polynomial.polyval(theta, model.invpol)
    safe = np.where(norm > 0, norm, 1.0)
    u = np.where(norm > 0, x / safe * rho, 0.0)
    v = np.where(norm > 0, y / safe * rho, 0.0)
    return pixels_from_sensor(model, np.stack([u, v], axis=-1))


def angular_pixel_size(model, pixels) -> np.ndarray:
    """Angle (radians) one pixel subtends at each of ``pixels``, for any camera model.

    The angles between the ray of a pixel and the rays one pixel further
    along the image rows and along the columns are measured (so an
    OCamCalib affine part counts); a pixel's size is their geometric mean.
    It scales inversely with the image resolution, which makes thresholds
    given in pixels independent of it.

    Parameters
    ----------
    model : OcamModel or CameraModel
    pixels : (..., 2) array_like
        ``(row, col)`` sample pixels.

    Returns
    -------
    (...,) ndarray
        Radians; NaN where a ray is outside the model's domain.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    steps = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    rays = rays_from_pixels(model, pixels[..., None, :] + steps)
    along_row = np.arccos(np.clip(np.sum(rays[..., 0, :] * rays[..., 1, :], axis=-1), -1.0, 1.0))
    along_col = np.arccos(np.clip(np.sum(rays[..., 0, :] * rays[..., 2, :], axis=-1), -1.0, 1.0))
    return np.sqrt(along_row * along_col)


def elevation_from_radius(pol: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Angle ``theta = atan2(pol(r), r)`` of the ray at sensor radius ``r`` (radians)."""
    radius = np.asarray(radius, dtype=np.float64)
    return np.arctan2(np.polynomial.polynomial.polyval(radius, pol), radius)


def max_image_radius(size: tuple[int, int], center: tuple[float, float],
                     affine: tuple[float, float, float] = (1.0, 0.0, 0.0)) -> float:
    """Largest sensor-plane radius of any image corner (pixels)."""
    h, w = size
    corners = np.array([[-0.5, -0.5], [-0.5, w - 0.5], [h - 0.5, -0.5], [h - 0.5, w - 0.5]])
    probe = OcamModel(pol=(1.0,), invpol=(1.0,), center=center, affine=affine, size=size)
    return float(radius_from_pixels(probe, corners).max())


def fit_inverse_polynomial(pol, radius_max: float, *, tolerance_px: float = 1e-4,
                           max_degree: int = 24, samples: int = 2000) -> tuple[float, ...]:
    """Fit the world2cam polynomial ``rho = invpol(theta)`` to a direct polynomial.

    As OCamCalib's ``findinvpoly`` does, the degree grows until the largest
    radius error on ``[0, radius_max]`` falls under ``tolerance_px``. The range
    is cut where ``theta(r)`` stops increasing, since no inverse exists beyond.

    Parameters
    ----------
    pol : (K,) array_like
        Direct polynomial, lowest degree first.
    radius_max : float
        Largest sensor radius (pixels) that must be inverted.
    tolerance_px : float, keyword-only
        Target largest radius error in pixels.
    max_degree : int, keyword-only
        Highest degree tried; the best fit found is returned if the target is
        not reached.
    samples : int, keyword-only
        Number of radii sampled.

    Returns
    -------
    tuple of float
        Inverse polynomial coefficients, lowest degree first.
    """
    pol = np.asarray(pol, dtype=np.float64)
    if not radius_max > 0:
        raise ValueError(f"radius_max must be positive, got {radius_max}")
    r = np.linspace(0.0, radius_max, samples)
    theta = elevation_from_radius(pol, r)
    increasing = np.diff(theta) > 0
    if not increasing[0]:
        raise ValueError("theta(r) must increase with r near the centre; check the sign of pol")
    stop = np.argmin(increasing) + 1 if not increasing.all() else samples
    r, theta = r[:stop], theta[:stop]
    best, best_err = None, np.inf
    for degree in range(2, max_degree + 1):
        with warnings.catch_warnings():
            # numpy's RankWarning: the error measured below judges the fit (and the readers check it).
            warnings.filterwarnings("ignore", message="The fit may be poorly conditioned")
            series = np.polynomial.Polynomial.fit(theta, r, degree)
        err = np.abs(series(theta) - r).max()
        if err < best_err:
            best, best_err = series, err
        if err < tolerance_px:
            break
    return tuple(float(v) for v in best.convert().coef)


def model_from_direct_polynomial(pol, *, center: tuple[float, float], size: tuple[int, int],
                                 affine: tuple[float, float, float] = (1.0, 0.0, 0.0),
                                 tolerance_px: float = 1e-4) -> OcamModel:
    """Build a complete model from the direct polynomial alone.

    The inverse polynomial is fitted over every radius the image reaches.

    Parameters
    ----------
    pol : (K,) array_like
        Direct polynomial, lowest degree first.
    center : (2,) tuple, keyword-only
        ``(row, col)`` of the distortion centre in pixels.
    size : (2,) tuple, keyword-only
        Image ``(height, width)``.
    affine : (3,) tuple, keyword-only
        ``(c, d, e)``.
    tolerance_px : float, keyword-only
        Target round-trip accuracy of the fitted inverse, pixels.
    """
    radius = max_image_radius(size, center, affine)
    invpol = fit_inverse_polynomial(pol, radius, tolerance_px=tolerance_px)
    return OcamModel(pol=tuple(pol), invpol=invpol, center=center, affine=affine, size=size)


def paracatadioptric_model(size: tuple[int, int], *, horizon_radius_px: float,
                           center: tuple[float, float] | None = None,
                           affine: tuple[float, float, float] = (1.0, 0.0, 0.0)) -> OcamModel:
    """Exact OCamCalib model of a paraboloid mirror seen by an orthographic camera.

    A paraboloid ``z = (r**2 - h**2) / (2 h)`` with its focus at the origin
    reflects every ray through the focus into a ray parallel to its axis, so
    ``pol(r) = -h/2 + r**2 / (2 h)`` holds exactly; ``h`` is the image radius
    that sees the horizon (``z = 0``).

    Parameters
    ----------
    size : (2,) tuple
        Image ``(height, width)``.
    horizon_radius_px : float, keyword-only
        Radius ``h`` in pixels at which rays are horizontal.
    center : (2,) tuple, optional, keyword-only
        ``(row, col)``; default the image centre ``((H-1)/2, (W-1)/2)``.
    affine : (3,) tuple, keyword-only
        ``(c, d, e)``.
    """
    h = float(horizon_radius_px)
    if not h > 0:
        raise ValueError(f"horizon_radius_px must be positive, got {horizon_radius_px}")
    if center is None:
        center = ((size[0] - 1) / 2.0, (size[1] - 1) / 2.0)
    pol = (-h / 2.0, 0.0, 1.0 / (2.0 * h))
    return model_from_direct_polynomial(pol, center=center, size=size, affine=affine)
