"""Central wide-angle camera models of Kalibr, and the equirectangular 360-degree camera.

Every model here follows the camera-model protocol of :mod:`ifmi.geometry.camera`
(``rays_from_pixels``, ``pixels_from_rays``, ``valid_pixels``,
``field_of_view_rad``, ``scaled``) and keeps its toolbox's camera frame:

* x along image columns, y along image rows, z the optical axis (Kalibr,
  OpenCV); for the equirectangular camera z is the image centre's direction
  and -y points up;
* a pixel ``(u, v)`` of the toolbox is ``(col, row)``, pixel centres at
  integers as in OpenCV. The functions take and return the project's
  ``(row, col)`` order.

Models (Kalibr names; intrinsics in Kalibr's order):

* :class:`UnifiedModel` -- ``omni``, ``[xi, fu, fv, pu, pv]``, the unified
  (Mei) model, with ``radtan`` ``[k1, k2, p1, p2]`` or no distortion;
* :class:`PinholeModel` -- ``pinhole``, ``[fu, fv, pu, pv]`` with ``radtan``
  or no distortion (the unified model with ``xi = 0``);
* :class:`ExtendedUnifiedModel` -- ``eucm``, ``[alpha, beta, fu, fv, pu, pv]``;
* :class:`DoubleSphereModel` -- ``ds``, ``[xi, alpha, fu, fv, pu, pv]``;
* :class:`KannalaBrandtModel` -- ``pinhole`` with ``equidistant``
  ``[k1, k2, k3, k4]``;
* :class:`EquirectangularModel` -- no intrinsics: column = longitude,
  row = latitude.

Rays that a model cannot project give NaN pixels, and pixels outside its
domain give NaN rays; ``valid_pixels`` is the valid image region. Lifting a
radtan-distorted pixel inverts the distortion by Newton's method (see
:func:`undistort_radtan`), converged to far below 1e-3 px.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from ifmi.geometry.camera import VALID_ROUND_TRIP_PX, SizedImage, angular_pixel_size, measured_field_of_view

__all__ = [
    "UnifiedModel",
    "PinholeModel",
    "ExtendedUnifiedModel",
    "DoubleSphereModel",
    "KannalaBrandtModel",
    "EquirectangularModel",
    "distort_radtan",
    "undistort_radtan",
    "check_usable_region",
    "KALIBR_MODELS",
    "MIN_PIXEL_ANGLE_RAD",
    "MAX_PIXEL_ANGLE_RAD",
]

# Newton's iteration of the radtan undistortion stops when the distorted point is
# reproduced to this accuracy in normalised image units (a micro-pixel at f ~ 1000 px) ...
_UNDISTORT_TOLERANCE = 1e-9
# ... or after this many steps; points not converged by then are outside the valid region.
_UNDISTORT_MAX_STEPS = 50
# Angles (and radii) sampled to find where the Kannala-Brandt polynomial (the radial
# radtan map) stops increasing.
_KB_THETA_SAMPLES = 20001
# Largest undistorted normalised radius searched for a radtan fold (about 84 degrees off axis).
_RADTAN_FOLD_SEARCH = 10.0
# Bounds of the angle one pixel subtends at the principal point (check_usable_region), radians.
# Below: a focal length over a million pixels (a 1000 mm lens on 1 um pixels is 1e6 px), whose
# whole image is a speck of the sphere. Above: a hemisphere in under four pixels (the
# project's smallest cameras, 64 px fisheyes, measure under 0.05 rad).
MIN_PIXEL_ANGLE_RAD = 1e-6
MAX_PIXEL_ANGLE_RAD = 0.5


def _check_pixels(pixels) -> np.ndarray:
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.shape[-1:] != (2,):
        raise ValueError(f"expected pixels of shape (..., 2), got {pixels.shape}")
    return pixels


def _check_rays(rays) -> np.ndarray:
    rays = np.asarray(rays, dtype=np.float64)
    if rays.shape[-1:] != (3,):
        raise ValueError(f"expected rays of shape (..., 3), got {rays.shape}")
    return rays


def _normalised(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def distort_radtan(m: np.ndarray, coeffs) -> np.ndarray:
    """Radial-tangential (Brown-Conrady) distortion of normalised points.

    Parameters
    ----------
    m : (..., 2) ndarray
        Undistorted normalised points ``(x, y)`` (x along columns).
    coeffs : (4,) sequence
        ``(k1, k2, p1, p2)`` as in Kalibr and OpenCV.

    Returns
    -------
    (..., 2) ndarray
        Distorted normalised points.
    """
    k1, k2, p1, p2 = coeffs
    x, y = m[..., 0], m[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + k2 * r2)
    dx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    dy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([dx, dy], axis=-1)


def _radtan_jacobian(m: np.ndarray, coeffs) -> np.ndarray:
    k1, k2, p1, p2 = coeffs
    x, y = m[..., 0], m[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + k2 * r2)
    dradial = 2.0 * (k1 + 2.0 * k2 * r2)  # d radial / d r2, times 2 for d r2 / dx = 2x
    jxx = radial + x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    jxy = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    jyx = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    jyy = radial + y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return np.stack([np.stack([jxx, jxy], -1), np.stack([jyx, jyy], -1)], -2)


def undistort_radtan(distorted: np.ndarray, coeffs, *, start: np.ndarray | None = None) -> np.ndarray:
    """Invert :func:`distort_radtan` by Newton's method (vectorised).

    Starting from the distorted point (or ``start``), each step solves the 2x2 linearised
    system; iteration stops when every point reproduces its distorted
    position to 1e-9 normalised units (1e-6 px at a 1000 px focal length,
    far below the 1e-3 px the models promise) or after 50 steps. Points
    whose iteration does not converge, or lands where the distortion folds
    over (non-positive Jacobian determinant), come back as NaN.

    Parameters
    ----------
    distorted : (..., 2) ndarray
        Distorted normalised points.
    coeffs : (4,) sequence
        ``(k1, k2, p1, p2)``.
    start : (..., 2) ndarray, optional, keyword-only
        Initial guesses (e.g. interpolated from a coarser solution); where a
        guess is not finite the distorted point is used.

    Returns
    -------
    (..., 2) ndarray
        Undistorted normalised points, NaN where the inverse does not exist.
    """
    distorted = np.asarray(distorted, dtype=np.float64)
    target = distorted.reshape(-1, 2)
    m = target.copy()
    if start is not None:
        guess = np.asarray(start, dtype=np.float64).reshape(-1, 2)
        usable = np.isfinite(guess).all(axis=-1)
        m[usable] = guess[usable]
    active = np.arange(len(m))
    for _ in range(_UNDISTORT_MAX_STEPS):
        residual = distort_radtan(m[active], coeffs) - target[active]
        moving = np.abs(residual).max(axis=-1) > _UNDISTORT_TOLERANCE
        active, residual = active[moving], residual[moving]
        if not active.size:
            break
        jac = _radtan_jacobian(m[active], coeffs)
        det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
        with np.errstate(invalid="ignore", divide="ignore"):
            step_x = (jac[:, 1, 1] * residual[:, 0] - jac[:, 0, 1] * residual[:, 1]) / det
            step_y = (jac[:, 0, 0] * residual[:, 1] - jac[:, 1, 0] * residual[:, 0]) / det
        m[active] -= np.stack([step_x, step_y], axis=-1)
    residual = np.abs(distort_radtan(m, coeffs) - target).max(axis=-1)
    jac = _radtan_jacobian(m, coeffs)
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    bad = ~(residual <= _UNDISTORT_TOLERANCE) | ~(det > 0)
    m[bad] = np.nan
    return m.reshape(distorted.shape)


def _checked_size(size) -> tuple[int, int]:
    size = tuple(int(v) for v in size)
    if len(size) != 2 or min(size) <= 0:
        raise ValueError(f"expected size (height, width) of positive integers, got {size}")
    return size


def _checked_finite(name: str, values) -> tuple[float, ...]:
    values = tuple(float(v) for v in values)
    if not all(np.isfinite(values)):
        raise ValueError(f"{name} must be finite, got {list(values)}")
    return values


class _Undistorted:
    """Models without lens distortion: no coefficients, distortion model ``none``."""

    distortion = ()
    distortion_model = "none"


class _CentralModel(SizedImage):
    """Shared parts of the Kalibr models: focal lengths, principal point, size, validity."""

    focal: tuple[float, float]
    principal_point: tuple[float, float]

    def _check_projection(self) -> None:
        object.__setattr__(self, "size", _checked_size(self.size))
        object.__setattr__(self, "focal", _checked_finite("focal (fu, fv)", self.focal))
        object.__setattr__(self, "principal_point",
                           _checked_finite("principal point (pu, pv)", self.principal_point))
        if len(self.focal) != 2 or len(self.principal_point) != 2:
            raise ValueError(f"expected focal (fu, fv) and principal point (pu, pv), got "
                             f"{len(self.focal)} and {len(self.principal_point)} values")
        if min(self.focal) <= 0:
            raise ValueError(f"focal lengths must be positive, got {self.focal}")

    def _check_projection_and(self, *names: str) -> tuple[float, ...]:
        """Check the projection, then the named scalar parameters (finite), stored as floats."""
        self._check_projection()
        values = _checked_finite(", ".join(names), [getattr(self, n) for n in names])
        for name, value in zip(names, values):
            object.__setattr__(self, name, value)
        return values

    @property
    def optical_axis(self) -> np.ndarray:
        """(3,) unit vector of the optical axis in the camera frame (+z)."""
        return np.array([0.0, 0.0, 1.0])

    def _normalised_from_pixels(self, pixels: np.ndarray) -> np.ndarray:
        (fu, fv), (pu, pv) = self.focal, self.principal_point
        return np.stack([(pixels[..., 1] - pu) / fu, (pixels[..., 0] - pv) / fv], axis=-1)

    def _pixels_from_normalised(self, m: np.ndarray) -> np.ndarray:
        (fu, fv), (pu, pv) = self.focal, self.principal_point
        return np.stack([fv * m[..., 1] + pv, fu * m[..., 0] + pu], axis=-1)

    def _scaled_projection(self, factor: float) -> dict:
        if not factor > 0:
            raise ValueError(f"scale factor must be positive, got {factor}")
        return {"focal": tuple(f * factor for f in self.focal),
                "principal_point": tuple((p + 0.5) * factor - 0.5 for p in self.principal_point),
                "size": (int(round(self.height * factor)), int(round(self.width * factor)))}

    def scaled(self, factor: float):
        """The model of the same camera imaged at ``factor`` times the resolution.

        Focal lengths scale by ``factor``; the principal point follows the
        pixel-centre convention, ``(p + 0.5) * factor - 0.5``.
        """
        return replace(self, **self._scaled_projection(factor))

    def valid_pixels(self, pixels) -> np.ndarray:
        """Valid image region: inside the image, in the model's domain, and round-tripping.

        Parameters
        ----------
        pixels : (..., 2) array_like
            ``(row, col)``, pixel centres at integers.

        Returns
        -------
        (...,) bool ndarray
            True where the pixel lies inside the image (``[-0.5, H - 0.5]``
            x ``[-0.5, W - 0.5]``), lifts to a ray, and that ray projects
            back onto the pixel to within 1e-3 px.
        """
        pixels = _check_pixels(pixels)
        inside = self.inside_image(pixels)
        back = self.pixels_from_rays(self.rays_from_pixels(pixels))
        with np.errstate(invalid="ignore"):
            close = np.linalg.norm(back - pixels, axis=-1) < VALID_ROUND_TRIP_PX
        return inside & close

    @cached_property
    def field_of_view_rad(self) -> float:
        """Full angle (radians) of the cone about the optical axis that the valid region sees.

        Twice the largest angle between the optical axis and the ray of a
        valid pixel, measured over every pixel of the image.
        """
        return measured_field_of_view(self)


@dataclass(frozen=True)
class UnifiedModel(_CentralModel):
    """Unified (Mei) model, Kalibr ``omni``, with optional radtan distortion.

    A ray ``X`` projects through the unit sphere shifted by ``xi`` along z:
    ``m = (x, y) / (z + xi |X|)``, then radtan distortion, then
    ``u = fu m_x + pu``, ``v = fv m_y + pv``.

    Attributes
    ----------
    xi : float
        Mirror parameter (>= 0).
    focal : (2,) tuple of float
        ``(fu, fv)`` in pixels.
    principal_point : (2,) tuple of float
        ``(pu, pv)`` = ``(col, row)`` in pixels.
    size : (2,) tuple of int
        Image ``(height, width)``.
    distortion : tuple of float
        ``(k1, k2, p1, p2)`` (``radtan``) or ``()`` (no distortion).
    """

    xi: float
    focal: tuple[float, float]
    principal_point: tuple[float, float]
    size: tuple[int, int]
    distortion: tuple[float, ...] = ()

    kalibr_model = "omni"

    def __post_init__(self) -> None:
        self._check_projection()
        object.__setattr__(self, "xi", _checked_finite("xi", [self.xi])[0])
        object.__setattr__(self, "distortion", _checked_finite("distortion", self.distortion))
        if self.xi < 0:
            raise ValueError(f"xi must be >= 0, got {self.xi}")
        if len(self.distortion) not in (0, 4):
            raise ValueError(f"expected 4 radtan coefficients or none, got {len(self.distortion)}")

    @property
    def distortion_model(self) -> str:
        return "radtan" if self.distortion else "none"

    @cached_property
    def max_undistorted_radius(self) -> float:
        """Undistorted normalised radius where the radial radtan map first stops increasing (inf if never).

        Beyond it the distortion folds back: a pixel there would also be the
        image of rays far outside, so it is outside the valid region (the
        small tangential terms are left out of this bound).
        """
        if not self.distortion:
            return float("inf")
        k1, k2 = self.distortion[:2]
        r = np.linspace(0.0, _RADTAN_FOLD_SEARCH, _KB_THETA_SAMPLES)
        falling = np.flatnonzero(1.0 + r * r * (3.0 * k1 + 5.0 * k2 * r * r) <= 0)
        return float(r[falling[0] - 1]) if falling.size else float("inf")

    def rays_from_pixels(self, pixels) -> np.ndarray:
        """Unit rays ``(..., 3)`` of ``(row, col)`` pixels ``(..., 2)``; NaN outside the domain."""
        m = self._normalised_from_pixels(_check_pixels(pixels))
        if self.distortion:
            m = undistort_radtan(m, self.distortion)
            with np.errstate(invalid="ignore"):
                m[np.sum(m * m, axis=-1) > self.max_undistorted_radius ** 2] = np.nan
        r2 = np.sum(m * m, axis=-1)
        with np.errstate(invalid="ignore"):
            root = np.sqrt(1.0 + (1.0 - self.xi ** 2) * r2)
        factor = (self.xi + root) / (1.0 + r2)
        rays = np.stack([factor * m[..., 0], factor * m[..., 1], factor - self.xi], axis=-1)
        return _normalised(rays)

    def pixels_from_rays(self, rays) -> np.ndarray:
        """``(row, col)`` pixels ``(..., 2)`` of rays ``(..., 3)``; NaN for rays it cannot see."""
        rays = _normalised(_check_rays(rays))
        z = rays[..., 2]
        # Points whose projection is unique: z > -w |X| (|X| = 1 here).
        w = self.xi if self.xi <= 1.0 else 1.0 / self.xi
        denom = z + self.xi
        ok = (z > -w) & (denom > 0)
        safe = np.where(ok, denom, 1.0)
        m = rays[..., :2] / safe[..., None]
        if self.distortion:
            m = distort_radtan(m, self.distortion)
        m[~ok] = np.nan
        return self._pixels_from_normalised(m)


@dataclass(frozen=True)
class PinholeModel(UnifiedModel):
    """Kalibr ``pinhole`` with ``radtan`` or no distortion: the unified model with ``xi = 0``.

    Construct with ``PinholeModel(0.0, focal, principal_point, size, distortion)``
    or :meth:`create`; ``xi`` must be 0.
    """

    kalibr_model = "pinhole"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.xi != 0:
            raise ValueError(f"a pinhole model has xi = 0, got {self.xi}")

    @classmethod
    def create(cls, focal, principal_point, size, distortion=()) -> "PinholeModel":
        """Pinhole model from ``(fu, fv)``, ``(pu, pv)``, ``(height, width)`` and radtan coefficients."""
        return cls(0.0, focal, principal_point, size, distortion)


@dataclass(frozen=True)
class ExtendedUnifiedModel(_Undistorted, _CentralModel):
    """Extended unified camera model (Khomutenko et al.), Kalibr ``eucm``.

    ``d = sqrt(beta (x^2 + y^2) + z^2)``, ``m = (x, y) / (alpha d + (1 - alpha) z)``.

    Attributes
    ----------
    alpha : float
        In ``[0, 1]``.
    beta : float
        Positive.
    focal, principal_point, size
        As :class:`UnifiedModel`.
    """

    alpha: float
    beta: float
    focal: tuple[float, float]
    principal_point: tuple[float, float]
    size: tuple[int, int]

    kalibr_model = "eucm"

    def __post_init__(self) -> None:
        alpha, beta = self._check_projection_and("alpha", "beta")
        if not 0 <= alpha <= 1 or not beta > 0:
            raise ValueError(f"expected 0 <= alpha <= 1 and beta > 0, got {alpha}, {beta}")

    def rays_from_pixels(self, pixels) -> np.ndarray:
        """Unit rays ``(..., 3)`` of ``(row, col)`` pixels ``(..., 2)``; NaN outside the domain."""
        m = self._normalised_from_pixels(_check_pixels(pixels))
        a, b = self.alpha, self.beta
        r2 = np.sum(m * m, axis=-1)
        with np.errstate(invalid="ignore"):
            mz = (1.0 - b * a * a * r2) / (a * np.sqrt(1.0 - (2.0 * a - 1.0) * b * r2) + (1.0 - a))
        return _normalised(np.stack([m[..., 0], m[..., 1], mz], axis=-1))

    def pixels_from_rays(self, rays) -> np.ndarray:
        """``(row, col)`` pixels ``(..., 2)`` of rays ``(..., 3)``; NaN for rays it cannot see."""
        rays = _normalised(_check_rays(rays))
        x, y, z = rays[..., 0], rays[..., 1], rays[..., 2]
        a, b = self.alpha, self.beta
        d = np.sqrt(b * (x * x + y * y) + z * z)
        denom = a * d + (1.0 - a) * z
        w = a / (1.0 - a) if a <= 0.5 else (1.0 - a) / a
        ok = (denom > 0) & (z > -w * d)
        m = np.stack([x, y], axis=-1) / np.where(ok, denom, 1.0)[..., None]
        m[~ok] = np.nan
        return self._pixels_from_normalised(m)


@dataclass(frozen=True)
class DoubleSphereModel(_Undistorted, _CentralModel):
    """Double sphere model (Usenko et al.), Kalibr ``ds``.

    ``d1 = |X|``, ``d2 = |(x, y, xi d1 + z)|``,
    ``m = (x, y) / (alpha d2 + (1 - alpha)(xi d1 + z))``.

    Attributes
    ----------
    xi : float
    alpha : float
        In ``[0, 1]``.
    focal, principal_point, size
        As :class:`UnifiedModel`.
    """

    xi: float
    alpha: float
    focal: tuple[float, float]
    principal_point: tuple[float, float]
    size: tuple[int, int]

    kalibr_model = "ds"

    def __post_init__(self) -> None:
        xi, alpha = self._check_projection_and("xi", "alpha")
        if not 0 <= alpha <= 1:
            raise ValueError(f"expected 0 <= alpha <= 1, got {alpha}")

    def rays_from_pixels(self, pixels) -> np.ndarray:
        """Unit rays ``(..., 3)`` of ``(row, col)`` pixels ``(..., 2)``; NaN outside the domain."""
        m = self._normalised_from_pixels(_check_pixels(pixels))
        xi, a = self.xi, self.alpha
        r2 = np.sum(m * m, axis=-1)
        with np.errstate(invalid="ignore"):
            mz = (1.0 - a * a * r2) / (a * np.sqrt(1.0 - (2.0 * a - 1.0) * r2) + 1.0 - a)
            scale = (mz * xi + np.sqrt(mz * mz + (1.0 - xi * xi) * r2)) / (mz * mz + r2)
        rays = np.stack([scale * m[..., 0], scale * m[..., 1], scale * mz - xi], axis=-1)
        return _normalised(rays)

    def pixels_from_rays(self, rays) -> np.ndarray:
        """``(row, col)`` pixels ``(..., 2)`` of rays ``(..., 3)``; NaN for rays it cannot see."""
        rays = _normalised(_check_rays(rays))
        x, y, z = rays[..., 0], rays[..., 1], rays[..., 2]
        xi, a = self.xi, self.alpha
        shifted = xi + z  # xi d1 + z with d1 = 1
        d2 = np.sqrt(x * x + y * y + shifted * shifted)
        denom = a * d2 + (1.0 - a) * shifted
        w1 = a / (1.0 - a) if a <= 0.5 else (1.0 - a) / a
        w2 = (w1 + xi) / np.sqrt(2.0 * w1 * xi + xi * xi + 1.0)
        ok = (z > -w2) & (denom > 0)
        m = np.stack([x, y], axis=-1) / np.where(ok, denom, 1.0)[..., None]
        m[~ok] = np.nan
        return self._pixels_from_normalised(m)


@dataclass(frozen=True)
class KannalaBrandtModel(_CentralModel):
    """Kannala-Brandt (equidistant) model, Kalibr ``pinhole`` with ``equidistant``.

    ``theta`` = angle from the optical axis,
    ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``,
    ``m = theta_d (x, y) / hypot(x, y)``. Lifting inverts ``theta_d(theta)``
    by Newton's method on the range where it increases.

    Attributes
    ----------
    focal, principal_point, size
        As :class:`UnifiedModel`.
    distortion : (4,) tuple of float
        ``(k1, k2, k3, k4)``.
    """

    focal: tuple[float, float]
    principal_point: tuple[float, float]
    size: tuple[int, int]
    distortion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    kalibr_model = "pinhole"
    distortion_model = "equidistant"

    def __post_init__(self) -> None:
        self._check_projection()
        object.__setattr__(self, "distortion", _checked_finite("distortion", self.distortion))
        if len(self.distortion) != 4:
            raise ValueError(f"expected 4 equidistant coefficients, got {len(self.distortion)}")

    def _theta_d(self, theta: np.ndarray) -> np.ndarray:
        t2 = theta * theta
        k1, k2, k3, k4 = self.distortion
        return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def _dtheta_d(self, theta: np.ndarray) -> np.ndarray:
        t2 = theta * theta
        k1, k2, k3, k4 = self.distortion
        return 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))

    @cached_property
    def max_angle_rad(self) -> float:
        """Largest angle from the axis (<= pi) up to which ``theta_d`` increases."""
        theta = np.linspace(0.0, np.pi, _KB_THETA_SAMPLES)
        falling = np.flatnonzero(self._dtheta_d(theta) <= 0)
        return float(theta[falling[0] - 1]) if falling.size else float(np.pi)

    def rays_from_pixels(self, pixels) -> np.ndarray:
        """Unit rays ``(..., 3)`` of ``(row, col)`` pixels ``(..., 2)``; NaN outside the domain."""
        m = self._normalised_from_pixels(_check_pixels(pixels))
        theta_d = np.hypot(m[..., 0], m[..., 1])
        limit = self.max_angle_rad
        theta = np.minimum(theta_d, limit)
        for _ in range(_UNDISTORT_MAX_STEPS):
            residual = self._theta_d(theta) - theta_d
            if np.all(np.abs(residual) <= _UNDISTORT_TOLERANCE):
                break
            theta = np.clip(theta - residual / self._dtheta_d(theta), 0.0, limit)
        ok = np.abs(self._theta_d(theta) - theta_d) <= _UNDISTORT_TOLERANCE
        scale = np.where(theta_d > 0, np.sin(theta) / np.where(theta_d > 0, theta_d, 1.0), 1.0)
        rays = np.stack([scale * m[..., 0], scale * m[..., 1], np.cos(theta)], axis=-1)
        rays[~ok] = np.nan
        return rays

    def pixels_from_rays(self, rays) -> np.ndarray:
        """``(row, col)`` pixels ``(..., 2)`` of rays ``(..., 3)``; NaN for rays it cannot see."""
        rays = _check_rays(rays)
        x, y, z = rays[..., 0], rays[..., 1], rays[..., 2]
        r = np.hypot(x, y)
        theta = np.arctan2(r, z)
        theta_d = self._theta_d(theta)
        scale = np.where(r > 0, theta_d / np.where(r > 0, r, 1.0), 0.0)
        m = np.stack([scale * x, scale * y], axis=-1)
        m[theta > self.max_angle_rad] = np.nan
        return self._pixels_from_normalised(m)


@dataclass(frozen=True)
class EquirectangularModel(_Undistorted, SizedImage):
    """Equirectangular 360-degree camera: column = longitude, row = latitude.

    Camera frame: z the direction of the image centre, x along columns, y
    down. Longitude ``atan2(x, z)`` grows with the column from ``-pi`` at the
    left edge to ``pi`` at the right; latitude ``asin(-y)`` falls from
    ``pi/2`` at the top edge to ``-pi/2`` at the bottom:
    ``col = (lon + pi) W / (2 pi) - 0.5``, ``row = (pi/2 - lat) H / pi - 0.5``.

    Attributes
    ----------
    size : (2,) tuple of int
        Image ``(height, width)``.
    """

    size: tuple[int, int]

    kalibr_model = "equirectangular"
    # Column 0 and column W - 1 are neighbours (360 degrees of longitude).
    wraps_columns = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "size", _checked_size(self.size))

    @property
    def optical_axis(self) -> np.ndarray:
        """(3,) direction of the image centre (+z)."""
        return np.array([0.0, 0.0, 1.0])

    @property
    def panorama_axis(self) -> np.ndarray:
        """(3,) the up direction (-y), about which columns turn."""
        return np.array([0.0, -1.0, 0.0])

    @property
    def field_of_view_rad(self) -> float:
        """The whole sphere: 2 pi."""
        return 2.0 * np.pi

    def scaled(self, factor: float) -> "EquirectangularModel":
        """The same camera at ``factor`` times the resolution."""
        if not factor > 0:
            raise ValueError(f"scale factor must be positive, got {factor}")
        return replace(self, size=(int(round(self.height * factor)), int(round(self.width * factor))))

    def rays_from_pixels(self, pixels) -> np.ndarray:
        """Unit rays ``(..., 3)`` of ``(row, col)`` pixels ``(..., 2)``."""
        pixels = _check_pixels(pixels)
        lon = (pixels[..., 1] + 0.5) * (2.0 * np.pi / self.width) - np.pi
        lat = 0.5 * np.pi - (pixels[..., 0] + 0.5) * (np.pi / self.height)
        cl = np.cos(lat)
        return np.stack([cl * np.sin(lon), -np.sin(lat), cl * np.cos(lon)], axis=-1)

    def pixels_from_rays(self, rays) -> np.ndarray:
        """``(row, col)`` pixels ``(..., 2)`` of rays ``(..., 3)``; columns in ``[-0.5, W - 0.5)``."""
        rays = _check_rays(rays)
        x, y, z = rays[..., 0], rays[..., 1], rays[..., 2]
        lon = np.arctan2(x, z)
        lat = np.arctan2(-y, np.hypot(x, z))
        col = (lon + np.pi) * (self.width / (2.0 * np.pi)) - 0.5
        row = (0.5 * np.pi - lat) * (self.height / np.pi) - 0.5
        return np.stack([row, col], axis=-1)

    def valid_pixels(self, pixels) -> np.ndarray:
        """``(...,)`` bool: inside the image (every pixel of the image is valid)."""
        return self.inside_image(_check_pixels(pixels))


def check_usable_region(model) -> None:
    """Raise ``ValueError`` unless a Kalibr model images a usable region about its principal point.

    The principal point must lie strictly inside the image (between the
    outermost pixel centres), its pixel must be in the valid region, and
    the angle one pixel subtends there must be finite and within
    :data:`MIN_PIXEL_ANGLE_RAD` .. :data:`MAX_PIXEL_ANGLE_RAD`. Extreme
    parameters (``xi`` of a million, a focal length of 1e-300 or 1e300 px)
    fail here instead of giving an empty or degenerate valid region.
    An equirectangular camera images the whole sphere and always passes.

    Parameters
    ----------
    model : camera model of this module
    """
    if isinstance(model, EquirectangularModel):
        return
    pu, pv = model.principal_point
    if not (0 < pu < model.width - 1 and 0 < pv < model.height - 1):
        raise ValueError(f"principal point (pu, pv) = ({pu:g}, {pv:g}) is outside the {model.width}x{model.height} "
                         f"image (expected 0 < pu < {model.width - 1}, 0 < pv < {model.height - 1})")
    centre = np.array([pv, pu])
    with np.errstate(all="ignore"):
        try:
            angle = float(angular_pixel_size(model, centre))
            valid = bool(model.valid_pixels(centre))
        except OverflowError:  # Python float arithmetic of parameters such as xi = 1e300
            angle, valid = float("nan"), False
    if not (valid and MIN_PIXEL_ANGLE_RAD <= angle <= MAX_PIXEL_ANGLE_RAD):
        size = f"{angle:.3g} rad" if np.isfinite(angle) else "no measurable angle (its rays do not lift)"
        raise ValueError(f"the camera images no usable region: one pixel at the principal point subtends "
                         f"{size}{'' if valid else ' and the pixel is outside the valid region'} "
                         f"(expected {MIN_PIXEL_ANGLE_RAD:g} to {MAX_PIXEL_ANGLE_RAD:g} rad)")


# Kalibr camera_model name -> model classes that carry it.
KALIBR_MODELS = ("pinhole", "omni", "eucm", "ds", "equirectangular")
