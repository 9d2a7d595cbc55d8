"""Whether frames went through block-transform compression (JPEG), from the block grid they keep.

A block codec transforms each 8x8 block on its own and quantises its high
frequencies away; what is left are steps at the block borders, on a grid
fixed to the image and not to the scene. Across those borders the image
changes more than between the other neighbouring pixels, so the mean
gradient on the grid exceeds the mean elsewhere (on uncompressed frames the
two agree to a few percent, whatever the texture or noise).

The registration uses it to choose where the band-limited search of
noise-dominated tile pairs pays
(:attr:`~ifmi.spectral.fourier_mellin.FourierMellinConfig.noisy_pair_fraction`):
on compressed frames the high frequencies of a tile are quantisation
residue and block steps that do not move with the scene, yet they have as
much say on the phase-only surface as the texture; on uncompressed frames
a tile that fails the phase-only search is weak at every frequency (render
or sensor noise), and the band limit only lets less precise tiles through
where the phase-only tiles would solve the pair. There the front end runs it
only for a pair no other stage solved
(:meth:`~ifmi.spectral.ifmi_front_end.IfmiFrontEnd.solve_pair`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["BLOCK_SIZE_PX", "MIN_BLOCK_EDGE_RATIO", "block_edge_ratio", "is_block_compressed"]

# Block size (pixels) of JPEG's luma transform and of most video codecs' largest common block.
BLOCK_SIZE_PX = 8
# Smallest block_edge_ratio of a compressed frame: the gradient across the block borders a tenth
# above the rest. Measured on every fourth frame: uncompressed 245-512 px renders (8 spp; with and
# without noise of 5 grey levels, exposure flicker or vignetting) 1.007 to 1.051; JPEG quality 90
# 1.011 to 1.047 (its steps are below the texture's); quality 75 with noise of 3 grey levels 1.13
# to 1.28; quality 50 1.32 to 1.78.
MIN_BLOCK_EDGE_RATIO = 1.1


def block_edge_ratio(gray: np.ndarray, *, block: int = BLOCK_SIZE_PX) -> float:
    """Mean absolute gradient across the block grid over the mean across the other pixel borders.

    The grid's phase is found, not assumed: of the ``block`` column phases,
    and of the row phases, the one with the largest mean gradient is taken
    as the grid's, so a cropped or padded frame is measured alike. Flat
    parts (the mask outside a mirror) add nothing to either mean's sum and
    the same share to both counts.

    Parameters
    ----------
    gray : (H, W) ndarray
        Gray frame, at least ``2 * block`` pixels on each side.
    block : int, keyword-only
        Block size in pixels (>= 2).

    Returns
    -------
    float
        About 1 for an uncompressed frame, above for a block-compressed one;
        1 for a frame without any gradient.
    """
    gray = np.asarray(gray, dtype=np.float32)
    if gray.ndim != 2 or min(gray.shape) < 2 * block or block < 2:
        raise ValueError(f"expected a 2-D frame of at least {2 * block} px a side and block >= 2, "
                         f"got shape {gray.shape} and block {block}")
    grid_sum = grid_count = rest_sum = rest_count = 0.0
    for axis in (1, 0):
        # Sum and count of |gradient| across the borders at each phase of this axis' grid lines.
        step = np.abs(np.diff(gray, axis=axis)).sum(axis=1 - axis, dtype=np.float64)
        phase = np.arange(step.size) % block
        sums = np.bincount(phase, weights=step, minlength=block)
        counts = np.bincount(phase, minlength=block) * float(gray.shape[1 - axis])
        grid = int(np.argmax(sums / counts))
        grid_sum, grid_count = grid_sum + sums[grid], grid_count + counts[grid]
        rest_sum, rest_count = rest_sum + sums.sum() - sums[grid], rest_count + counts.sum() - counts[grid]
    if rest_sum <= 0:
        return 1.0
    return float((grid_sum / grid_count) / (rest_sum / rest_count))


def is_block_compressed(gray: np.ndarray) -> bool:
    """True when ``gray`` keeps the block grid of a block-transform codec (:data:`MIN_BLOCK_EDGE_RATIO`);
    False for a frame smaller than two blocks a side, which holds no grid to measure."""
    gray = np.asarray(gray)
    if gray.ndim != 2 or min(gray.shape) < 2 * BLOCK_SIZE_PX:
        return False
    return block_edge_ratio(gray) >= MIN_BLOCK_EDGE_RATIO
