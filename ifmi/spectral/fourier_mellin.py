"""Improved Fourier-Mellin invariant (iFMI) registration of tile pairs, batched.

Motion model of a tile pair ``(a, b)`` of size ``N x N`` with centre
``c = ((N - 1) / 2, (N - 1) / 2)``, coordinates ``(row, col)``::

    b(q) = a(M(q)),   M(q) = s R(theta) (q - c) + c + t,
    R(theta) = [[cos theta, -sin theta], [sin theta, cos theta]]

so a point ``q`` of tile b shows the content of point ``M(q)`` of tile a.

Per pair (all tiles of a frame at once, one FFT call per step):

1. mean removal, Hann window, ``rfft2``; the magnitude of the half plane
   (the spectrum of a real image is centrosymmetric), a high-pass emphasis,
   and its resampling onto a log-polar grid over angles ``[0, pi)``;
2. phase-only matched filter of the two log-polar magnitudes: the peak gives
   ``theta`` (mod pi) along the angle axis and ``log s`` along the log-radius
   axis, with a parabolic sub-pixel fit refined by a phase-plane fit
   (:func:`ifmi.spectral.phase_correlation.refine_shift_phase_plane`); the log-polar
   grid starts at a fraction of the largest radius, because the window blurs
   the low frequencies by a fixed amount that would bias the scale;
3. tile b is resampled from its source image at ``M(q)`` without the
   translation (undoing ``theta`` and ``s``); the ``theta + pi`` candidate is
   the point reflection of that tile, whose spectrum follows from the same
   FFT. Phase correlation with tile a gives ``t`` for both candidates, and
   the higher peak resolves the 180-degree ambiguity;
4. sub-pixel translation from the parabolic peak refined by a phase-plane
   fit; refinement passes (default one) resample b with the full motion
   estimate and measure the small residual similarity (rotation, scale and
   translation) the same way, which removes the bias that the window causes
   at large motions, and compose it with the estimate.

With a prediction of where tile a's content lies in frame b and how it is
distorted -- an affine *placement* ``p -> o + L (p - c)`` in b's source
(:meth:`FourierMellin.register_placed`) -- steps 1 to 3 are skipped: tile b
is resampled at the placement, step 4 measures the residual, and the result
is again a placement (:func:`compose_placement`). The tiles the last
residual was measured on are returned with their placement, so a tracker
can use exactly those pixels as the next pair's reference.

Quality figures of the translation correlation -- peak ratio (main peak over
the highest value outside its lobe) and peak-to-noise ratio ((peak - mean) /
std of the surface) -- reject bad tiles with the thresholds ``th_pr`` and
``th_pnr``; textureless tiles are rejected before.

Noise-dominated pairs. The phase-only surface gives every frequency the same
say. Where image noise or compression outweighs the texture over most of the
band (sensor noise, JPEG quantisation, low-contrast scenes), the noise
frequencies drown the peak and most tiles of the pair fail the filters. When
fewer than ``noisy_pair_fraction`` of a pair's tiles pass, the pair's
translation search is done again on the band-limited surface
(:func:`~ifmi.spectral.phase_correlation.gaussian_lowpass` times
:func:`~ifmi.spectral.phase_correlation.gaussian_highpass` of the same
cross-power spectrum: one more inverse FFT, no resampling), judged with the
stricter ``noisy_th_pr``. Pairs whose tiles mostly pass are left exactly as
they were. The iFMI front end runs this search on block-compressed captures
only (:mod:`ifmi.spectral.compression`): there the high frequencies are
quantisation residue and block steps fixed to the image; on uncompressed
frames a tile that fails is weak at every frequency, and the band limit only
lets less precise tiles through. On those the front end uses it for a pair
that no other stage solved (``IfmiFrontEnd.solve_pair`` of
:mod:`ifmi.spectral.ifmi_front_end`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import IntEnum

import cv2
import numpy as np
import scipy.fft

from ifmi.options import check_finite_fields
from ifmi.spectral.phase_correlation import (Peaks, correlation_surface, find_peaks, gaussian_highpass,
                                             gaussian_lowpass, hann_window,
                                normalized_cross_power, refine_shift_phase_plane)
from ifmi.spectral.tiling import MIN_TILE_SIZE_PX

__all__ = [
    "FourierMellinConfig",
    "TileSpectra",
    "TileMotion",
    "PlacedTiles",
    "PlacedRegistration",
    "placement_from_motion",
    "compose_placement",
    "motion_from_placement",
    "FourierMellin",
    "TileRejection",
    "transform_points",
    "registration_bytes_per_tile",
    "max_tile_count",
    "TILE_MEMORY_BUDGET_BYTES",
]

# Rows (exclusive) OpenCV's remap accepts, and the range of its 16-bit fixed-point maps.
_REMAP_MAX_ROWS = 2 ** 15
# Pixels of the tiles whose remap maps are built and used at a time (512 kB per float32 map).
_MAP_CHUNK_PIXELS = 2 ** 17
# Peak memory of registering one frame pair, per tile: bytes per tile pixel (the tiles, their
# spectra, correlation surfaces, resampled tiles) and per sample of the log-polar grid (the
# descriptors and their spectra). Measured with tracemalloc over two ``prepare`` calls and one
# ``correspondences`` on the demo office at 256 px: 49 to 81 bytes per tile pixel (tiles of 8 to
# 64 px, 16 to 31232 tiles) and about 19 per log-polar sample (grids of 32x16 to 256x256); these
# bounds are at or above every measurement (5.2 kB measured for an 8 px tile, 5.4 kB bounded).
_PEAK_BYTES_PER_TILE_PIXEL = 72
_PEAK_BYTES_PER_LOG_POLAR_SAMPLE = 24
# Memory one frame pair's tile registration may take, which bounds the tiles of a frame. ``ifmi
# sweep`` runs two estimates at once by default (ifmi.runtime.local_workers.DEFAULT_LOCAL_WORKERS), and a
# run keeps its reference frame's tiles besides, so this keeps a sweep within a few GiB. Time
# grows with it too: 31232 tiles of 32 px (1.6 GiB) took 10.6 s per frame pair on 2 cores,
# 7936 tiles (0.4 GiB) 3.3 s; the default layouts hold 32 to 1000 tiles (2 to 250 MB).
TILE_MEMORY_BUDGET_BYTES = 2 ** 30


class TileRejection(IntEnum):
    """Why a tile pair was rejected (``TileMotion.reason``); ``KEPT`` (0) when it was not."""

    KEPT = 0
    TEXTURELESS = 1
    LOW_PEAK_RATIO = 2
    LOW_PEAK_TO_NOISE_RATIO = 3

    @property
    def label(self) -> str:
        """Snake-case name used in diagnostics (``"low_peak_to_noise_ratio"``)."""
        return self.name.lower()

# OpenCV interpolation flag of each ``FourierMellinConfig.resample_interpolation`` name.
# Most refinement passes: each one resamples and registers every tile again (about the cost of
# the first registration) while the residual settles after one or two; more only cost time.
_MAX_REFINE_PASSES = 10
# Most FFT threads: scipy's FFT starts at most as many threads as the machine has CPUs, and a
# count past a C int (2**31) was a TypeError traceback at the first frame.
_MAX_FFT_WORKERS = 1024
# Most phase-plane iterations: the fit converges within a few (default 3) even on noisy tiles.
_MAX_PHASE_PLANE_ITERATIONS = 50
_INTERPOLATIONS = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC, "lanczos4": cv2.INTER_LANCZOS4}


@dataclass(frozen=True)
class FourierMellinConfig:
    """Options of the tile registration.

    Attributes
    ----------
    log_polar_angles : int or None
        Angle samples over ``[0, pi)``; default the tile size.
    log_polar_radii : int or None
        Log-radius samples; default half the tile size.
    min_radius_fraction : float
        Smallest spectral radius of the log-polar grid as a fraction of the
        largest (``N/2 - 1`` bins). The window blurs the spectrum by a few
        bins, which does not scale with the image; low radii would bias the
        scale estimate toward 1, so they are left out.
    correlation_lowpass : float or None
        Standard deviation (cycles per pixel) of a Gaussian weight on the
        phase-only cross-power spectrum of the tiles' translation search
        (:func:`~ifmi.spectral.phase_correlation.gaussian_lowpass`); None weights all
        frequencies alike. Phase correlation gives each frequency the same
        say, and at the high ones image noise outweighs the texture of flat
        surfaces: their peak drowns and the tile fails ``th_pr``. The weight
        smooths the surface over about 1 pixel (``1 / (2 pi sigma)``), so
        ``th_pr`` and ``th_pnr`` are measured on the smoothed surface. Only
        the search peak and the tile filters see it; the sub-pixel shift
        comes from the phase-plane fit of the unweighted spectra. Off by
        default: with 0.15 and ``th_pr`` 2.0 (smoothing raises chance peaks'
        ratios: unrelated tile pairs pass 1.5 about twice as often) the
        noisy, JPEG-compressed warehouse sequences went from 0.030 to under
        0.010 rad ATE, and on 126 fast sequences the median ATE over three
        seeds improved by more than 5 % on 67 and worsened on 43 (frame
        mode), but a frame of office_trans_x10 took a wrong peak (ATE 0.004
        -> 0.09 rad on two of three seeds).
        For noisy footage use it with ``correlation_highpass_bins=1.0`` and
        ``th_pr=2.0``; ``noisy_pair_fraction`` applies that band limit to the
        pairs that need it only.
    correlation_highpass_bins : float
        Standard deviation (frequency samples of the tile) of a Gaussian
        high-pass weight on the same spectrum
        (:func:`~ifmi.spectral.phase_correlation.gaussian_highpass`); 0 is off. It
        takes away the few lowest frequencies, where the window's spectrum
        and structures larger than a tile weigh most. With the low-pass
        above (0.15, 1 sample, ``th_pr`` 2.0) office_trans_x10 kept its
        0.003-0.006 rad on all three seeds and every warehouse sequence,
        noisy or not, stayed below the feature methods' ATE; over 90
        held-out fast sequences it was better than the default by more than
        5 % on 48 and worse on 35 (12 by more than half), so it stays off.
    noisy_pair_fraction : float
        A pair whose phase-only translation search keeps fewer than this
        fraction of its tiles (``th_pr`` and ``th_pnr``) is noise-dominated and
        searched again on the band-limited surface (module docstring); 0 is
        off. Without a fixed ``correlation_lowpass`` only. At 0.5, on six 512 px
        renders (pure rotation and translation) passed through noise of 5 grey
        levels, JPEG quality 50, exposure flicker and a vignette, the ATE fell
        in 10 of 12 runs (frame and keyframe mode; 0.96x down to 0.03x on the
        low-contrast warehouse) and rose in two (1.05x; 2.95x on atelier in
        keyframe mode). The clean office, lawn, urban and pure-rotation atelier
        renders keep at least half their tiles on every pair: their estimates
        are the same bit for bit. On the clean warehouse, where three quarters of the
        tiles fail anyway, it is 0.55-1.16x except in keyframe mode on pure
        rotation (3.9x: more keyframes were taken). On 54 uncompressed 384 px
        renders (8 spp) it was worse by more than 10 % on 23 and better on 15,
        so the iFMI front end sets it to 0 on frames without a block grid
        (:func:`ifmi.spectral.compression.is_block_compressed`) and uses it
        there only to retry a pair no other stage solved.
    noisy_lowpass : float
        Standard deviation (cycles per pixel) of the band limit's Gaussian
        low-pass: the surface is smoothed over ``1 / (2 pi sigma)`` = 1.06 px,
        inside the peak's excluded lobe, so the peak ratio still compares the
        peak with the surface away from it.
    noisy_highpass_bins : float
        Standard deviation (frequency samples) of the band limit's Gaussian
        high-pass, which takes away the lowest frequencies the window's own
        spectrum fills.
    noisy_th_pr : float
        Smallest accepted peak ratio on the band-limited surface, where
        smoothing raises chance peaks' ratios (unrelated tile pairs pass 1.5
        about twice as often). Its peak ratios are reported scaled by
        ``th_pr / noisy_th_pr``, so that ``th_pr`` judges every tile.
    th_pr : float
        Smallest accepted peak ratio of the translation correlation.
    th_pnr : float
        Smallest accepted peak-to-noise ratio of the translation correlation.
    min_std : float
        Tiles whose gray-level standard deviation is below this are textureless.
    refine_passes : int
        Extra passes that resample tile b with the full motion and fit the
        residual translation. When at least one follows, the first (search)
        pass only has to land within a pixel: it resamples bilinearly and
        keeps the parabolic sub-pixel peak, and the passes measure the
        residual with ``resample_interpolation`` and the phase-plane fit
        (as accurate on the rendered benchmark sequences: 20-frame drift
        219e-5 against 227e-5 rad summed over six runs; about 0.5 ms less
        per frame for 32 tiles of 64 px). At most 10: each pass costs about
        one registration and the residual settles after one or two.
    estimate_rotation_scale : bool
        Estimate ``s`` and ``theta``; when false they are 1 and 0 and only the
        translation is measured (faster; for nearly rigid tile motion).
    workers : int
        FFT threads (1 to 1024).
    phase_plane_max_frequency : float
        Largest frequency (cycles per pixel) of the phase-plane shift refinement.
    phase_plane_weight_power : float
        Exponent of the cross-spectrum magnitude weighting the phase-plane fit
        of the first translation and of the log-polar shifts.
    residual_weight_power : float
        The same exponent for the residual translation of the refinement
        passes, where tile b has been resampled onto tile a and the shift is
        a small fraction of a pixel; 1 weights each frequency by about the
        inverse variance of its phase under white image noise (see
        :func:`~ifmi.spectral.phase_correlation.refine_shift_phase_plane`).
    phase_plane_iterations : int
        Iterations of the phase-plane fit. Frequencies dominated by noise
        shrink each step toward zero, so a few iterations are needed to
        converge on noisy tiles (at most 50).
    refine_predicted_rotation_scale : bool
        When tile b is cut at a predicted affine placement
        (:meth:`FourierMellin.register_placed`), let the refinement passes
        measure the residual rotation and scale too (log-polar descriptors
        of the resampled tiles). Off by default: the predicted affine map
        leaves only second-order rotation and scale, and measuring the
        translation alone was as accurate on the rendered benchmark
        sequences (20-frame drift 62.3e-5 against 61.7e-5 rad, mean of six)
        and about a millisecond faster per frame. Without a prediction the
        residual rotation and scale are always measured.
    resample_interpolation : {"cubic", "lanczos4", "linear"}
        Interpolation of tile b where it is cut at a sub-pixel place, turned
        and scaled. Bilinear interpolation low-passes the tile by an amount
        that depends on the fractional offset, which biases the measured
        shift toward whole pixels; the bicubic and 8x8 Lanczos kernels keep
        that bias five or more times smaller (the tests measure it). On
        sharp images Lanczos is clearly better: on 1024 px pure-rotation
        sequences warped from one image (``omnisim warp``) the frame-to-frame
        error was 5.7e-6 against 9.7e-6 rad (photo-like) and 1.42e-5
        against 1.84e-5 rad (high-spp render), for about 16 % more compute
        per frame on 256 px renders.
    """

    log_polar_angles: int | None = None
    log_polar_radii: int | None = None
    min_radius_fraction: float = 0.3
    correlation_lowpass: float | None = None
    correlation_highpass_bins: float = 0.0
    noisy_pair_fraction: float = 0.5
    noisy_lowpass: float = 0.15
    noisy_highpass_bins: float = 1.0
    noisy_th_pr: float = 2.0
    th_pr: float = 1.5
    th_pnr: float = 8.0
    min_std: float = 1.0
    refine_passes: int = 1
    estimate_rotation_scale: bool = True
    workers: int = 1
    phase_plane_max_frequency: float = 0.35
    phase_plane_weight_power: float = 0.25
    residual_weight_power: float = 1.0
    phase_plane_iterations: int = 3
    refine_predicted_rotation_scale: bool = False
    resample_interpolation: str = "lanczos4"

    def __post_init__(self) -> None:
        check_finite_fields(self, ("min_radius_fraction", "correlation_lowpass", "correlation_highpass_bins",
                                   "noisy_pair_fraction", "noisy_lowpass", "noisy_highpass_bins", "noisy_th_pr",
                                   "th_pr", "th_pnr", "min_std", "phase_plane_max_frequency",
                                   "phase_plane_weight_power", "residual_weight_power"))
        for name in ("log_polar_angles", "log_polar_radii"):
            value = getattr(self, name)
            if value is not None and value < 8:
                raise ValueError(f"{name} must be >= 8 or None, got {value}")
        if not 0 < self.min_radius_fraction < 1 or self.th_pr < 0 or self.th_pnr < 0 or self.min_std < 0:
            raise ValueError(
                "expected 0 < min_radius_fraction < 1 and non-negative th_pr, th_pnr, min_std; got "
                f"{self.min_radius_fraction}, {self.th_pr}, {self.th_pnr}, {self.min_std}")
        if not 0 < self.phase_plane_max_frequency <= 0.5 or self.phase_plane_iterations < 1:
            raise ValueError("expected 0 < phase_plane_max_frequency <= 0.5 and phase_plane_iterations >= 1, "
                             f"got {self.phase_plane_max_frequency}, {self.phase_plane_iterations}")
        if self.correlation_lowpass is not None and not 0 < self.correlation_lowpass <= 0.5:
            raise ValueError("expected correlation_lowpass None or in (0, 0.5] cycles per pixel, "
                             f"got {self.correlation_lowpass}")
        if self.correlation_highpass_bins < 0:
            raise ValueError("expected correlation_highpass_bins >= 0 frequency samples (0: off), "
                             f"got {self.correlation_highpass_bins}")
        if not (0 <= self.noisy_pair_fraction <= 1 and 0 < self.noisy_lowpass <= 0.5
                and self.noisy_highpass_bins >= 0 and self.noisy_th_pr > 0):
            raise ValueError("expected noisy_pair_fraction in [0, 1], noisy_lowpass in (0, 0.5] cycles per pixel, "
                             "noisy_highpass_bins >= 0 and noisy_th_pr > 0, got "
                             f"{self.noisy_pair_fraction}, {self.noisy_lowpass}, {self.noisy_highpass_bins}, "
                             f"{self.noisy_th_pr}")
        if self.resample_interpolation not in _INTERPOLATIONS:
            raise ValueError(f"resample_interpolation must be one of {sorted(_INTERPOLATIONS)}, "
                             f"got {self.resample_interpolation!r}")
        if self.phase_plane_weight_power < 0 or self.residual_weight_power < 0:
            raise ValueError("expected non-negative phase_plane_weight_power and residual_weight_power, got "
                             f"{self.phase_plane_weight_power}, {self.residual_weight_power}")
        if not 0 <= self.refine_passes <= _MAX_REFINE_PASSES or self.workers < 1:
            raise ValueError(f"expected 0 <= refine_passes <= {_MAX_REFINE_PASSES} and workers >= 1, got "
                             f"{self.refine_passes}, {self.workers}")
        if self.workers > _MAX_FFT_WORKERS:
            raise ValueError(f"expected workers <= {_MAX_FFT_WORKERS} FFT threads, got {self.workers}")
        if self.phase_plane_iterations > _MAX_PHASE_PLANE_ITERATIONS:
            raise ValueError(f"expected phase_plane_iterations <= {_MAX_PHASE_PLANE_ITERATIONS}, "
                             f"got {self.phase_plane_iterations}")


@dataclass(frozen=True)
class TileSpectra:
    """Per-tile spectra of one frame, computed once and reused (keyframes).

    Attributes
    ----------
    spectrum : (T, N, N//2+1) complex64 ndarray
        ``rfft2`` of the windowed, mean-free tiles.
    descriptor : (T, A, R//2+1) complex64 ndarray or None
        ``rfft2`` of the log-polar magnitude (None without rotation/scale).
    std : (T,) ndarray
        Gray-level standard deviation of each tile.
    centroid : (T, 2) ndarray or None
        ``(row, col)`` of each tile's energy centroid, pixels from the tile
        centre: the mean position weighted by the squared windowed,
        mean-free gray level, the weight each pixel has in the
        correlation. Where the motion varies across a tile (parallax), the
        measured translation is the motion of this point rather than of
        the centre (:func:`energy_centroids`). None on the tiles of b that a
        registration resamples (:attr:`PlacedRegistration.last`): they are
        matched against templates, and only a template's centroid is used.
    """

    spectrum: np.ndarray
    descriptor: np.ndarray | None
    std: np.ndarray
    centroid: np.ndarray

    def rows(self, index: np.ndarray) -> "TileSpectra":
        """The spectra of some tiles (``index``: bool mask or indices)."""
        return TileSpectra(spectrum=self.spectrum[index],
                           descriptor=None if self.descriptor is None else self.descriptor[index],
                           std=self.std[index], centroid=None if self.centroid is None else self.centroid[index])


def energy_centroids(windowed: np.ndarray) -> np.ndarray:
    """Energy centroids of windowed, mean-free tiles.

    A correlation of two tiles sums the products of their pixels, so each
    pixel weighs in proportion to its energy (its squared windowed gray
    level). When the motion is not uniform across the tile, as with the
    parallax of a near surface, the correlation peak is, to first order,
    the motion at the energy-weighted mean position, which can lie a few
    pixels from the tile centre on unevenly textured tiles.

    Parameters
    ----------
    windowed : (T, N, N) float ndarray
        Mean-free tiles multiplied by their window.

    Returns
    -------
    (T, 2) ndarray
        ``(row, col)`` of each centroid in pixels from the tile centre
        ``((N - 1) / 2, (N - 1) / 2)``; ``(0, 0)`` for a tile without energy.
    """
    energy = np.square(windowed)
    n = windowed.shape[-1]
    ones = np.ones(n, dtype=energy.dtype)
    # Row and column sums as products with ones (a fraction of the time of axis reductions).
    rows, cols = (energy @ ones).astype(np.float64), (ones @ energy).astype(np.float64)
    g = np.arange(n) - (n - 1) / 2.0
    total = rows.sum(axis=1)
    safe = np.where(total > 0, total, 1.0)
    return np.stack([rows @ g, cols @ g], axis=1) / safe[:, None]


@dataclass(frozen=True)
class TileMotion:
    """Registration of tile pairs (see the module docstring for the model).

    Attributes
    ----------
    scale : (T,) ndarray
        ``s``.
    angle_rad : (T,) ndarray
        ``theta`` in radians, in ``[-pi, pi)``.
    translation : (T, 2) ndarray
        ``t`` as ``(row, col)`` pixels.
    peak_ratio, peak_to_noise, peak_value : (T,) ndarray
        Quality of the translation correlation.
    rotation_peak_ratio : (T,) ndarray
        Peak ratio of the log-polar correlation (nan without rotation/scale).
    valid : (T,) bool ndarray
    reason : (T,) int ndarray
        :class:`TileRejection` code of each tile.
    """

    scale: np.ndarray
    angle_rad: np.ndarray
    translation: np.ndarray
    peak_ratio: np.ndarray
    peak_to_noise: np.ndarray
    peak_value: np.ndarray
    rotation_peak_ratio: np.ndarray
    valid: np.ndarray
    reason: np.ndarray


def transform_points(points_b: np.ndarray, scale: np.ndarray, angle_rad: np.ndarray,
                     translation: np.ndarray, tile_size: int) -> np.ndarray:
    """Flow equation: tile-a position ``M(q)`` of tile-b points ``q``.

    Parameters
    ----------
    points_b : (T, K, 2) or (K, 2) ndarray
        ``(row, col)`` in tile coordinates (0 at the tile's first pixel).
    scale, angle_rad : (T,) ndarray
    translation : (T, 2) ndarray
    tile_size : int

    Returns
    -------
    (T, K, 2) ndarray
        ``s R(theta) (q - c) + c + t`` with ``c`` the tile centre.
    """
    c = (tile_size - 1) / 2.0
    q = np.broadcast_to(points_b, (len(scale),) + np.shape(points_b)[-2:]) - c
    alpha = (scale * np.cos(angle_rad))[:, None]
    beta = (scale * np.sin(angle_rad))[:, None]
    row = alpha * q[..., 0] - beta * q[..., 1] + c + translation[:, None, 0]
    col = beta * q[..., 0] + alpha * q[..., 1] + c + translation[:, None, 1]
    return np.stack([row, col], axis=-1)


def placement_from_motion(origins: np.ndarray, scale: np.ndarray, angle_rad: np.ndarray,
                          translation: np.ndarray, tile_size: int) -> tuple[np.ndarray, np.ndarray]:
    """Affine placement in b's source of the aligned tile ``b'(p) = b(M^{-1}(p))``.

    Parameters
    ----------
    origins : (T, 2) ndarray
        ``(row, col)`` of tile b's first pixel in its source.
    scale, angle_rad : (T,) ndarray
    translation : (T, 2) ndarray
        The tile motion ``M`` (module docstring), ``(row, col)`` pixels.
    tile_size : int

    Returns
    -------
    offsets : (T, 2) ndarray
        Source ``(row, col)`` of the aligned tile's centre.
    linear : (T, 2, 2) ndarray
        ``L = R(-theta) / s``: source ``(row, col)`` per aligned-tile step.
    """
    c = (tile_size - 1) / 2.0
    return compose_placement(np.asarray(origins, dtype=np.float64) + c, np.broadcast_to(np.eye(2), (len(scale), 2, 2)),
                             scale, angle_rad, translation)


def compose_placement(offsets: np.ndarray, linear: np.ndarray, scale: np.ndarray, angle_rad: np.ndarray,
                      translation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Placement of tiles after a residual motion measured against tiles cut at ``(offsets, linear)``.

    If tiles cut at the placement show tile a moved by the similarity
    ``D = (s, theta, t)`` (module docstring), the tiles cut at the returned
    placement show tile a unmoved: ``o' = o - L' t`` and ``L' = L R(-theta) / s``.

    Parameters
    ----------
    offsets : (T, 2) ndarray
    linear : (T, 2, 2) ndarray
    scale, angle_rad : (T,) ndarray
    translation : (T, 2) ndarray

    Returns
    -------
    offsets : (T, 2) ndarray
    linear : (T, 2, 2) ndarray
    """
    cos = np.cos(angle_rad) / scale
    sin = np.sin(angle_rad) / scale
    step = np.empty(cos.shape + (2, 2))
    step[..., 0, 0] = step[..., 1, 1] = cos
    step[..., 0, 1] = sin
    step[..., 1, 0] = -sin
    linear = np.asarray(linear, dtype=np.float64) @ step
    offsets = np.asarray(offsets, dtype=np.float64) - np.einsum("tij,tj->ti", linear, translation)
    return offsets, linear


def motion_from_placement(origins: np.ndarray, offsets: np.ndarray, linear: np.ndarray,
                          tile_size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`placement_from_motion` for similarity placements: ``(s, theta, t)``."""
    c = (tile_size - 1) / 2.0
    angle = np.arctan2(linear[:, 0, 1], linear[:, 0, 0])
    scale = 1.0 / np.hypot(linear[:, 0, 0], linear[:, 0, 1])
    translation = np.linalg.solve(linear, (np.asarray(origins, dtype=np.float64) + c - offsets)[..., None])[..., 0]
    return scale, angle, translation


@dataclass(frozen=True)
class PlacedTiles:
    """Tiles resampled from a frame at known affine placements (see :meth:`FourierMellin.resample_placed`).

    Attributes
    ----------
    tiles : (T, N, N) float32 ndarray or None
        None for templates kept from an earlier frame, which only carry their spectra.
    offsets : (T, 2) ndarray
        Source ``(row, col)`` of each tile centre.
    linear : (T, 2, 2) ndarray
    spectra : TileSpectra or None
        Their spectra, when already computed.
    curvature : (T, 2, 2, 2) ndarray or None
        Second-order part of the placement (see :meth:`FourierMellin.resample_placed`); None is zero.
    """

    tiles: np.ndarray | None
    offsets: np.ndarray
    linear: np.ndarray
    spectra: TileSpectra | None
    curvature: np.ndarray | None = None


@dataclass(frozen=True)
class PlacedRegistration:
    """Result of :meth:`FourierMellin.register_placed`.

    Attributes
    ----------
    offsets, linear : (T, 2) and (T, 2, 2) ndarray
        Final placement in b's source of each tile of a (its centre and ``L``).
    peak_ratio, peak_to_noise, peak_value : (T,) ndarray
        Quality of the translation correlation.
    valid : (T,) bool ndarray
    reason : (T,) int ndarray
        :class:`TileRejection` code of each tile.
    last : PlacedTiles
        The tiles of b the final residual was measured on, with their
        placement: cut at the same place, they make the reference tiles of
        the next pair (tile tracking).
    template_centroid : (T, 2) ndarray
        Energy centroid of each tile of a (:attr:`TileSpectra.centroid`),
        tile ``(row, col)`` pixels from its centre: the point whose motion
        the registration measures.
    """

    offsets: np.ndarray
    linear: np.ndarray
    peak_ratio: np.ndarray
    peak_to_noise: np.ndarray
    peak_value: np.ndarray
    valid: np.ndarray
    reason: np.ndarray
    last: PlacedTiles
    template_centroid: np.ndarray


def _replace_rows(placed: PlacedTiles, rows: np.ndarray, update: PlacedTiles, *,
                  in_place: bool = True) -> PlacedTiles:
    """``placed`` with ``rows`` set from ``update``.

    With ``in_place`` the arrays of ``placed`` are overwritten; otherwise new
    arrays are filled (``placed`` is left as it was, and only its other rows are copied).
    Descriptors are kept only when ``update`` has them (zero in the other rows).
    """
    others = None
    if not in_place:
        others = np.ones(len(placed.offsets), dtype=bool)
        others[rows] = False

    def merged(old: np.ndarray, new: np.ndarray) -> np.ndarray:
        if in_place:
            old[rows] = new
            return old
        out = np.empty_like(old)
        out[others] = old[others]
        out[rows] = new
        return out

    arrays = {name: merged(getattr(placed, name), getattr(update, name)) for name in ("tiles", "offsets", "linear")}
    spectrum = merged(placed.spectra.spectrum, update.spectra.spectrum)
    std = merged(placed.spectra.std, update.spectra.std)
    descriptor = None
    if update.spectra.descriptor is not None:
        descriptor = np.zeros((len(placed.offsets),) + update.spectra.descriptor.shape[1:],
                              dtype=update.spectra.descriptor.dtype)
        descriptor[rows] = update.spectra.descriptor
    return replace(placed, **arrays, spectra=replace(placed.spectra, spectrum=spectrum, std=std,
                                                     descriptor=descriptor))


def _placement_maps(n: int, offsets: np.ndarray, linear: np.ndarray,
                    curvature: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Source ``(row, col)`` maps ``(K N, N)`` float32 of tiles placed at ``o + L u + q(u)``.

    Each map is ``((L_i0 u_r + L_i1 u_c) + o_i) + ((Q_i00 u_r^2 + 2 Q_i01 u_r u_c) + Q_i11 u_c^2)``
    in float32, summed in this order into preallocated arrays: two full-size passes per map
    (six with curvature) and no full-size temporaries.
    """
    f32 = np.float32
    g = np.arange(n, dtype=f32) - f32((n - 1) / 2.0)
    lin = np.asarray(linear, dtype=f32)
    off = np.asarray(offsets, dtype=f32)
    gr, gc = g[None, :, None], g[None, None, :]
    maps = np.empty((2, len(off), n, n), dtype=f32)
    q = None if curvature is None else np.asarray(curvature, dtype=f32)
    term = None if q is None else np.empty((len(off), n, n), dtype=f32)
    for i in (0, 1):
        out = maps[i]
        np.add(lin[:, i, 0, None, None] * gr, lin[:, i, 1, None, None] * gc, out=out)
        out += off[:, i, None, None]
        if q is not None:
            np.multiply(2 * q[:, i, 0, 1, None, None] * gr, gc, out=term)
            np.add(q[:, i, 0, 0, None, None] * gr * gr, term, out=term)
            term += q[:, i, 1, 1, None, None] * gc * gc
            out += term
    return maps[0].reshape(-1, n), maps[1].reshape(-1, n)


def registration_bytes_per_tile(tile_size: int, *, config: FourierMellinConfig = FourierMellinConfig()) -> int:
    """Bytes that registering one frame pair takes per tile at its peak (an upper bound, measured).

    Parameters
    ----------
    tile_size : int
        ``N``.
    config : FourierMellinConfig, keyword-only
        Its log-polar grid (default ``N`` angles by ``N / 2`` radii) counts besides the tile's pixels.

    Returns
    -------
    int
    """
    n = int(tile_size)
    samples = int(config.log_polar_angles or n) * int(config.log_polar_radii or n // 2)
    return _PEAK_BYTES_PER_TILE_PIXEL * n * n + _PEAK_BYTES_PER_LOG_POLAR_SAMPLE * samples


def max_tile_count(tile_size: int, *, config: FourierMellinConfig = FourierMellinConfig()) -> int:
    """Most tiles of ``tile_size`` px a frame may have: their registration within :data:`TILE_MEMORY_BUDGET_BYTES`.

    For the default 32 px tiles that is 12483 tiles, for 64 px tiles 3120.
    """
    return TILE_MEMORY_BUDGET_BYTES // registration_bytes_per_tile(tile_size, config=config)


class FourierMellin:
    """Precomputed windows, filters and log-polar maps for ``count`` tiles of size ``tile_size``.

    Parameters
    ----------
    tile_size : int
        ``N`` (even).
    count : int
        Number of tiles per frame ``T``.
    config : FourierMellinConfig, keyword-only
    """

    def __init__(self, tile_size: int, count: int, *, config: FourierMellinConfig = FourierMellinConfig()):
        n = int(tile_size)
        if n < MIN_TILE_SIZE_PX or n % 2:
            raise ValueError(f"tile size must be even and >= {MIN_TILE_SIZE_PX}, got {tile_size}")
        limit = max_tile_count(n, config=config)
        if not 1 <= count <= limit:
            raise ValueError(f"tile count must be from 1 to {limit} for {n} px tiles (registering a frame pair "
                             f"within {TILE_MEMORY_BUDGET_BYTES / 2 ** 30:g} GiB), got {count}")
        self.tile_size = n
        self.count = int(count)
        self.config = config
        self.window = hann_window((n, n))
        self.n_angles = int(config.log_polar_angles or n)
        self.n_radii = int(config.log_polar_radii or n // 2)
        r_max = n / 2.0 - 1.0
        r_min = max(1.0, config.min_radius_fraction * r_max)
        if not r_min < r_max:
            raise ValueError(f"log-polar radii {r_min}..{r_max} are empty for {n} px tiles")
        self.log_radius_step = np.log(r_max / r_min) / (self.n_radii - 1)
        # High-pass emphasis on the half plane, rows in fftshift order.
        fr = np.fft.fftshift(np.fft.fftfreq(n))[:, None]
        fc = np.fft.rfftfreq(n)[None, :]
        x = np.cos(np.pi * fr) * np.cos(np.pi * fc)
        self.highpass = ((1.0 - x) * (2.0 - x)).astype(np.float32)
        # Spectrum factor of a point reflection about the tile centre: f[N-1-i, N-1-j] has the
        # rfft2 conj(F[k]) * exp(2 pi i (k_r + k_c) / N).
        k_r = np.arange(n)[:, None]
        k_c = np.arange(n // 2 + 1)[None, :]
        self.flip_ramp = np.exp(2j * np.pi * (k_r + k_c) / n).astype(np.complex64)
        # Log-polar sampling of the stacked half-plane magnitudes (T*N rows).
        phi = np.arange(self.n_angles) * (np.pi / self.n_angles)
        rho = r_min * np.exp(self.log_radius_step * np.arange(self.n_radii))
        rows = n / 2.0 + rho[None, :] * np.cos(phi)[:, None]
        cols = rho[None, :] * np.sin(phi)[:, None]
        # OpenCV's remap takes fewer than 2^15 rows and 16-bit fixed-point maps: the tiles are
        # remapped in chunks of at most ``lp_chunk`` tiles, with the maps of one chunk.
        self.lp_chunk = min(self.count, (_REMAP_MAX_ROWS - 1) // max(n, self.n_angles))
        offsets = (np.arange(self.lp_chunk) * n)[:, None, None]
        lp_rows = (rows[None] + offsets).reshape(-1, self.n_radii).astype(np.float32)
        lp_cols = np.broadcast_to(cols[None], (self.lp_chunk,) + cols.shape).reshape(
            -1, self.n_radii).astype(np.float32)
        # Fixed-point form of the constant maps: remap skips converting them on every call.
        self.lp_map1, self.lp_map2 = cv2.convertMaps(lp_cols, lp_rows, cv2.CV_16SC2)

    # -- per frame ---------------------------------------------------------------------------
    def _windowed_fft(self, tiles: np.ndarray, *, with_centroid: bool = False) -> TileSpectra:
        """Spectra and gray-level spread of tiles, and their energy centroids if asked (no descriptor)."""
        tiles = tiles.astype(np.float32, copy=False)
        k = len(tiles)
        pixels = tiles[0].size
        centred = tiles - (tiles.reshape(k, -1).sum(axis=1) / pixels)[:, None, None]
        flat = centred.reshape(k, -1)
        std = np.sqrt(np.einsum("ki,ki->k", flat, flat) / pixels)
        centred *= self.window
        centroid = energy_centroids(centred) if with_centroid else None
        spectrum = scipy.fft.rfft2(centred, workers=self.config.workers, overwrite_x=True)
        return TileSpectra(spectrum=spectrum.astype(np.complex64, copy=False), descriptor=None, std=std,
                           centroid=centroid)

    def spectra(self, tiles: np.ndarray, *, with_descriptor: bool = True, with_centroid: bool = True) -> TileSpectra:
        """Spectra of one frame's tiles.

        Parameters
        ----------
        tiles : (K, N, N) ndarray
            ``1 <= K <= T`` tiles (all of a frame's, or some of them).
        with_descriptor : bool, keyword-only
            Compute the log-polar descriptor (when rotation and scale are estimated).
        with_centroid : bool, keyword-only
            Compute the energy centroids (:attr:`TileSpectra.centroid`): tiles
            that serve as templates need them, tiles only matched against
            templates do not.

        Returns
        -------
        TileSpectra
        """
        n = self.tile_size
        if tiles.ndim != 3 or tiles.shape[1:] != (n, n) or not 1 <= len(tiles) <= self.count:
            raise ValueError(f"expected tiles of shape (K, {n}, {n}) with 1 <= K <= {self.count}, "
                             f"got {tiles.shape}")
        k = len(tiles)
        windowed = self._windowed_fft(tiles, with_centroid=with_centroid)
        spectrum = windowed.spectrum
        descriptor = None
        if self.config.estimate_rotation_scale and with_descriptor:
            magnitude = np.abs(np.fft.fftshift(spectrum, axes=1)) * self.highpass
            log_polar = np.empty((k, self.n_angles, self.n_radii), dtype=np.float32)
            for first in range(0, k, self.lp_chunk):
                chunk = magnitude[first:first + self.lp_chunk]
                stacked = np.ascontiguousarray(chunk.reshape(-1, chunk.shape[-1]), dtype=np.float32)
                # The maps of the first K tiles read only the first K stacked tiles.
                rows = len(chunk) * self.n_angles
                log_polar[first:first + len(chunk)] = cv2.remap(
                    stacked, self.lp_map1[:rows], self.lp_map2[:rows], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE).reshape(len(chunk), self.n_angles, self.n_radii)
            log_polar -= log_polar.mean(axis=(1, 2), keepdims=True)
            descriptor = scipy.fft.rfft2(log_polar, workers=self.config.workers).astype(np.complex64)
        return replace(windowed, descriptor=descriptor)

    # -- per pair ----------------------------------------------------------------------------
    def _refine(self, spectra_a, spectra_b, shift, shape, *, weight_power=None):
        c = self.config
        if weight_power is None:
            weight_power = c.phase_plane_weight_power
        return refine_shift_phase_plane(spectra_a, spectra_b, shift, shape,
                                        max_frequency=c.phase_plane_max_frequency,
                                        weight_power=weight_power,
                                        iterations=c.phase_plane_iterations)

    def _search_shift(self, spectra_a, spectra_b, peak_shift, shape):
        # The search pass's translation: the parabolic peak when refinement passes measure the
        # residual after it, else the phase-plane fit.
        if self.config.refine_passes:
            return np.asarray(peak_shift, dtype=np.float64)
        return self._refine(spectra_a, spectra_b, peak_shift, shape)

    @property
    def _search_interpolation(self) -> str:
        return "linear" if self.config.refine_passes else self.config.resample_interpolation

    def resample_placed(self, source: np.ndarray, offsets: np.ndarray, linear: np.ndarray, *,
                        interpolation: str | None = None, curvature: np.ndarray | None = None) -> np.ndarray:
        """Tiles ``x(p) = source(o + L u + q(u))``, ``u = p - c``, sampled at placements (one remap call).

        Parameters
        ----------
        source : (H, W) float32 ndarray
        offsets : (K, 2) ndarray
            ``o``: ``(row, col)`` in ``source`` of each tile's centre ``c``.
        linear : (K, 2, 2) ndarray
            ``L``: source ``(row, col)`` per tile ``(row, col)`` step.
        interpolation : {"cubic", "lanczos4", "linear"}, optional, keyword-only
            Default: ``config.resample_interpolation``.
        curvature : (K, 2, 2, 2) ndarray, optional, keyword-only
            Symmetric matrices ``Q_i`` of the second-order term, ``q(u)_i = u^T Q_i u``
            for source row (``i = 0``) and column (``i = 1``); default none.

        Returns
        -------
        (K, N, N) float32 ndarray
        """
        n = self.tile_size
        offsets, linear = np.asarray(offsets), np.asarray(linear)
        curvature = None if curvature is None else np.asarray(curvature)
        kind = _INTERPOLATIONS[interpolation or self.config.resample_interpolation]
        # Maps and remap chunk by chunk of tiles: a chunk's maps are remapped while they are in
        # the cache, and a chunk stays below OpenCV's 2^15 rows. The output is written in place.
        step = max(1, min(_MAP_CHUNK_PIXELS // (n * n), (_REMAP_MAX_ROWS - 1) // n))
        out = np.empty((len(offsets) * n, n), dtype=np.float32)
        for first in range(0, len(offsets), step):
            part = slice(first, first + step)
            map_rows, map_cols = _placement_maps(n, offsets[part], linear[part],
                                                 None if curvature is None else curvature[part])
            cv2.remap(source, map_cols, map_rows, kind, dst=out[first * n:(first + step) * n],
                      borderMode=cv2.BORDER_REFLECT_101)
        return out.reshape(-1, n, n)

    def resample(self, source: np.ndarray, origins: np.ndarray, scale: np.ndarray,
                 angle: np.ndarray, translation: np.ndarray, *, interpolation: str | None = None) -> np.ndarray:
        """Tiles ``b'(p) = b(M^{-1}(p))`` sampled from ``source`` (one remap call).

        Parameters
        ----------
        source : (H, W) float32 ndarray
        origins : (K, 2) ndarray
            ``(row, col)`` in ``source`` of each tile's first pixel (sub-pixel allowed).
        scale, angle : (K,) ndarray
            ``s`` and ``theta`` (radians) of each tile's motion.
        translation : (K, 2) ndarray
            ``t`` of each tile's motion, ``(row, col)`` pixels.
        interpolation : {"cubic", "lanczos4", "linear"}, optional, keyword-only
            Default: ``config.resample_interpolation``.

        Returns
        -------
        (K, N, N) float32 ndarray
        """
        return self.resample_placed(source, *placement_from_motion(origins, scale, angle, translation,
                                                                   self.tile_size),
                                    interpolation=interpolation)

    def _residual_motion(self, spectra_a: TileSpectra, tiles: np.ndarray, *, with_rotation: bool):
        """Residual ``(s, theta, t)`` of tiles already resampled onto tile a, and their spectra."""
        count = len(tiles)
        zeros2 = np.zeros((count, 2))
        shape = (self.tile_size, self.tile_size)
        spectra = self.spectra(tiles, with_descriptor=with_rotation, with_centroid=False)
        d_shift = -self._refine(spectra_a.spectrum, spectra.spectrum, zeros2, shape,
                                weight_power=self.config.residual_weight_power)
        if not with_rotation:
            return np.ones(count), np.zeros(count), d_shift, spectra
        lp_shift = self._refine(spectra_a.descriptor, spectra.descriptor, zeros2, (self.n_angles, self.n_radii))
        d_angle = -lp_shift[:, 0] * (np.pi / self.n_angles)
        d_scale = np.exp(lp_shift[:, 1] * self.log_radius_step)
        return d_scale, d_angle, d_shift, spectra

    def _refined_placement(self, spectra_a: TileSpectra, source_b: np.ndarray, offsets: np.ndarray,
                           linear: np.ndarray, *, with_rotation: bool, curvature: np.ndarray | None = None):
        """``refine_passes`` passes: resample b at the placement, measure the residual, compose.

        Returns the final placement and the last resampled tiles with their
        placement and spectra (None without refinement passes).
        """
        last = None
        for _ in range(self.config.refine_passes):
            tiles = self.resample_placed(source_b, offsets, linear, curvature=curvature)
            d_scale, d_angle, d_shift, spectra = self._residual_motion(spectra_a, tiles,
                                                                       with_rotation=with_rotation)
            last = PlacedTiles(tiles=tiles, offsets=offsets, linear=linear, spectra=spectra, curvature=curvature)
            offsets, linear = compose_placement(offsets, linear, d_scale, d_angle, d_shift)
        return offsets, linear, last

    def _reasons(self, spectra_a: TileSpectra, std_b: np.ndarray, peak_ratio: np.ndarray,
                 pnr: np.ndarray) -> np.ndarray:
        # Later assignments take precedence: a textureless tile is reported as such.
        reason = np.full(len(pnr), TileRejection.KEPT, dtype=np.int64)
        reason[pnr < self.config.th_pnr] = TileRejection.LOW_PEAK_TO_NOISE_RATIO
        reason[peak_ratio < self.config.th_pr] = TileRejection.LOW_PEAK_RATIO
        reason[(spectra_a.std < self.config.min_std) | (std_b < self.config.min_std)] = TileRejection.TEXTURELESS
        return reason

    def register_placed(self, spectra_a: TileSpectra, source_b: np.ndarray, offsets_b: np.ndarray,
                        linear_b: np.ndarray, *, curvature_b: np.ndarray | None = None,
                        refine: bool = True) -> "PlacedRegistration":
        """Register tiles of b cut at predicted affine placements against tiles a.

        Tile b is resampled at its placement (the prediction of where, and how
        distorted, tile a's content appears in b), the translation is measured
        by phase correlation, and the refinement passes measure and compose
        the residual similarity.

        Parameters
        ----------
        spectra_a : TileSpectra
            Spectra of the tiles of a (``T`` tiles).
        source_b : (H, W) float32 ndarray
            Image the tiles of b are resampled from; pad it so that tiles do not leave it.
        offsets_b : (T, 2) ndarray
            Predicted ``(row, col)`` in ``source_b`` of each tile centre.
        linear_b : (T, 2, 2) ndarray
            Predicted ``L`` of each tile (see :meth:`resample_placed`).
        curvature_b : (T, 2, 2, 2) ndarray, optional, keyword-only
            Predicted second-order term of each placement (see :meth:`resample_placed`),
            kept as it is: only the translation (and, if configured, rotation and scale)
            is measured.
        refine : bool, keyword-only
            Run the refinement passes. When false, the translation is the
            phase-plane fit on the search pass's tiles, for a caller that runs
            the refinement itself (:meth:`refine_placed`) with a better shape.

        Returns
        -------
        PlacedRegistration
        """
        source_b = np.ascontiguousarray(source_b, dtype=np.float32)
        offsets_b = np.asarray(offsets_b, dtype=np.float64)
        linear_b = np.asarray(linear_b, dtype=np.float64)
        shape = (self.tile_size, self.tile_size)
        tiles = self.resample_placed(source_b, offsets_b, linear_b, interpolation=self._search_interpolation,
                                     curvature=curvature_b)
        spectra_b = self._windowed_fft(tiles)
        fb, std_b = spectra_b.spectrum, spectra_b.std
        fa = spectra_a.spectrum
        peaks = self._translation_peaks(fa, fb)
        # b'(p) = a(p + t) means b' is a moved by d = -t.
        if refine:
            translation = -self._search_shift(fa, fb, peaks.shift, shape)
        else:
            translation = -self._refine(fa, fb, peaks.shift, shape)
        count = len(offsets_b)
        offsets, linear = compose_placement(offsets_b, linear_b, np.ones(count), np.zeros(count), translation)
        reason = self._reasons(spectra_a, std_b, peaks.peak_ratio, peaks.peak_to_noise)
        # Only the tiles the filters kept are refined; the others keep the search placement.
        keep = np.flatnonzero(reason == TileRejection.KEPT)
        last = PlacedTiles(tiles=tiles, offsets=offsets_b.copy(), linear=linear_b.copy(),
                           spectra=replace(spectra_b, std=std_b.copy()),
                           curvature=curvature_b)
        if refine and self.config.refine_passes and keep.size:
            with_rotation = self.config.estimate_rotation_scale and self.config.refine_predicted_rotation_scale
            kept_offsets, kept_linear, kept_last = self._refined_placement(
                spectra_a.rows(keep), source_b, offsets[keep], linear[keep], with_rotation=with_rotation,
                curvature=None if curvature_b is None else curvature_b[keep])
            offsets[keep], linear[keep] = kept_offsets, kept_linear
            last = _replace_rows(last, keep, kept_last)
        return PlacedRegistration(offsets=offsets, linear=linear, peak_ratio=peaks.peak_ratio,
                                  peak_to_noise=peaks.peak_to_noise, peak_value=peaks.value,
                                  valid=reason == TileRejection.KEPT, reason=reason, last=last,
                                  template_centroid=spectra_a.centroid)

    def refine_placed(self, spectra_a: TileSpectra, source_b: np.ndarray, placed: "PlacedRegistration",
                      linear_b: np.ndarray, *, curvature_b: np.ndarray | None = None) -> "PlacedRegistration":
        """Re-measure the kept tiles of ``placed`` cut with a new shape: refinement passes only.

        The centres start where ``placed`` found them; the tiles are cut with
        ``linear_b`` (and ``curvature_b``) instead of the shape they were
        registered with, and the passes measure the residual as in
        :meth:`register_placed`. Quality figures and rejections stay those of
        ``placed``.

        Parameters
        ----------
        spectra_a : TileSpectra
        source_b : (H, W) float32 ndarray
        placed : PlacedRegistration
            From :meth:`register_placed` on the same tiles and source.
        linear_b : (T, 2, 2) ndarray
        curvature_b : (T, 2, 2, 2) ndarray, optional, keyword-only

        Returns
        -------
        PlacedRegistration
        """
        keep = np.flatnonzero(placed.valid)
        offsets, linear = placed.offsets.copy(), np.array(linear_b, dtype=np.float64)
        last = replace(placed.last, curvature=curvature_b)
        if self.config.refine_passes and keep.size:
            with_rotation = self.config.estimate_rotation_scale and self.config.refine_predicted_rotation_scale
            kept_offsets, kept_linear, kept_last = self._refined_placement(
                spectra_a.rows(keep), np.ascontiguousarray(source_b, dtype=np.float32), offsets[keep], linear[keep],
                with_rotation=with_rotation, curvature=None if curvature_b is None else curvature_b[keep])
            offsets[keep], linear[keep] = kept_offsets, kept_linear
            # New arrays: ``placed`` stays as it was.
            return replace(placed, offsets=offsets, linear=linear,
                           last=_replace_rows(last, keep, kept_last, in_place=False))
        last = replace(last, tiles=last.tiles.copy(), offsets=last.offsets.copy(), linear=last.linear.copy(),
                       spectra=replace(last.spectra, spectrum=last.spectra.spectrum.copy(),
                                       std=last.spectra.std.copy()))
        return replace(placed, offsets=offsets, linear=linear, last=last)

    def _translation_peaks(self, fa: np.ndarray, fb: np.ndarray, *, candidates: int = 1) -> Peaks:
        """Translation peaks of tile spectra ``(T, N, N//2+1)``, band-passed as configured.

        A noise-dominated pair (``noisy_pair_fraction`` of the config) is searched
        again on the band-limited surface. ``candidates`` > 1: the stack holds that
        many candidates of each tile, one after another (``T = candidates * tiles``);
        a tile passes when one of its candidates does.
        """
        c = self.config
        shape = (self.tile_size, self.tile_size)
        cross = normalized_cross_power(fa, fb, lowpass_sigma=c.correlation_lowpass,
                                       highpass_bins=c.correlation_highpass_bins)
        peaks = find_peaks(correlation_surface(cross, shape, workers=c.workers))
        if c.noisy_pair_fraction <= 0 or c.correlation_lowpass is not None:
            return peaks
        passed = (peaks.peak_ratio >= c.th_pr) & (peaks.peak_to_noise >= c.th_pnr)
        if passed.reshape(candidates, -1).any(axis=0).mean() >= c.noisy_pair_fraction:
            return peaks
        cross *= gaussian_lowpass(shape, c.noisy_lowpass)
        if c.noisy_highpass_bins > 0:
            cross *= gaussian_highpass(shape, c.noisy_highpass_bins)
        limited = find_peaks(correlation_surface(cross, shape, workers=c.workers))
        return replace(limited, peak_ratio=limited.peak_ratio * (c.th_pr / c.noisy_th_pr))

    def _search_rotation_scale(self, spectra_a: TileSpectra, spectra_b: TileSpectra, source_b: np.ndarray,
                               origins_b: np.ndarray):
        """Steps 2 and 3 of the module docstring: ``theta`` and ``s`` from the log-polar descriptors,
        the 180-degree ambiguity and the translation peak of the chosen candidate.

        Returns ``(scale, angle, rotation_peak_ratio, fb, peaks)`` with ``fb`` the spectra of the
        re-rotated tiles b and ``peaks`` their translation peaks.
        """
        t = self.count
        workers = self.config.workers
        lp = correlation_surface(normalized_cross_power(spectra_a.descriptor, spectra_b.descriptor),
                                 (self.n_angles, self.n_radii), workers=workers)
        lp_peaks = find_peaks(lp)
        lp_shift = self._refine(spectra_a.descriptor, spectra_b.descriptor, lp_peaks.shift,
                                (self.n_angles, self.n_radii))
        angle = -lp_shift[:, 0] * (np.pi / self.n_angles)
        scale = np.exp(lp_shift[:, 1] * self.log_radius_step)
        # Both candidates of the 180-degree ambiguity: tile b re-rotated by theta, and the same
        # tile turned by another 180 degrees about its centre, which is its point reflection
        # (the window is symmetric), whose spectrum is conj(B) times a phase ramp.
        fb1 = self._windowed_fft(self.resample(source_b, origins_b, scale, angle, np.zeros((t, 2)),
                                               interpolation=self._search_interpolation)).spectrum
        fb2 = np.concatenate([fb1, np.conj(fb1) * self.flip_ramp])
        fa2 = np.concatenate([spectra_a.spectrum, spectra_a.spectrum])
        peaks2 = self._translation_peaks(fa2, fb2, candidates=2)
        index = np.arange(t) + np.where(peaks2.value[t:] > peaks2.value[:t], t, 0)
        angle = np.mod(np.concatenate([angle, angle + np.pi])[index] + np.pi, 2 * np.pi) - np.pi
        peaks = Peaks(shift=peaks2.shift[index], value=peaks2.value[index],
                      peak_ratio=peaks2.peak_ratio[index], peak_to_noise=peaks2.peak_to_noise[index])
        return scale, angle, lp_peaks.peak_ratio, fb2[index], peaks

    def register(self, spectra_a: TileSpectra, spectra_b: TileSpectra, source_b: np.ndarray,
                 origins_b: np.ndarray) -> TileMotion:
        """Register all tile pairs of two frames without a prediction.

        Parameters
        ----------
        spectra_a, spectra_b : TileSpectra
            From :meth:`spectra` of the two frames' tiles.
        source_b : (H, W) float32 ndarray
            Image that tile b was cut from, resampled for the re-rotated,
            re-scaled tiles; pad it so that tiles do not leave it.
        origins_b : (T, 2) ndarray
            ``(row, col)`` in ``source_b`` of each tile's first pixel.

        Returns
        -------
        TileMotion
        """
        n, t = self.tile_size, self.count
        shape = (n, n)
        source_b = np.ascontiguousarray(source_b, dtype=np.float32)
        origins_b = np.asarray(origins_b, dtype=np.float64)
        fa = spectra_a.spectrum
        if self.config.estimate_rotation_scale:
            scale, angle, rotation_ratio, fb, peaks = self._search_rotation_scale(spectra_a, spectra_b,
                                                                                  source_b, origins_b)
        else:
            scale, angle, rotation_ratio = np.ones(t), np.zeros(t), np.full(t, np.nan)
            fb = spectra_b.spectrum
            peaks = self._translation_peaks(fa, fb)
        # b'(p) = a(p + t) means b' is a moved by d = -t.
        translation = -self._search_shift(fa, fb, peaks.shift, shape)
        offsets, linear = placement_from_motion(origins_b, scale, angle, translation, n)
        offsets, linear, _ = self._refined_placement(spectra_a, source_b, offsets, linear,
                                                     with_rotation=self.config.estimate_rotation_scale)
        scale, angle, translation = motion_from_placement(origins_b, offsets, linear, n)
        reason = self._reasons(spectra_a, spectra_b.std, peaks.peak_ratio, peaks.peak_to_noise)
        return TileMotion(scale=scale, angle_rad=angle, translation=translation, peak_ratio=peaks.peak_ratio,
                          peak_to_noise=peaks.peak_to_noise, peak_value=peaks.value,
                          rotation_peak_ratio=rotation_ratio, valid=reason == TileRejection.KEPT, reason=reason)
