"""Homographies between the rays of two cameras: the model of a plane, or of a pure rotation.

Convention (as :mod:`ifmi.backend.relative_pose`): ``X_a = R_ab @ X_b + t_ab``.
A plane seen by camera b, ``n_b . X_b = d_b``, maps the rays of b onto those
of a by ``H_ab = R_ab + t_ab n_b^T / d_b``: ``rays_a ~ H_ab @ rays_b`` up to a
positive factor. A rotation is the homography of zero translation
(``H_ab = R_ab``), so the homography holds the rotation-only model as its
special case and explains, besides, the parallax of a translation over a
plane.

All functions are pure; rays are unit ``(N, 3)`` arrays.
"""

from __future__ import annotations

import numpy as np

from ifmi.geometry.rotations import cross, cross_product_matrix

__all__ = ["homography_from_rays", "homography_transfer_angles", "inlier_homography", "refitted_homography"]


def homography_from_rays(rays_a: np.ndarray, rays_b: np.ndarray) -> np.ndarray:
    """Least-squares ``H_ab`` with ``rays_a x (H_ab @ rays_b) = 0`` (direct linear transform).

    Parameters
    ----------
    rays_a, rays_b : (..., N, 3) ndarray
        Corresponding unit rays, N >= 4; leading axes are separate fits.

    Returns
    -------
    (..., 3, 3) ndarray
        Up to scale (unit Frobenius norm).
    """
    # [a]x H b, linear in H's rows: kron([a]x, b^T) @ vec(H) (row-major).
    rows = np.einsum("...nij,...nk->...nijk", cross_product_matrix(rays_a), rays_b)
    rows = rows.reshape(rows.shape[:-4] + (-1, 9))
    return np.linalg.svd(rows, full_matrices=False)[2][..., -1, :].reshape(rows.shape[:-2] + (3, 3))


def homography_transfer_angles(homography: np.ndarray, rays_a: np.ndarray, rays_b: np.ndarray) -> np.ndarray:
    """Angle (radians) between ``rays_a`` and ``H_ab @ rays_b``, either sign of ``H``.

    Parameters
    ----------
    homography : (..., 3, 3) ndarray
        ``H_ab``; leading axes are separate homographies.
    rays_a, rays_b : (N, 3) ndarray

    Returns
    -------
    (..., N) ndarray
    """
    mapped = rays_b @ np.swapaxes(homography, -1, -2)
    lengths = np.maximum(np.linalg.norm(mapped, axis=-1), 1e-300)
    cosines = np.sum(mapped * rays_a, axis=-1) / lengths
    sines = np.linalg.norm(cross(mapped, rays_a), axis=-1) / lengths
    return np.arctan2(sines, np.abs(cosines))


def inlier_homography(rays_a: np.ndarray, rays_b: np.ndarray, *, threshold_rad: float,
                      refits: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """``H_ab`` fitted to all rays, then refitted ``refits`` times to the rays it transfers within
    ``threshold_rad``: a homography of rays that are already screened for gross outliers.

    Parameters
    ----------
    rays_a, rays_b : (N, 3) ndarray
        Unit rays, N >= 4.
    threshold_rad : float, keyword-only
        Inlier threshold on :func:`homography_transfer_angles` (radians).
    refits : int, keyword-only
        Refits on the inliers; one stops early when fewer than four rays remain.

    Returns
    -------
    homography : (3, 3) ndarray
    errors : (N,) ndarray
        Transfer angles (radians) of every ray under it.
    """
    return refitted_homography(homography_from_rays(rays_a, rays_b), rays_a, rays_b, threshold_rad=threshold_rad,
                               refits=refits, fitted=np.ones(len(rays_a), dtype=bool))


def refitted_homography(homography: np.ndarray, rays_a: np.ndarray, rays_b: np.ndarray, *, threshold_rad: float,
                        refits: int, fit=homography_from_rays,
                        fitted: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``homography`` refitted ``refits`` times, each time by ``fit`` to the rays the current one
    transfers within ``threshold_rad``; stops early when fewer than four rays remain.

    Parameters
    ----------
    homography : (3, 3) ndarray
        The start, ``H_ab``.
    rays_a, rays_b : (N, 3) ndarray
        Unit rays.
    threshold_rad : float, keyword-only
        Inlier threshold on :func:`homography_transfer_angles` (radians).
    refits : int, keyword-only
    fit : callable, keyword-only
        ``fit(rays_a, rays_b) -> (3, 3)`` on the inliers; the direct linear transform by default.
    fitted : (N,) bool ndarray, optional, keyword-only
        The rays ``homography`` was fitted to by ``fit``, when it was. A refit stops early, with
        the same result, when the inliers are the rays of the last fit (the fit would return the
        same homography).

    Returns
    -------
    homography : (3, 3) ndarray
    errors : (N,) ndarray
        Transfer angles (radians) of every ray under it.
    """
    errors = homography_transfer_angles(homography, rays_a, rays_b)
    for _ in range(refits):
        keep = errors < threshold_rad
        # The same inliers as the last refit's give the same homography again: done.
        if keep.sum() < 4 or (fitted is not None and np.array_equal(keep, fitted)):
            break
        homography = fit(rays_a[keep], rays_b[keep])
        errors = homography_transfer_angles(homography, rays_a, rays_b)
        fitted = keep
    return homography, errors
