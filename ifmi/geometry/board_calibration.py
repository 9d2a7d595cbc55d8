"""Calibrate the unified (Mei) camera model from images of a planar checkerboard.

The inner corners of a checkerboard, detected in several images, fix the
camera's intrinsics and each image's board pose. This module fits them
jointly by nonlinear least squares (``scipy.optimize.least_squares``) over
the reprojection error in pixels, for the unified model of
:class:`~ifmi.geometry.camera_models.UnifiedModel` (Kalibr ``omni``, with
or without ``radtan`` distortion): a catadioptric camera with a parabolic
mirror is the model with ``xi = 1``, one with a hyperbolic mirror has
``0 < xi < 1``.

The fit starts from a given model (for a parabolic mirror,
:func:`parabolic_start`: ``xi = 1``, the principal point at the centre of
the mirror's circle, the focal length from its radius). Each board's
starting pose comes from the corners' rays under that model: the rays are
turned so that their mean direction is the z axis, projected onto the
plane ``z = 1``, and the board-to-plane homography (direct linear
transform) is split into a rotation and a translation.

Frames: the Kalibr camera frame (x along columns, y along rows, z the
optical axis). Board points lie in the board's plane ``z = 0``, in metres.
Pixels are ``(row, col)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ifmi.geometry.camera_models import UnifiedModel

__all__ = ["BoardFitConfig", "BoardCalibration", "board_points", "parabolic_start", "pose_from_rays",
           "fit_unified_to_boards"]

# Residual (px) given to a corner the model cannot project, so the fit moves away from it.
_UNSEEN_RESIDUAL_PX = 1e3
# Unknowns per board pose: rotation vector (3) and translation (3).
_POSE_SIZE = 6
# Fewest corners per board for a pose (a homography has eight unknowns, two equations per corner).
_MIN_CORNERS = 4


@dataclass(frozen=True)
class BoardFitConfig:
    """Options of :func:`fit_unified_to_boards`.

    Attributes
    ----------
    distortion : bool
        Fit the four ``radtan`` coefficients ``(k1, k2, p1, p2)`` too.
    max_evaluations : int
        Most residual evaluations of the least-squares solver.
    """

    distortion: bool = True
    max_evaluations: int = 20000


@dataclass(frozen=True)
class BoardCalibration:
    """Result of :func:`fit_unified_to_boards`.

    Attributes
    ----------
    model : UnifiedModel
        The fitted camera.
    camera_from_board : tuple of ((3, 3) ndarray, (3,) ndarray)
        Each board's pose: rotation and translation (metres) carrying
        board points into the camera frame.
    residuals_px : (V, N, 2) ndarray
        Projected minus detected corners, ``(row, col)``, pixels.
    rms_px : float
        Root mean square of the reprojection errors' lengths over every corner, pixels.
    success : bool
        Whether the solver converged.
    """

    model: UnifiedModel
    camera_from_board: tuple
    residuals_px: np.ndarray
    rms_px: float
    success: bool

    @property
    def per_view_rms_px(self) -> np.ndarray:
        """(V,) ndarray: RMS reprojection error of each board, pixels."""
        return np.sqrt(np.mean(np.sum(self.residuals_px ** 2, axis=-1), axis=-1))


def board_points(rows: int, cols: int, square_m: float) -> np.ndarray:
    """Inner corners of a checkerboard in its own plane, in OpenCV's order.

    Parameters
    ----------
    rows, cols : int
        Inner corners per column and per row of the pattern (OpenCV's
        pattern size is ``(cols, rows)``).
    square_m : float
        Side of one square, metres.

    Returns
    -------
    (rows * cols, 3) ndarray
        ``(x, y, 0)`` in metres, row after row, x along a row.
    """
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64) * float(square_m)
    return np.stack([x.ravel(), y.ravel(), np.zeros(rows * cols)], axis=-1)


def parabolic_start(centre_px, horizon_radius_px: float, size) -> UnifiedModel:
    """Unified model of a parabolic mirror: ``xi = 1``, principal point ``centre_px``.

    With ``xi = 1`` a ray at angle ``theta`` from the axis lands at image
    radius ``f tan(theta / 2)``, so the rays at right angles to the axis (the
    horizon) lie on the circle of radius ``f``.

    Parameters
    ----------
    centre_px : (2,) sequence
        ``(row, col)`` of the mirror's centre, pixels.
    horizon_radius_px : float
        Image radius of the horizon (for a start, the mirror's rim), pixels.
    size : (2,) sequence of int
        Image ``(height, width)``.
    """
    f = float(horizon_radius_px)
    return UnifiedModel(1.0, (f, f), (float(centre_px[1]), float(centre_px[0])), tuple(size))


def _rotation_to_z(direction: np.ndarray) -> np.ndarray:
    """(3, 3) rotation carrying the unit vector ``direction`` onto +z (the shortest turn)."""
    axis = np.cross(direction, [0.0, 0.0, 1.0])
    sin, cos = np.linalg.norm(axis), float(direction[2])
    if sin < 1e-12:
        return np.eye(3) if cos > 0 else np.diag([1.0, -1.0, -1.0])
    return Rotation.from_rotvec(axis / sin * np.arctan2(sin, cos)).as_matrix()


def _homography(board_xy: np.ndarray, plane_xy: np.ndarray) -> np.ndarray:
    """(3, 3) homography from board to plane points by the normalised direct linear transform."""
    def normaliser(points):
        mean, spread = points.mean(axis=0), np.sqrt(2.0) / np.mean(np.linalg.norm(points - points.mean(0), axis=1))
        return np.array([[spread, 0.0, -spread * mean[0]], [0.0, spread, -spread * mean[1]], [0.0, 0.0, 1.0]])

    t_board, t_plane = normaliser(board_xy), normaliser(plane_xy)
    a = np.c_[board_xy, np.ones(len(board_xy))] @ t_board.T
    b = np.c_[plane_xy, np.ones(len(plane_xy))] @ t_plane.T
    zeros = np.zeros_like(a)
    rows_u = np.hstack([a, zeros, -b[:, :1] * a])
    rows_v = np.hstack([zeros, a, -b[:, 1:2] * a])
    h = np.linalg.svd(np.vstack([rows_u, rows_v]))[2][-1].reshape(3, 3)
    return np.linalg.inv(t_plane) @ h @ t_board


def pose_from_rays(rays: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose of a planar board from the camera rays of its points.

    Parameters
    ----------
    rays : (N, 3) ndarray
        Directions (any length) of the points in the camera frame; all
        within less than 90 degrees of their mean.
    points : (N, 3) ndarray
        The points in the board's plane (``z = 0``), metres.

    Returns
    -------
    rotation : (3, 3) ndarray
    translation : (3,) ndarray
        ``camera = rotation @ board + translation``, metres.
    """
    rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    mean = rays.mean(axis=0)
    turn = _rotation_to_z(mean / np.linalg.norm(mean))
    turned = rays @ turn.T
    h = _homography(points[:, :2], turned[:, :2] / turned[:, 2:])
    h = h / np.linalg.norm(h[:, 0])
    if h[2, 2] < 0:  # the board in front of the plane z = 1
        h = -h
    u, _, vt = np.linalg.svd(np.c_[h[:, 0], h[:, 1], np.cross(h[:, 0], h[:, 1])])
    rotation = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    scale = 2.0 / (np.linalg.norm(h[:, 0]) + np.linalg.norm(h[:, 1]))
    return turn.T @ rotation, turn.T @ (h[:, 2] * scale)


def _model_builder(start: UnifiedModel, config: BoardFitConfig):
    """(start vector, model from vector) of the intrinsics: xi, fu, fv, pu, pv[, k1, k2, p1, p2]."""
    coeffs = start.distortion if start.distortion else (0.0, 0.0, 0.0, 0.0)
    vector = [start.xi, *start.focal, *start.principal_point] + (list(coeffs) if config.distortion else [])

    def build(p):
        distortion = tuple(p[5:9]) if config.distortion else ()
        return UnifiedModel(abs(p[0]), (p[1], p[2]), (p[3], p[4]), start.size, distortion)

    return np.asarray(vector, dtype=np.float64), build


def _projected(model: UnifiedModel, poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(V, N, 2) pixels of the board points under each pose ``(rotvec, t)``; NaN where unseen."""
    rotations = Rotation.from_rotvec(poses[:, :3]).as_matrix()
    camera = np.einsum("vij,nj->vni", rotations, points) + poses[:, None, 3:]
    return model.pixels_from_rays(camera)


def _checked_corners(corners, points: np.ndarray) -> np.ndarray:
    corners = np.asarray(corners, dtype=np.float64)
    if corners.ndim != 3 or corners.shape[1:] != (len(points), 2) or len(corners) < 1:
        raise ValueError(f"expected corners of shape (V, {len(points)}, 2) with V >= 1, got {corners.shape}")
    if len(points) < _MIN_CORNERS or not np.isfinite(corners).all():
        raise ValueError(f"expected at least {_MIN_CORNERS} finite corners per board")
    return corners


def fit_unified_to_boards(corners, points, start: UnifiedModel, *,
                          config: BoardFitConfig = BoardFitConfig()) -> BoardCalibration:
    """Fit the unified model and every board's pose to detected checkerboard corners.

    Parameters
    ----------
    corners : (V, N, 2) array_like
        Detected corners ``(row, col)`` of V boards, pixels, in the order of ``points``.
    points : (N, 3) array_like
        The board's corners in its plane (:func:`board_points`), metres.
    start : UnifiedModel
        Starting model (e.g. :func:`parabolic_start`); its size is kept.
    config : BoardFitConfig, keyword-only

    Returns
    -------
    BoardCalibration

    Raises
    ------
    ValueError
        Corners of the wrong shape or not finite, or a starting model that
        cannot see some board's corners.
    """
    points = np.asarray(points, dtype=np.float64)
    corners = _checked_corners(corners, points)
    vector, build = _model_builder(start, config)
    rays = start.rays_from_pixels(corners)
    if not np.isfinite(rays).all():
        raise ValueError("the starting model cannot lift every corner to a ray")
    poses = [pose_from_rays(view, points) for view in rays]
    pose_vector = np.concatenate([np.r_[Rotation.from_matrix(r).as_rotvec(), t] for r, t in poses])
    n_intrinsics = len(vector)

    def residuals(p):
        try:
            model = build(p[:n_intrinsics])
        except ValueError:
            return np.full(corners.size, _UNSEEN_RESIDUAL_PX)
        projected = _projected(model, p[n_intrinsics:].reshape(-1, _POSE_SIZE), points)
        return np.nan_to_num((projected - corners).ravel(), nan=_UNSEEN_RESIDUAL_PX)

    solution = least_squares(residuals, np.r_[vector, pose_vector], method="lm", x_scale="jac",
                             max_nfev=config.max_evaluations)
    model = build(solution.x[:n_intrinsics])
    pose_array = solution.x[n_intrinsics:].reshape(-1, _POSE_SIZE)
    found = _projected(model, pose_array, points) - corners
    return BoardCalibration(
        model=model,
        camera_from_board=tuple((Rotation.from_rotvec(p[:3]).as_matrix(), p[3:].copy()) for p in pose_array),
        residuals_px=found, rms_px=float(np.sqrt(np.mean(np.sum(found ** 2, axis=-1)))),
        success=bool(solution.success))
