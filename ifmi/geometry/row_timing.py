"""When each image row of a rolling-shutter camera is exposed, relative to the frame's middle row."""

from __future__ import annotations

import numpy as np

__all__ = ["row_time_offsets"]

def row_time_offsets(rows: np.ndarray, *, height: int, readout: float) -> np.ndarray:
    """Time of each image row relative to the middle row, in frame intervals.

    Parameters
    ----------
    rows : (N,) array_like
        Image row coordinates (pixels, 0-based; sub-pixel values allowed).
    height : int, keyword-only
        Image height ``H`` in pixels (at least 2).
    readout : float, keyword-only
        :attr:`RollingShutterOptions.readout`.

    Returns
    -------
    (N,) ndarray
        ``readout * (row - (H - 1) / 2) / (H - 1)``.
    """
    if height < 2:
        raise ValueError(f"expected an image height of at least 2 rows, got {height}")
    middle = 0.5 * (height - 1)
    return readout * (np.asarray(rows, dtype=np.float64) - middle) / (height - 1)
