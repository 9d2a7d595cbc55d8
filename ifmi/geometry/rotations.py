"""Rotation conventions of the project, named in the function names.

Roll, pitch and yaw follow ``Rotation.from_matrix(R).as_euler("ZYX")`` read as
``(yaw, pitch, roll)``: yaw about camera z, pitch about y, roll about x, so
``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``. Quaternions are ``(qx, qy, qz, qw)``
(scalar last, as in TUM files). All angles are radians.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "rpy_from_matrix",
    "matrix_from_rpy",
    "quat_xyzw_from_matrix",
    "matrix_from_quat_xyzw",
    "geodesic_angle",
    "wrap_angle",
    "project_to_rotation",
    "matrix_aligning_rays",
    "cross_product_matrix",
    "cross",
]


def rpy_from_matrix(R: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw of rotation matrices.

    Parameters
    ----------
    R : (..., 3, 3) array_like

    Returns
    -------
    (..., 3) ndarray
        ``(roll, pitch, yaw)`` in radians.
    """
    R = np.asarray(R, dtype=np.float64)
    ypr = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_euler("ZYX")
    return ypr[:, ::-1].reshape(R.shape[:-2] + (3,))


def matrix_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """Rotation matrices ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` from ``(..., 3)`` roll, pitch, yaw (radians)."""
    rpy = np.asarray(rpy, dtype=np.float64)
    R = Rotation.from_euler("ZYX", rpy.reshape(-1, 3)[:, ::-1]).as_matrix()
    return R.reshape(rpy.shape[:-1] + (3, 3))


def quat_xyzw_from_matrix(R: np.ndarray) -> np.ndarray:
    """``(..., 4)`` unit quaternions ``(qx, qy, qz, qw)`` with ``qw >= 0`` from ``(..., 3, 3)`` matrices."""
    R = np.asarray(R, dtype=np.float64)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = np.where(q[:, 3:4] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def matrix_from_quat_xyzw(q: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` matrices from ``(..., 4)`` quaternions ``(qx, qy, qz, qw)`` (normalised here)."""
    q = np.asarray(q, dtype=np.float64)
    R = Rotation.from_quat(q.reshape(-1, 4)).as_matrix()
    return R.reshape(q.shape[:-1] + (3, 3))


def geodesic_angle(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angle of ``R_a^T R_b`` in radians, ``(...)`` from two ``(..., 3, 3)`` stacks."""
    R_a = np.asarray(R_a, dtype=np.float64)
    R_b = np.asarray(R_b, dtype=np.float64)
    rel = np.swapaxes(R_a, -1, -2) @ R_b
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    # arccos is ill-conditioned near 0; use the norm of the skew part as well.
    skew = np.stack([rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0],
                     rel[..., 1, 0] - rel[..., 0, 1]], axis=-1)
    sin = np.linalg.norm(skew, axis=-1) / 2.0
    return np.arctan2(sin, cos)


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Wrap angles (radians) into ``[-pi, pi)``."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def project_to_rotation(M: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (Frobenius norm) to each ``(..., 3, 3)`` matrix, via SVD."""
    M = np.asarray(M, dtype=np.float64)
    U, _, Vt = np.linalg.svd(M)
    D = np.ones(M.shape[:-1])
    D[..., -1] = np.sign(np.linalg.det(U @ Vt))
    return (U * D[..., None, :]) @ Vt



def matrix_aligning_rays(from_rays: np.ndarray, to_rays: np.ndarray, *, fraction: float = 1.0) -> np.ndarray:
    """Smallest rotations ``R`` with ``to_rays ~ R @ from_rays``, one per ray pair, or a fraction of each.

    Parameters
    ----------
    from_rays, to_rays : (N, 3) ndarray
        Unit rays; the two of a pair must not be opposite.
    fraction : float, keyword-only
        Part of the turn: the rotation about the same axis by ``fraction``
        times the angle between the rays (1: onto ``to_rays``, 0: identity).

    Returns
    -------
    (N, 3, 3) ndarray
        Rotation about ``from x to`` (the identity for equal rays).
    """
    a = np.asarray(from_rays, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(to_rays, dtype=np.float64).reshape(-1, 3)
    axis = np.cross(a, b)
    sin = np.linalg.norm(axis, axis=1)
    angle = np.arctan2(sin, np.einsum("ni,ni->n", a, b))
    # angle / sin -> 1 as the rays meet: the rotation vector is axis * angle / sin.
    scale = np.divide(angle, sin, out=np.ones_like(angle), where=sin > 1e-300)
    return Rotation.from_rotvec(fraction * scale[:, None] * axis).as_matrix().reshape(-1, 3, 3)


def cross_product_matrix(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]_x`` (``[v]_x @ u == cross(v, u)``) of (..., 3) vectors, (..., 3, 3)."""
    if v.ndim == 1:  # one vector: plain floats, faster than the array path on small inputs
        x, y, z = v.tolist()
        return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cross products ``u x v`` along the last axis of (..., 3) vectors (broadcasting), (..., 3).

    The same products and differences as ``np.cross`` (equal to the last bit), at a fraction of
    its cost on small arrays.
    """
    u0, u1, u2 = u[..., 0], u[..., 1], u[..., 2]
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0], axis=-1)
