"""Fit one camera model to another: the same camera, expressed in a different model.

Pixels are sampled over the source model's valid region and lifted to rays;
the target model's parameters are found by least squares
(``scipy.optimize.least_squares``) so that it projects those rays back onto
the same pixels. Both models share the image size.

Frames: the OCamCalib frame (x along rows, y along columns, z the mirror
axis; the central pixel looks along -z) and the Kalibr frame (x along
columns, y along rows, z the optical axis) differ by a fixed half turn,
``(x, y, z)_kalibr = (y, x, -z)_ocam``; rays are carried across it, so a
converted model sees the same scene point at the same pixel.

Targets (:data:`TARGETS`): ``omni`` (unified + radtan), ``pinhole``
(+ radtan), ``kb`` (Kannala-Brandt), ``eucm``, ``ds`` and ``ocamcalib``
(direct polynomial of degree 4 without the linear term, as OCamCalib fits,
with its centre and affine part; the inverse polynomial is refitted).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from ifmi.geometry.camera import (
    INVERSE_TOLERANCE_PX,
    OcamModel,
    check_affine,
    check_center_inside,
    model_from_direct_polynomial,
    valid_mask,
)
from ifmi.geometry.camera_models import (
    DoubleSphereModel,
    ExtendedUnifiedModel,
    KannalaBrandtModel,
    PinholeModel,
    UnifiedModel,
    check_usable_region,
)
from ifmi.spectral.panorama import inverse_polynomial_error

__all__ = ["TARGETS", "CalibrationFit", "fit_camera_model", "reprojection_errors", "rays_in_frame_of",
           "percent_below"]

TARGETS = ("omni", "pinhole", "kb", "eucm", "ds", "ocamcalib")
# OCamCalib frame -> Kalibr frame (a proper rotation, its own inverse).
_OCAM_TO_KALIBR = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
# Residual (px) given to a sample the target cannot project, so the fit moves away from it.
_UNSEEN_RESIDUAL_PX = 1e3
# Samples per image side of the fitting grid, and the stride (px) of the error grid.
_FIT_GRID = 60
# Starting alphas of the double-sphere fit (see _kalibr_builder).
_DS_START_ALPHAS = (0.5, 0.6)
# Grids of the radial pre-fit (see _radial_start): EUCM (beta, alpha), double sphere (xi, alpha).
# The good basins are narrow in alpha (the double sphere of tests/camera_examples.py's
# omni-radtan camera: a 0.05 step in alpha misses it), hence a fine alpha step.
_SCAN_ALPHAS = np.linspace(0.0, 1.0, 201)
_EUCM_SCAN_BETAS = np.geomspace(0.05, 50.0, 40)
_DS_SCAN_XIS = np.linspace(-0.95, 1.5, 50)
# Every this many fitting samples enter the radial pre-fit (a radial profile needs few).
_SCAN_STRIDE = 4
_CHECK_STRIDE_PX = 2
# Fewest fitting samples in the source's valid region: their residuals (two or three each)
# must outnumber the nine parameters of the largest target model with room to spare.
_MIN_FIT_SAMPLES = 10


@dataclass(frozen=True)
class CalibrationFit:
    """Result of :func:`fit_camera_model`.

    Attributes
    ----------
    model : camera model
        The fitted target model.
    max_error_px, median_error_px : float
        Reprojection error of the source's rays through the fitted model,
        over the part of the source's valid region (every second pixel) that
        the fitted model sees (all of it when ``coverage`` is 1), pixels.
    coverage : float
        Fraction of those pixels the fitted model sees at all (1.0 when it
        can represent the whole valid region).
    success : bool
    reason : str
    target_from_source : (3, 3) ndarray
        Rotation carrying directions of the source's camera frame into the
        fitted model's (the identity when both keep one toolbox's frame;
        the half turn of the module notes between OCamCalib and Kalibr).
        A camera rotation ``R`` estimated with the source is
        ``T R T^T`` with the fitted model, ``T`` this matrix.
    """

    model: object
    max_error_px: float
    median_error_px: float
    coverage: float
    success: bool
    reason: str = ""
    target_from_source: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def changes_frame(self) -> bool:
        """Whether the fitted model's camera frame differs from the source's."""
        return not np.array_equal(self.target_from_source, np.eye(3))


def rays_in_frame_of(rays: np.ndarray, source, target) -> np.ndarray:
    """``(..., 3)`` rays of ``source``'s frame expressed in ``target``'s frame.

    ``source`` and ``target`` are models, or ``"ocamcalib"`` / ``"kalibr"`` naming a frame.
    """
    def is_ocam(model):
        return model == "ocamcalib" if isinstance(model, str) else isinstance(model, OcamModel)

    if is_ocam(source) == is_ocam(target):
        return rays
    return rays @ _OCAM_TO_KALIBR.T


def _samples(model, per_side: int) -> np.ndarray:
    rows = np.linspace(0, model.height - 1, per_side)
    cols = np.linspace(0, model.width - 1, per_side)
    grid = np.stack(np.meshgrid(rows, cols, indexing="ij"), axis=-1).reshape(-1, 2)
    return grid[model.valid_pixels(grid)]


def reprojection_errors(source, target, pixels: np.ndarray) -> np.ndarray:
    """``(N,)`` distance (px) between ``pixels`` (N, 2) of ``source`` and the target's projection of their rays.

    NaN where the target cannot project the ray.
    """
    rays = rays_in_frame_of(source.rays_from_pixels(pixels), source, target)
    return np.hypot(*(target.pixels_from_rays(rays) - pixels).T)


def _axis_pixel_and_scale(source) -> tuple[np.ndarray, float]:
    """Pixel (row, col) of the source's optical axis, and its focal scale there (px per radian)."""
    centre = source.pixels_from_rays(source.optical_axis)
    ray0, ray1 = source.rays_from_pixels(np.array([centre, centre + [0.0, 1.0]]))
    return centre, 1.0 / np.arccos(np.clip(ray0 @ ray1, -1.0, 1.0))


def _checked_start(source, pixels: np.ndarray) -> tuple[np.ndarray, float]:
    """:func:`_axis_pixel_and_scale`, after checking that the source gives a fit something to start from.

    Raises
    ------
    ValueError
        Too few sample pixels in the source's valid region, or an optical axis
        that images outside the image or with a degenerate pixel angle.
    """
    if len(pixels) < _MIN_FIT_SAMPLES:
        raise ValueError(f"the camera's valid region holds {len(pixels)} of the {_FIT_GRID}x{_FIT_GRID} sample "
                         f"pixels, at least {_MIN_FIT_SAMPLES} are needed to fit a model to it")
    with np.errstate(all="ignore"):
        centre, scale = _axis_pixel_and_scale(source)
    if not (np.all(np.isfinite(centre)) and np.isfinite(scale) and scale > 0):
        raise ValueError(f"the camera's optical axis images at pixel (row, col) = ({centre[0]:.6g}, "
                         f"{centre[1]:.6g}) with {1.0 / scale:.3g} rad per pixel; expected a finite pixel and "
                         f"pixel angle to start the fit from")
    return centre, scale


def _check_fitted(model, target: str) -> None:
    """Raise ``ValueError`` unless the fitted model is a calibration that reads back (see :mod:`ifmi.io`)."""
    try:
        if not isinstance(model, OcamModel):
            check_usable_region(model)
            return
        for name, check, args in (("affine (c d e)", check_affine, (model.affine,)),
                                  ("center (row col)", check_center_inside, (model.center, model.size))):
            try:
                check(*args)
            except ValueError as exc:
                raise ValueError(f"{name}: {exc}") from None
        error, radius = inverse_polynomial_error(model)
        if not error <= INVERSE_TOLERANCE_PX:
            raise ValueError(f"its inverse polynomial does not invert the direct one: round-trip error "
                             f"{error:.3g} px at radius {radius:.1f} px, at most {INVERSE_TOLERANCE_PX} px accepted")
    except ValueError as exc:
        raise ValueError(f"this camera cannot be converted to {target}: the fitted model is no valid "
                         f"calibration ({exc})") from None


def _kalibr_builder(kind: str, size):
    """(initial parameters given (pp, f), model from parameters) for a Kalibr target.

    EUCM and the double sphere also start from their best radial shape
    (:func:`_radial_start`); every start is fitted and the best kept.
    The double sphere gets a list of starts: with
    ``xi = 0``, ``alpha = 0.5`` (the unified model with ``xi = 1``) it projects every
    ray but the backward one, so cameras seeing beyond 180 degrees start with every
    sample projectable (a sample it cannot project gives a constant residual, no
    gradient, and the fit wanders off to a far local minimum); ``alpha = 0.6`` suits
    narrower lenses.
    """
    def split(p, k):
        return (p[k], p[k + 1]), (p[k + 2], p[k + 3])

    if kind == "omni":
        # xi = q^2 >= 0 for any q: the optimiser moves freely, and xi = 0 (a pinhole) is reachable.
        return (lambda pp, f: [1.0, 2 * f, 2 * f, *pp, 0, 0, 0, 0],
                lambda p: UnifiedModel(p[0] ** 2, *split(p, 1), size, tuple(p[5:9])))
    if kind == "pinhole":
        return (lambda pp, f: [f, f, *pp, 0, 0, 0, 0],
                lambda p: PinholeModel.create(*split(p, 0), size, tuple(p[4:8])))
    if kind == "kb":
        return (lambda pp, f: [f, f, *pp, 0, 0, 0, 0],
                lambda p: KannalaBrandtModel(*split(p, 0), size, tuple(p[4:8])))
    if kind == "eucm":
        return (lambda pp, f: [0.6, 1.0, f, f, *pp],
                lambda p: ExtendedUnifiedModel(np.clip(p[0], 0, 1), max(p[1], 1e-6), *split(p, 2), size))
    if kind == "ds":
        return (lambda pp, f: [[0.0, alpha, f, f, *pp] for alpha in _DS_START_ALPHAS],
                lambda p: DoubleSphereModel(p[0], np.clip(p[1], 0, 1), *split(p, 2), size))
    raise ValueError(f"unknown target model {kind!r}; expected one of {TARGETS}")


def _radial_start(kind: str, rays: np.ndarray, pixels: np.ndarray, centre: np.ndarray):
    """Shape parameters and focal length of the best radially symmetric ``kind`` on a grid, or None.

    The image radius of each sample is ``f g(theta)`` for the model's radial
    function ``g`` of the angle from the axis; for every grid point of
    (alpha, beta) (EUCM) or (xi, alpha) (double sphere) ``f`` follows in
    closed form (linear least squares), and the point with the smallest
    squared error wins. Grids where a sample is unprojectable are skipped.
    Only ``eucm`` and ``ds`` have a pre-fit.
    """
    if kind not in ("eucm", "ds"):
        return None
    rays, pixels = rays[::_SCAN_STRIDE], pixels[::_SCAN_STRIDE]
    radius = np.hypot(*(pixels - centre).T)
    sin, cos = np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2]
    alpha = _SCAN_ALPHAS[:, None]
    best, best_cost = None, np.inf
    for value in _EUCM_SCAN_BETAS if kind == "eucm" else _DS_SCAN_XIS:
        if kind == "eucm":  # value = beta
            denom = alpha * np.sqrt(value * sin * sin + cos * cos) + (1.0 - alpha) * cos
        else:  # value = xi
            shifted = value + cos
            denom = alpha * np.hypot(sin, shifted) + (1.0 - alpha) * shifted
        with np.errstate(divide="ignore", invalid="ignore"):
            g = sin / denom
            f = np.sum(g * radius, axis=1) / np.sum(g * g, axis=1)
            cost = np.sum((f[:, None] * g - radius) ** 2, axis=1)
        cost[~np.all(denom > 0, axis=1) | ~(f > 0)] = np.inf
        k = int(np.argmin(cost))
        if cost[k] < best_cost:
            a = float(_SCAN_ALPHAS[k])
            best, best_cost = ((a, value) if kind == "eucm" else (value, a)) + (float(f[k]),), cost[k]
    return best


def _fit_kalibr(source, kind: str, pixels: np.ndarray):
    initial, build = _kalibr_builder(kind, source.size)
    centre, scale = _checked_start(source, pixels)
    rays = rays_in_frame_of(source.rays_from_pixels(pixels), source, "kalibr")

    def residuals(p):
        try:
            projected = build(p).pixels_from_rays(rays)
        except ValueError:
            return np.full(2 * len(pixels), _UNSEEN_RESIDUAL_PX)
        return np.nan_to_num((projected - pixels).ravel(), nan=_UNSEEN_RESIDUAL_PX)

    # Principal point (u, v) = (col, row) of the axis pixel; one start, or a list of them.
    starts = np.atleast_2d(np.asarray(initial((centre[1], centre[0]), scale), dtype=np.float64))
    radial = _radial_start(kind, rays, pixels, centre)
    if radial is not None:  # the best radial shape as one more start
        starts = np.vstack([starts, [radial[0], radial[1], radial[2], radial[2], centre[1], centre[0]]])
    solutions = [least_squares(residuals, start, method="lm", x_scale="jac", max_nfev=4000) for start in starts]
    return build(min(solutions, key=lambda solution: solution.cost).x)


def _fit_ocamcalib(source, pixels: np.ndarray) -> OcamModel:
    centre, scale = _checked_start(source, pixels)
    rays = rays_in_frame_of(source.rays_from_pixels(pixels), source, "ocamcalib")

    def build(p):
        pol = (p[5], 0.0, p[6], p[7], p[8])
        return OcamModel(pol=pol, invpol=(1.0,), center=(p[0], p[1]), affine=(p[2], p[3], p[4]), size=source.size)

    def residuals(p):
        model = build(p)
        lifted = model.rays_from_pixels(pixels)
        # Angle residuals in pixels at the centre's scale (the inverse polynomial is fitted afterwards).
        return (np.cross(lifted, rays) * scale).ravel()

    start = np.array([centre[0], centre[1], 1.0, 0.0, 0.0, -scale, 0.0, 0.0, 0.0])
    solution = least_squares(residuals, start, method="lm", x_scale="jac", max_nfev=4000)
    p = solution.x
    try:
        return model_from_direct_polynomial((p[5], 0.0, p[6], p[7], p[8]), center=(p[0], p[1]), size=source.size,
                                            affine=(p[2], p[3], p[4]))
    except ValueError as exc:  # e.g. a fitted polynomial whose elevation does not grow from the centre
        raise ValueError(f"this camera cannot be converted to ocamcalib: the fitted model has no inverse ({exc})") \
            from None


def fit_camera_model(source, target: str) -> CalibrationFit:
    """Fit a ``target`` model (one of :data:`TARGETS`) to the ``source`` camera model.

    Parameters
    ----------
    source : camera model
        Any model of :mod:`ifmi.geometry.camera` / :mod:`ifmi.geometry.camera_models`
        (equirectangular cameras are no source: no lens model fits them).
    target : str

    Returns
    -------
    CalibrationFit
        The fitted model and its reprojection errors over the source's
        valid region (pixels); ``success`` is False when the fitted model
        sees less than the whole valid region.

    Raises
    ------
    ValueError
        For an equirectangular source, an OCamCalib source looking along +z,
        a pinhole target for a camera seeing 180 degrees or more (a
        pinhole images less than a half space), a source whose valid region
        or optical axis gives the fit nothing to start from, or a fitted
        model that is no valid calibration (it would not read back: see
        :func:`ifmi.io.calib.parse_calib`, :func:`ifmi.io.kalibr.parse_kalibr`).
    """
    if target not in TARGETS:
        raise ValueError(f"unknown target model {target!r}; expected one of {TARGETS}")
    if getattr(source, "wraps_columns", False):
        raise ValueError("an equirectangular camera has no lens model to convert to")
    if target == "pinhole" and source.field_of_view_rad >= np.pi:
        raise ValueError(f"a pinhole model sees less than 180 degrees, this camera "
                         f"{np.degrees(source.field_of_view_rad):.0f} degrees; convert to omni, ds, eucm or kb")
    if isinstance(source, OcamModel) and source.pol[0] >= 0:
        raise ValueError("the OCamCalib model's central ray points along +z; only -z has a Kalibr frame")
    pixels = _samples(source, _FIT_GRID)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        model = _fit_ocamcalib(source, pixels) if target == "ocamcalib" else _fit_kalibr(source, target, pixels)
        _check_fitted(model, target)
        check = valid_mask(source)
        rows, cols = np.nonzero(check[::_CHECK_STRIDE_PX, ::_CHECK_STRIDE_PX])
        grid = np.stack([rows, cols], axis=-1).astype(np.float64) * _CHECK_STRIDE_PX
        errors = reprojection_errors(source, model, grid)
    seen = np.isfinite(errors)
    coverage = float(seen.mean())
    reason = "" if coverage == 1.0 else f"the {target} model sees only {percent_below(coverage)} % of the valid region"
    return CalibrationFit(model=model, max_error_px=float(np.max(errors[seen])) if seen.any() else np.inf,
                          median_error_px=float(np.median(errors[seen])) if seen.any() else np.inf,
                          coverage=coverage, success=coverage == 1.0, reason=reason,
                          target_from_source=rays_in_frame_of(np.eye(3), source, model).T)


def percent_below(fraction: float) -> str:
    """``fraction`` as a percentage with one decimal, rounded down (99.96 % shows as 99.9, never 100.0)."""
    return f"{np.floor(1000.0 * fraction) / 10.0:.1f}"
