"""Camera-frame rays of film pixels for the Kalibr and equirectangular models, in drjit.

The renderer's sensor (:mod:`omnisim.sensor`) calls :func:`rays_from_film`
with the pixel ``(row, col)`` of each sample; the formulas are those of
:mod:`ifmi.camera_models` (same camera frames: x along columns, y along
rows, z the optical axis; equirectangular: -y up), evaluated in float32.

A model's parameters travel as one flat list (:func:`ray_parameters`) that
the sensor stores as opaque JIT variables, so a new calibration of the same
model reuses the compiled kernel; only the model kind (and, for the unified
model, whether it has radtan distortion) changes the kernel.

The radtan undistortion starts from a lookup table of the radial inverse
(``TABLE_SIZE`` samples of the undistorted against the distorted radius,
tangential terms left out, linearly interpolated) and then takes two Newton
steps, which converge quadratically to float32 precision from that start.
The Kannala-Brandt model needs no iteration at all: ``sin(theta) / theta_d``
and ``cos(theta)`` are tabulated against ``theta_d`` (``KB_TABLE_SIZE``
samples of the numpy model's exact inversion), and linear interpolation in
them is exact to ~1e-7 rad. Tables travel with the parameters (built by
:func:`ray_parameters`), so they are calibration data, not kernel code.
Samples outside a model's domain or valid region come back invalid (black
pixels).
"""

from __future__ import annotations

import numpy as np

__all__ = ["RAY_KINDS", "TABLE_SIZE", "KB_TABLE_SIZE", "ray_kind", "ray_parameters", "parameter_count", "scalar_count",
           "rays_from_film"]

# Kinds of ray code: one compiled kernel each.
RAY_KINDS = ("unified", "unified_radtan", "eucm", "ds", "kb", "equirectangular")
# Entries of the radial inverse table of the radtan model.
TABLE_SIZE = 512
# Entries of each Kannala-Brandt table: at a spacing of about 0.001 in theta_d, linear
# interpolation of sin(theta)/theta_d and cos(theta) errs by ~1e-7 (their second
# derivatives are of order one).
KB_TABLE_SIZE = 2048
# Newton steps of the radtan undistortion after the table's start: its error (below 1e-4
# normalised units for the tests' cameras, tangential terms of 1e-3 included) falls under
# float32 rounding in two quadratic steps (measured: max 3e-4 px over every valid pixel).
_NEWTON_STEPS = 2
# Stand-in (normalised radius) for "no fold" of a radtan distortion: beyond any image.
_NO_FOLD = 1e6
# Largest last Newton step (normalised units) of a converged radtan undistortion.
_LAST_STEP = 1e-3
# Dense samples of the forward radial map from which the inverse table is interpolated.
_TABLE_DENSE = 20000
# The table reaches this factor beyond the largest distorted radius of the image.
_TABLE_MARGIN = 1.05


def ray_kind(model) -> str:
    """Kind of ray code for an :mod:`ifmi.camera_models` model (one of :data:`RAY_KINDS`)."""
    from ifmi.camera_models import (DoubleSphereModel, EquirectangularModel, ExtendedUnifiedModel,
                                    KannalaBrandtModel, UnifiedModel)

    if isinstance(model, UnifiedModel):
        return "unified_radtan" if model.distortion else "unified"
    for cls, kind in ((ExtendedUnifiedModel, "eucm"), (DoubleSphereModel, "ds"),
                      (KannalaBrandtModel, "kb"), (EquirectangularModel, "equirectangular")):
        if isinstance(model, cls):
            return kind
    raise ValueError(f"no renderer ray code for a {type(model).__name__}")


def ray_parameters(model) -> list[float]:
    """Flat parameter list of a model, in the order :func:`rays_from_film` reads it.

    unified: ``xi fu fv pu pv [k1 k2 p1 p2 fold_radius^2 1/step table...]``; eucm:
    ``alpha beta fu fv pu pv``; ds: ``xi alpha fu fv pu pv``; kb:
    ``fu fv pu pv 1/step theta_d_limit sin-table... cos-table...``;
    equirectangular: ``height width``. Tables: :func:`_inverse_table`,
    :func:`_kannala_brandt_tables`.
    """
    kind = ray_kind(model)
    if kind.startswith("unified"):
        values = [model.xi, *model.focal, *model.principal_point, *model.distortion]
        if model.distortion:
            values.append(min(model.max_undistorted_radius, _NO_FOLD) ** 2)
    elif kind == "eucm":
        values = [model.alpha, model.beta, *model.focal, *model.principal_point]
    elif kind == "ds":
        values = [model.xi, model.alpha, *model.focal, *model.principal_point]
    elif kind == "kb":
        values = [*model.focal, *model.principal_point, *_kannala_brandt_tables(model)]
    else:
        values = [model.height, model.width]
    if kind == "unified_radtan":
        values += _inverse_table(model)
    return [float(v) for v in values]


def _kannala_brandt_tables(model) -> list[float]:
    """``[1 / step, theta_d limit]``, then ``sin(theta) / theta_d`` and ``cos(theta)`` at ``KB_TABLE_SIZE`` steps.

    Values come from the numpy model's own inversion along the image x
    axis; past the valid range (``theta_d`` beyond its increasing part) the
    last valid value repeats and the limit marks those samples invalid.
    """
    limit = _TABLE_MARGIN * _largest_distorted_radius(model)
    step = limit / (KB_TABLE_SIZE - 1)
    theta_d = np.arange(KB_TABLE_SIZE) * step
    fu, (pu, pv) = model.focal[0], model.principal_point
    rays = model.rays_from_pixels(np.stack([np.full_like(theta_d, pv), pu + fu * theta_d], axis=-1))
    valid = np.isfinite(rays).all(axis=1)
    last = int(np.flatnonzero(valid)[-1])
    rays[last + 1:] = rays[last]
    ratio = np.where(theta_d > 0, rays[:, 0] / np.where(theta_d > 0, theta_d, 1.0), 1.0)
    return [1.0 / step, float(theta_d[last]), *ratio.tolist(), *rays[:, 2].tolist()]


def _largest_distorted_radius(model) -> float:
    """Largest normalised (distorted) radius of the image's corners."""
    (fu, fv), (pu, pv) = model.focal, model.principal_point
    u = np.array([-0.5, model.width - 0.5])
    v = np.array([-0.5, model.height - 0.5])
    return float(np.hypot(*np.meshgrid((u - pu) / fu, (v - pv) / fv)).max())


def _inverse_table(model) -> list[float]:
    """``[1 / step] + TABLE_SIZE`` undistorted radii (radial radtan terms) at distorted radii ``0, step, ...``.

    Beyond the forward map's increasing range the last value repeats (the
    Newton steps then fail to converge and the sample is invalid).
    """
    limit = _TABLE_MARGIN * _largest_distorted_radius(model)
    k1, k2 = model.distortion[:2]
    reach = np.linspace(0.0, 4.0 * limit, _TABLE_DENSE)
    forward_x, forward_y = reach, reach * (1.0 + reach ** 2 * (k1 + k2 * reach ** 2))
    rising = np.flatnonzero(np.diff(forward_y) <= 0)
    stop = rising[0] + 1 if rising.size else len(forward_y)
    forward_x, forward_y = forward_x[:stop], forward_y[:stop]
    step = limit / (TABLE_SIZE - 1)
    table = np.interp(np.arange(TABLE_SIZE) * step, forward_y, forward_x)
    return [1.0 / step, *table.tolist()]


def _normalised(dr, p, row, col, first: int):
    fu, fv, pu, pv = p[first:first + 4]
    return (col - pu) / fu, (row - pv) / fv


def _radtan(dr, x, y, k1, k2, p1, p2):
    r2 = dr.fma(x, x, y * y)
    radial = 1.0 + r2 * (k1 + k2 * r2)
    dx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    dy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    dradial = 2.0 * (k1 + 2.0 * k2 * r2)
    jxx = radial + x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    jxy = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    jyy = radial + y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return dx, dy, jxx, jxy, jyy


def _table_index(dr, mi, inv_step, radius, size: int):
    """Index and fraction of ``radius`` in a table of ``size`` entries at spacing ``1 / inv_step``."""
    t = dr.clip(radius * inv_step, 0.0, size - 1.001)
    index = mi.UInt32(t)
    return index, t - mi.Float(index)


def _table_lerp(dr, mi, table, offset: int, index, frac):
    """Linear interpolation in ``table`` (entries from ``offset``) at ``index + frac``."""
    a = dr.gather(mi.Float, table, index + offset)
    b = dr.gather(mi.Float, table, index + offset + 1)
    return dr.fma(frac, b - a, a)


def _undistort_radtan(dr, mi, mx, my, k1, k2, p1, p2, fold2, inv_step, table):
    rd = dr.sqrt(dr.fma(mx, mx, my * my))
    index, frac = _table_index(dr, mi, inv_step, rd, TABLE_SIZE)
    ru = _table_lerp(dr, mi, table, scalar_count("unified_radtan"), index, frac)
    shrink = dr.select(rd > 0, ru / dr.maximum(rd, 1e-30), 1.0)
    x, y = mx * shrink, my * shrink
    for _ in range(_NEWTON_STEPS):
        dx, dy, jxx, jxy, jyy = _radtan(dr, x, y, k1, k2, p1, p2)
        ex, ey = dx - mx, dy - my
        det = jxx * jyy - jxy * jxy
        inv_det = dr.rcp(det)
        step_x, step_y = (jyy * ex - jxy * ey) * inv_det, (jxx * ey - jxy * ex) * inv_det
        x, y = x - step_x, y - step_y
    # Newton converges quadratically: after a last step below _LAST_STEP the error is of
    # its square (1e-6 normalised, far below a thousandth of a pixel); a diverging or
    # folded (det <= 0) iteration marks a pixel outside the valid region.
    ok = (dr.abs(step_x) < _LAST_STEP) & (dr.abs(step_y) < _LAST_STEP) & (det > 0)
    return x, y, ok & (dr.fma(x, x, y * y) <= fold2)


def _unified(dr, mi, p, table, row, col, radtan: bool):
    xi = p[0]
    mx, my = _normalised(dr, p, row, col, 1)
    ok = mi.Bool(True)
    if radtan:
        mx, my, ok = _undistort_radtan(dr, mi, mx, my, *p[5:11], table)
    r2 = dr.fma(mx, mx, my * my)
    arg = 1.0 + (1.0 - xi * xi) * r2
    factor = (xi + dr.sqrt(dr.maximum(arg, 0.0))) / (1.0 + r2)
    return mi.Vector3f(factor * mx, factor * my, factor - xi), ok & (arg >= 0)


def _eucm(dr, mi, p, row, col):
    alpha, beta = p[0], p[1]
    mx, my = _normalised(dr, p, row, col, 2)
    r2 = dr.fma(mx, mx, my * my)
    arg = 1.0 - (2.0 * alpha - 1.0) * beta * r2
    mz = (1.0 - beta * alpha * alpha * r2) / (alpha * dr.sqrt(dr.maximum(arg, 0.0)) + (1.0 - alpha))
    return mi.Vector3f(mx, my, mz), arg >= 0


def _double_sphere(dr, mi, p, row, col):
    xi, alpha = p[0], p[1]
    mx, my = _normalised(dr, p, row, col, 2)
    r2 = dr.fma(mx, mx, my * my)
    arg = 1.0 - (2.0 * alpha - 1.0) * r2
    mz = (1.0 - alpha * alpha * r2) / (alpha * dr.sqrt(dr.maximum(arg, 0.0)) + 1.0 - alpha)
    arg2 = mz * mz + (1.0 - xi * xi) * r2
    scale = (mz * xi + dr.sqrt(dr.maximum(arg2, 0.0))) / (mz * mz + r2)
    return mi.Vector3f(scale * mx, scale * my, scale * mz - xi), (arg >= 0) & (arg2 >= 0)


def _kannala_brandt(dr, mi, p, table, row, col):
    mx, my = _normalised(dr, p, row, col, 0)
    inv_step, limit = p[4], p[5]
    theta_d = dr.sqrt(dr.fma(mx, mx, my * my))
    index, frac = _table_index(dr, mi, inv_step, theta_d, KB_TABLE_SIZE)
    first = scalar_count("kb")
    scale = _table_lerp(dr, mi, table, first, index, frac)
    z = _table_lerp(dr, mi, table, first + KB_TABLE_SIZE, index, frac)
    return mi.Vector3f(scale * mx, scale * my, z), theta_d <= limit


def _equirectangular(dr, mi, p, row, col):
    height, width = p[0], p[1]
    lon = (col + 0.5) * (2.0 * dr.pi / width) - dr.pi
    lat = 0.5 * dr.pi - (row + 0.5) * (dr.pi / height)
    sin_lon, cos_lon = dr.sincos(lon)
    sin_lat, cos_lat = dr.sincos(lat)
    return mi.Vector3f(cos_lat * sin_lon, -sin_lat, cos_lat * cos_lon), mi.Bool(True)


def rays_from_film(dr, mi, kind: str, params: list, table, row, col):
    """Unit camera-frame rays of pixel positions ``(row, col)`` (drjit arrays, pixel centres at integers).

    Parameters
    ----------
    dr, mi : modules
        ``drjit`` and ``mitsuba`` (variant set).
    kind : str
        One of :data:`RAY_KINDS`.
    params : list of mi.Float
        The first :func:`scalar_count` parameters of :func:`ray_parameters`,
        as width-1 opaque variables.
    table : mi.Float
        All of :func:`ray_parameters` (opaque); lookup tables are read from it.
    row, col : mi.Float

    Returns
    -------
    direction : mi.Vector3f
        Unit ray in the model's camera frame.
    valid : mi.Bool
        False outside the model's valid region (those samples are black).
    """
    if kind in ("unified", "unified_radtan"):
        direction, ok = _unified(dr, mi, params, table, row, col, kind == "unified_radtan")
    elif kind == "eucm":
        direction, ok = _eucm(dr, mi, params, row, col)
    elif kind == "ds":
        direction, ok = _double_sphere(dr, mi, params, row, col)
    elif kind == "kb":
        direction, ok = _kannala_brandt(dr, mi, params, table, row, col)
    elif kind == "equirectangular":
        direction, ok = _equirectangular(dr, mi, params, row, col)
    else:
        raise ValueError(f"unknown ray kind {kind!r}; expected one of {RAY_KINDS}")
    norm = dr.norm(direction)
    ok = ok & (norm > 0) & dr.isfinite(norm)
    return direction / dr.select(ok, norm, 1.0), ok


def scalar_count(kind: str) -> int:
    """Number of scalar parameters of ``kind`` (before its lookup table, if any)."""
    return {"unified": 5, "unified_radtan": 11, "eucm": 6, "ds": 6, "kb": 6, "equirectangular": 2}[kind]


def parameter_count(kind: str) -> int:
    """Length of :func:`ray_parameters` for ``kind`` (scalars and lookup table)."""
    tables = {"unified_radtan": TABLE_SIZE, "kb": 2 * KB_TABLE_SIZE}
    return scalar_count(kind) + tables.get(kind, 0)
