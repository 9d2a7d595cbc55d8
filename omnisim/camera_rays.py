"""Camera-frame rays of film pixels for the Kalibr and equirectangular models, in drjit.

The renderer's sensor (:mod:`omnisim.sensor`) calls :func:`rays_from_film`
with the pixel ``(row, col)`` of each sample; the formulas are those of
:mod:`ifmi.geometry.camera_models` (same camera frames: x along columns, y along
rows, z the optical axis; equirectangular: -y up), evaluated in float32.

A model's calibration travels as one short flat list (:func:`ray_parameters`);
from it and the film size, :func:`kernel_data` derives what the ray code
reads: a few scalars and one lookup table. The sensor stores both as opaque
JIT variables, so a new calibration of the same model (any image size)
reuses the compiled kernel; only the model kind (and, for the unified model,
whether it has radtan distortion) changes the kernel.

The radtan undistortion needs no iteration in the kernel: a dense table
(:func:`undistortion_table`) holds the normalised undistorted coordinates of
nodes on a grid over the image (every pixel, or every half or quarter pixel
where a pixel spacing would not be exact enough), computed by the numpy
model's converged Newton inversion, and the kernel interpolates it
bilinearly (four gathers). The bilinear error on a cell of side ``h`` is at
most ``h^2 / 8 (|f_rr| + |f_cc|)`` (maximum second derivatives on the cell);
that bound, carried to image pixels through the distortion's Jacobian, is
computed for every table and kept below :data:`TABLE_ERROR_TARGET_PX`, the
models' own round-trip tolerance, wherever the distortion is smooth enough
for it. Next to a fold of the radial distortion (where it turns back inside
the image) the inverse is singular and no grid is exact: cells whose bound
exceeds :data:`CELL_TOLERANCE_PX` are left out, so a band a few pixels wide
inside the fold is black instead of wrong. The valid region lives in the
same table: invalid nodes hold a huge sentinel, and a sample that draws on
one comes out beyond any image and is marked invalid (black).
The Kannala-Brandt model needs no iteration either: ``sin(theta) / theta_d``
and ``cos(theta)`` are tabulated against ``theta_d`` (``KB_TABLE_SIZE``
samples of the numpy model's exact inversion), and linear interpolation in
them is exact to ~1e-7 rad.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ifmi.geometry.camera import VALID_ROUND_TRIP_PX

__all__ = ["RAY_KINDS", "KB_TABLE_SIZE", "TABLE_ERROR_TARGET_PX", "CELL_TOLERANCE_PX", "MAX_TABLE_NODES",
           "UndistortionTable",
           "ray_kind", "ray_parameters", "parameter_count", "model_from_parameters", "undistortion_table",
           "kernel_data", "rays_from_film"]

# Kinds of ray code: one compiled kernel each.
RAY_KINDS = ("unified", "unified_radtan", "eucm", "ds", "kb", "equirectangular")
# Entries of each Kannala-Brandt table: at a spacing of about 0.001 in theta_d, linear
# interpolation of sin(theta)/theta_d and cos(theta) errs by ~1e-7 (their second
# derivatives are of order one).
KB_TABLE_SIZE = 2048
# The undistortion table's interpolation bound must stay below the models' round-trip tolerance.
TABLE_ERROR_TARGET_PX = VALID_ROUND_TRIP_PX
# Cells whose interpolation bound exceeds this (px) are not rendered (black): the exactness
# the renderer promises (position reprojection within 0.01 px).
CELL_TOLERANCE_PX = 0.01
# Largest undistortion table (nodes; 16 bytes each in the kernel): finer spacings than a
# pixel are tried only below it.
MAX_TABLE_NODES = 4_000_000
# Nodes per pixel along each axis, tried in turn until the interpolation bound meets the target.
_TABLE_SUBDIVISIONS = (1, 2, 4)
# Spacing (px) of the first, coarse solution from which the pixel table's iteration starts.
_COARSE_SPACING_PX = 8.0
# Row and column of the table's first node: half a pixel beyond the image's edge (-0.5).
_TABLE_ORIGIN_PX = -1.0
# Value of both coordinates of an invalid node. A sample on a cell with an invalid corner
# draws at least a fraction of ~6e-8 from it (the ulp of its table coordinate, >= 0.5), so
# its squared radius exceeds 1e21, far beyond _MAX_RADIUS2; squares stay finite in float32.
_INVALID_NODE = 1e18
# Squared normalised radius beyond which a table sample is invalid (radius 1e6: a ray a
# micro-radian from the image plane, beyond any real image).
_MAX_RADIUS2 = 1e12
# The Kannala-Brandt table reaches this factor beyond the largest distorted radius of the image.
_TABLE_MARGIN = 1.05
# Calibration values per kind (ray_parameters).
_PARAMETER_COUNTS = {"unified": 5, "unified_radtan": 9, "eucm": 6, "ds": 6, "kb": 8, "equirectangular": 2}


def ray_kind(model) -> str:
    """Kind of ray code for an :mod:`ifmi.geometry.camera_models` model (one of :data:`RAY_KINDS`)."""
    from ifmi.geometry.camera_models import (DoubleSphereModel, EquirectangularModel, ExtendedUnifiedModel,
                                    KannalaBrandtModel, UnifiedModel)

    if isinstance(model, UnifiedModel):
        return "unified_radtan" if model.distortion else "unified"
    for cls, kind in ((ExtendedUnifiedModel, "eucm"), (DoubleSphereModel, "ds"),
                      (KannalaBrandtModel, "kb"), (EquirectangularModel, "equirectangular")):
        if isinstance(model, cls):
            return kind
    raise ValueError(f"no renderer ray code for a {type(model).__name__}")


def ray_parameters(model) -> list[float]:
    """A model's calibration as a flat list, in Kalibr's orders.

    unified: ``xi fu fv pu pv [k1 k2 p1 p2]``; eucm: ``alpha beta fu fv pu pv``;
    ds: ``xi alpha fu fv pu pv``; kb: ``fu fv pu pv k1 k2 k3 k4``;
    equirectangular: ``height width``. :func:`model_from_parameters` inverts it.
    """
    kind = ray_kind(model)
    if kind.startswith("unified"):
        values = [model.xi, *model.focal, *model.principal_point, *model.distortion]
    elif kind == "eucm":
        values = [model.alpha, model.beta, *model.focal, *model.principal_point]
    elif kind == "ds":
        values = [model.xi, model.alpha, *model.focal, *model.principal_point]
    elif kind == "kb":
        values = [*model.focal, *model.principal_point, *model.distortion]
    else:
        values = [model.height, model.width]
    return [float(v) for v in values]


def parameter_count(kind: str) -> int:
    """Length of :func:`ray_parameters` for ``kind``."""
    if kind not in _PARAMETER_COUNTS:
        raise ValueError(f"unknown ray kind {kind!r}; expected one of {RAY_KINDS}")
    return _PARAMETER_COUNTS[kind]


def model_from_parameters(kind: str, values, size):
    """The :mod:`ifmi.geometry.camera_models` model of ``kind`` with calibration ``values`` and image ``size``.

    Parameters
    ----------
    kind : str
        One of :data:`RAY_KINDS`.
    values : (parameter_count(kind),) sequence of float
        As :func:`ray_parameters` returns them.
    size : (2,) sequence of int
        Image ``(height, width)`` (the film's); an equirectangular model takes it
        instead of its two values.

    Raises
    ------
    ValueError
        If the number of values is wrong or the model rejects them.
    """
    from ifmi.geometry.camera_models import (DoubleSphereModel, EquirectangularModel, ExtendedUnifiedModel,
                                    KannalaBrandtModel, UnifiedModel)

    values = [float(v) for v in values]
    if len(values) != parameter_count(kind):
        raise ValueError(f"expected {parameter_count(kind)} {kind} parameters, got {len(values)}")
    size = (int(size[0]), int(size[1]))
    if kind.startswith("unified"):
        return UnifiedModel(values[0], values[1:3], values[3:5], size, tuple(values[5:]))
    if kind == "eucm":
        return ExtendedUnifiedModel(values[0], values[1], values[2:4], values[4:6], size)
    if kind == "ds":
        return DoubleSphereModel(values[0], values[1], values[2:4], values[4:6], size)
    if kind == "kb":
        return KannalaBrandtModel(values[0:2], values[2:4], size, tuple(values[4:8]))
    return EquirectangularModel(size)


@dataclass(frozen=True)
class UndistortionTable:
    """Normalised undistorted coordinates of a radtan model on a grid of image positions.

    Node ``(i, j)`` sits at pixel ``(row, col) = (-1 + i * spacing_px, -1 + j * spacing_px)``;
    the grid reaches beyond every film position of the image (``[-0.5, H - 0.5]`` x
    ``[-0.5, W - 0.5]``).

    Attributes
    ----------
    spacing_px : float
        Node spacing (pixels): 1, 1/2 or 1/4.
    values : (n_rows, n_cols, 2) ndarray
        Undistorted normalised ``(x, y)`` (x along columns) of each node; NaN at
        nodes outside the model's valid domain (no converged inverse, or beyond
        the fold of the radial distortion).
    error_bound_px : float
        Largest bilinear interpolation error over the cells whose four nodes are
        valid, as reprojection error in image pixels (see :func:`undistortion_table`).
    cell_bounds_px : (n_rows - 1, n_cols - 1) ndarray
        That bound per cell (NaN where a corner is invalid).
    """

    spacing_px: float
    values: np.ndarray
    error_bound_px: float
    cell_bounds_px: np.ndarray

    @property
    def rendered_nodes(self) -> np.ndarray:
        """``(n_rows, n_cols)`` bool: valid nodes none of whose cells exceeds :data:`CELL_TOLERANCE_PX`.

        The renderer interpolates only between such nodes; a sample on a
        cell with another corner is black.
        """
        with np.errstate(invalid="ignore"):
            rough = self.cell_bounds_px > CELL_TOLERANCE_PX
        near_rough = np.zeros(self.values.shape[:2], dtype=bool)
        for dr_, dc in ((0, 0), (0, 1), (1, 0), (1, 1)):
            near_rough[dr_:dr_ + rough.shape[0], dc:dc + rough.shape[1]] |= rough
        return np.isfinite(self.values).all(axis=-1) & ~near_rough

    @property
    def rendered_error_bound_px(self) -> float:
        """The interpolation bound (pixels) over the cells the renderer draws (0 if none)."""
        nodes = self.rendered_nodes
        drawn = nodes[:-1, :-1] & nodes[:-1, 1:] & nodes[1:, :-1] & nodes[1:, 1:]
        return float(self.cell_bounds_px[drawn].max()) if drawn.any() else 0.0


def undistortion_table(model, *, target_px: float = TABLE_ERROR_TARGET_PX,
                       max_nodes: int = MAX_TABLE_NODES) -> UndistortionTable:
    """Dense undistortion table of a radtan-distorted unified (or pinhole) model.

    Spacings of 1, 1/2 and 1/4 pixel are tried in turn; the first whose
    interpolation bound is at most ``target_px`` is returned, else the finest
    one with at most ``max_nodes`` nodes (a pixel spacing at least).

    The bound of a cell is ``(|D_rr| + |D_cc|) / 8`` -- the largest second
    differences of the node values over the cell's corners, i.e. ``h^2``
    times the second derivatives in the classic bilinear bound
    ``h^2 / 8 (|f_rr| + |f_cc|)`` -- times the largest spectral norm over the
    corners of ``diag(fu, fv) J``, with ``J`` the distortion's Jacobian, which
    carries an error in undistorted coordinates to distorted image pixels.
    Second differences are taken where three consecutive nodes are valid.

    Parameters
    ----------
    model : ifmi.geometry.camera_models.UnifiedModel
        With radtan distortion (``PinholeModel`` included).
    target_px : float, keyword-only
        Wanted bound (pixels).
    max_nodes : int, keyword-only
        Largest number of nodes of a finer-than-pixel table.
    """
    if not getattr(model, "distortion", ()) or ray_kind(model) != "unified_radtan":
        raise ValueError(f"expected a unified or pinhole model with radtan distortion, got {model!r}")
    coarse = _table_at_spacing(model, _COARSE_SPACING_PX)
    table = _table_at_spacing(model, 1.0, coarse)
    # The bound scales with the square of the spacing: pick the subdivision that should meet it.
    for subdivisions in _TABLE_SUBDIVISIONS[1:]:
        shape = _table_shape(model.size, 1.0 / subdivisions)
        if table.error_bound_px <= target_px or shape[0] * shape[1] > max_nodes:
            break
        if table.error_bound_px / subdivisions ** 2 <= target_px or subdivisions == _TABLE_SUBDIVISIONS[-1]:
            table = _table_at_spacing(model, 1.0 / subdivisions, table)
            break
    return table


def _table_shape(size, spacing: float) -> tuple[int, int]:
    """Nodes (rows, cols) from -1 to at least one pixel beyond the last pixel centre."""
    return tuple(int(np.ceil((n + 1 - _TABLE_ORIGIN_PX) / spacing)) + 1 for n in size)


def _table_at_spacing(model, spacing: float, coarser: UndistortionTable | None = None) -> UndistortionTable:
    """The table at ``spacing``, solved by Newton's iteration from ``coarser`` interpolated (2-3 steps).

    Nodes all of whose coarser neighbours are invalid are invalid without
    iterating (beyond a fold most of the image may be, and there the
    iteration runs to its step limit).
    """
    from ifmi.geometry.camera_models import undistort_radtan

    n_rows, n_cols = _table_shape(model.size, spacing)
    rows = _TABLE_ORIGIN_PX + spacing * np.arange(n_rows)
    cols = _TABLE_ORIGIN_PX + spacing * np.arange(n_cols)
    distorted = model._normalised_from_pixels(np.stack(np.meshgrid(rows, cols, indexing="ij"), axis=-1))
    values = np.full_like(distorted, np.nan)
    if coarser is None:
        values = undistort_radtan(distorted, model.distortion)
    else:
        start = _interpolated(coarser.values, coarser.spacing_px, rows, cols)
        valid = np.isfinite(coarser.values).all(axis=-1).astype(np.float64)
        hopeful = _interpolated(valid, coarser.spacing_px, rows, cols) > 0
        values[hopeful] = undistort_radtan(distorted[hopeful], model.distortion, start=start[hopeful])
    with np.errstate(invalid="ignore"):
        values[np.sum(values * values, axis=-1) > model.max_undistorted_radius ** 2] = np.nan
    cells = _cell_error_bounds(model, values)
    finite = cells[np.isfinite(cells)]
    bound = float(finite.max()) if finite.size else 0.0
    return UndistortionTable(spacing, values, bound, cells)


def _interpolated(values: np.ndarray, spacing: float, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of node ``values`` (n_rows, n_cols, ...) on the grid ``rows`` x ``cols`` (pixels).

    Separable: along rows, then along columns; NaN next to NaN nodes.
    """
    for axis, positions in ((0, rows), (1, cols)):
        size = values.shape[axis]
        t = np.clip((positions - _TABLE_ORIGIN_PX) / spacing, 0.0, size - 1.0)
        first = np.minimum(np.floor(t).astype(int), size - 2)
        f = np.expand_dims(t - first, [a for a in range(values.ndim) if a != axis])
        values = np.take(values, first, axis=axis) * (1.0 - f) + np.take(values, first + 1, axis=axis) * f
    return values


def _cell_error_bounds(model, values: np.ndarray) -> np.ndarray:
    """Per-cell bilinear error bound (pixels); NaN where a corner is invalid."""
    from ifmi.geometry.camera_models import _radtan_jacobian

    def second_difference(axis: int) -> np.ndarray:
        out = np.full(values.shape[:2], np.nan)
        ahead, here, behind = (np.take(values, range(k, values.shape[axis] - 2 + k), axis=axis) for k in (2, 1, 0))
        inner = np.linalg.norm(ahead - 2.0 * here + behind, axis=-1)
        if axis == 0:
            out[1:-1] = inner
        else:
            out[:, 1:-1] = inner
        return out

    def cell_max(node: np.ndarray) -> np.ndarray:
        corners = np.stack([node[:-1, :-1], node[:-1, 1:], node[1:, :-1], node[1:, 1:]])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN corners give NaN
            return np.nanmax(corners, axis=0)

    curvature = (cell_max(second_difference(0)) + cell_max(second_difference(1))) / 8.0
    gain = np.array(model.focal)[:, None] * _radtan_jacobian(np.nan_to_num(values), model.distortion)
    # Spectral norm of each 2x2 matrix: sqrt((F + sqrt(F^2 - 4 det^2)) / 2), F the squared Frobenius norm.
    frobenius2 = np.sum(gain * gain, axis=(-2, -1))
    det = gain[..., 0, 0] * gain[..., 1, 1] - gain[..., 0, 1] * gain[..., 1, 0]
    gain = np.sqrt(0.5 * (frobenius2 + np.sqrt(np.maximum(frobenius2 ** 2 - 4.0 * det ** 2, 0.0))))
    valid = np.isfinite(values).all(axis=-1)
    cell_valid = valid[:-1, :-1] & valid[:-1, 1:] & valid[1:, :-1] & valid[1:, 1:]
    bounds = curvature * cell_max(gain)
    bounds[~cell_valid] = np.nan
    return bounds


def kernel_data(model) -> tuple[list[float], np.ndarray]:
    """What :func:`rays_from_film` reads for ``model``: scalars and one float32 lookup table.

    unified: ``xi fu fv pu pv``; unified_radtan: ``xi 1/spacing n_cols n_rows``
    with the :func:`undistortion_table` row by row, each node as ``(x, y)`` of
    itself and of its right-hand neighbour (nodes not rendered, see
    :attr:`UndistortionTable.rendered_nodes`, hold a huge sentinel); eucm, ds: as :func:`ray_parameters`; kb:
    ``fu fv pu pv 1/step theta_d_limit`` with the ``sin(theta) / theta_d`` and
    ``cos(theta)`` tables; equirectangular: ``height width``. Models without a
    table get a one-entry placeholder.
    """
    kind = ray_kind(model)
    placeholder = np.zeros(1, dtype=np.float32)
    if kind == "unified_radtan":
        table = undistortion_table(model)
        n_rows, n_cols = table.values.shape[:2]
        nodes = np.where(table.rendered_nodes[..., None], table.values, _INVALID_NODE)
        # Each entry holds a node and its right-hand neighbour: two 4-float loads per sample.
        pairs = np.concatenate([nodes, np.roll(nodes, -1, axis=1)], axis=-1)
        return [model.xi, 1.0 / table.spacing_px, float(n_cols), float(n_rows)], pairs.astype(np.float32).ravel()
    if kind == "kb":
        scalars, tables = _kannala_brandt_tables(model)
        return [*model.focal, *model.principal_point, *scalars], np.asarray(tables, dtype=np.float32)
    return ray_parameters(model), placeholder


def _kannala_brandt_tables(model) -> tuple[list[float], list[float]]:
    """``[1 / step, theta_d limit]``, and ``sin(theta) / theta_d`` then ``cos(theta)`` at ``KB_TABLE_SIZE`` steps.

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
    return [1.0 / step, float(theta_d[last])], [*ratio.tolist(), *rays[:, 2].tolist()]


def _largest_distorted_radius(model) -> float:
    """Largest normalised (distorted) radius of the image's corners."""
    (fu, fv), (pu, pv) = model.focal, model.principal_point
    u = np.array([-0.5, model.width - 0.5])
    v = np.array([-0.5, model.height - 0.5])
    return float(np.hypot(*np.meshgrid((u - pu) / fu, (v - pv) / fv)).max())


def _normalised(dr, p, row, col, first: int):
    fu, fv, pu, pv = p[first:first + 4]
    return (col - pu) / fu, (row - pv) / fv


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


def _grid_cell(dr, mi, position, inv_spacing, nodes):
    """First node index and fraction of a film position (pixels) along one axis of the undistortion table."""
    t = dr.clip(dr.fma(position, inv_spacing, -_TABLE_ORIGIN_PX * inv_spacing), 0.0, nodes - 1.0)
    index = dr.minimum(mi.UInt32(t), mi.UInt32(nodes) - 2)
    return index, t - mi.Float(index)


def _undistorted_from_table(dr, mi, p, table, row, col):
    """Bilinear interpolation of the undistortion table at ``(row, col)``: undistorted ``(x, y)``.

    Near a node that is not rendered the result is beyond ``_MAX_RADIUS2`` (the sentinel).
    """
    inv_spacing, n_cols, n_rows = p[1], p[2], p[3]
    r, fr = _grid_cell(dr, mi, row, inv_spacing, n_rows)
    c, fc = _grid_cell(dr, mi, col, inv_spacing, n_cols)
    stride = mi.UInt32(n_cols)
    first = r * stride + c
    upper = dr.gather(mi.Vector4f, table, first)
    lower = dr.gather(mi.Vector4f, table, first + stride)
    top_x, top_y = dr.fma(fc, upper.z - upper.x, upper.x), dr.fma(fc, upper.w - upper.y, upper.y)
    bottom_x, bottom_y = dr.fma(fc, lower.z - lower.x, lower.x), dr.fma(fc, lower.w - lower.y, lower.y)
    return dr.fma(fr, bottom_x - top_x, top_x), dr.fma(fr, bottom_y - top_y, top_y)


def _unified(dr, mi, p, table, row, col, radtan: bool):
    xi = p[0]
    if radtan:
        mx, my = _undistorted_from_table(dr, mi, p, table, row, col)
    else:
        mx, my = _normalised(dr, p, row, col, 1)
    r2 = dr.fma(mx, mx, my * my)
    arg = dr.fma(1.0 - xi * xi, r2, 1.0)
    factor = (xi + dr.sqrt(dr.maximum(arg, 0.0))) / (1.0 + r2)
    # A point of the unit sphere by construction: no normalisation needed.
    return mi.Vector3f(factor * mx, factor * my, factor - xi), (arg >= 0) & (r2 < _MAX_RADIUS2)


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
    scale = _table_lerp(dr, mi, table, 0, index, frac)
    z = _table_lerp(dr, mi, table, KB_TABLE_SIZE, index, frac)
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
        The scalars of :func:`kernel_data`, as width-1 opaque variables.
    table : mi.Float
        The lookup table of :func:`kernel_data` (opaque).
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
        return direction, ok
    if kind == "eucm":
        direction, ok = _eucm(dr, mi, params, row, col)
    elif kind == "ds":
        direction, ok = _double_sphere(dr, mi, params, row, col)
    elif kind == "kb":
        direction, ok = _kannala_brandt(dr, mi, params, table, row, col)
    elif kind == "equirectangular":
        direction, ok = _equirectangular(dr, mi, params, row, col)
    else:
        raise ValueError(f"unknown ray kind {kind!r}; expected one of {RAY_KINDS}")
    norm2 = dr.squared_norm(direction)
    ok = ok & (norm2 > 0) & dr.isfinite(norm2)
    return direction * dr.rsqrt(dr.select(ok, norm2, 1.0)), ok
