"""The tile placement maps of :mod:`ifmi.spectral.fourier_mellin` as one compiled pass.

A tile of ``N x N`` pixels placed at offset ``o`` with linear part ``L`` and
curvature ``Q`` samples its source panorama at ``o + L u + q(u)``, ``u`` the
pixel's ``(row, col)`` about the tile centre. NumPy builds these maps in
twelve broadcast passes over ``(K, N, N)`` arrays; this kernel (numba,
compiled on first use and cached beside this file) writes each value once, in
the same float32 order of operations, so the maps are the same bit for bit.
"""

import numba
import numpy as np

__all__ = ["placement_maps_into"]


@numba.njit(cache=True, nogil=True)
def placement_maps_into(maps: np.ndarray, offsets: np.ndarray, linear: np.ndarray, curvature: np.ndarray,
                         curved: bool) -> None:
    """Fill ``maps`` (2, K, N, N) float32 with the source row and column of tiles placed at ``o + L u + q(u)``.

    Each value is ``((L_i0 u_r + L_i1 u_c) + o_i) + (((Q_i00 u_r) u_r + (2 Q_i01 u_r) u_c) + (Q_i11 u_c) u_c)``,
    every product and sum rounded to float32 in this order (the curvature term only when ``curved``),
    ``u = (r, c) - (N - 1) / 2``: the values NumPy's broadcast operations give, computed in one pass.

    Parameters
    ----------
    maps : (2, K, N, N) float32 ndarray
        Written.
    offsets : (K, 2) float32 ndarray
    linear : (K, 2, 2) float32 ndarray
    curvature : (K, 2, 2, 2) float32 ndarray
        Read only when ``curved``.
    curved : bool
    """
    n = maps.shape[-1]
    half = np.float32((n - 1) / 2.0)
    two = np.float32(2.0)
    for t in range(maps.shape[1]):
        for i in range(2):
            l0, l1, o = linear[t, i, 0], linear[t, i, 1], offsets[t, i]
            q00, q01, q11 = curvature[t, i, 0, 0], two * curvature[t, i, 0, 1], curvature[t, i, 1, 1]
            for r in range(n):
                u_r = np.float32(r) - half
                row_term, cross_term, square_term = l0 * u_r, q01 * u_r, q00 * u_r * u_r
                for c in range(n):
                    u_c = np.float32(c) - half
                    value = (row_term + l1 * u_c) + o
                    if curved:
                        value = value + ((square_term + cross_term * u_c) + q11 * u_c * u_c)
                    maps[i, t, r, c] = value
