"""Batched phase correlation with sub-pixel peaks and quality figures.

Convention: for images related by ``b(x) = a(x - d)`` (the content of ``a``
moved by ``d`` in ``b``), the phase-correlation surface of ``(a, b)`` peaks at
``d``. Coordinates are ``(row, col)``; shifts are wrapped to
``[-size/2, size/2)`` along each axis.

All functions work on stacks ``(T, H, W)`` of equally sized images and their
``rfft2`` spectra ``(T, H, W//2 + 1)``, with one FFT call per step.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft

__all__ = [
    "hann_window",
    "windowed_spectra",
    "gaussian_lowpass",
    "gaussian_highpass",
    "normalized_cross_power",
    "correlation_surface",
    "Peaks",
    "find_peaks",
    "refine_shift_phase_plane",
    "phase_correlation",
]

# Relative floor of the cross-power magnitude; keeps textureless pairs finite.
_POWER_FLOOR = 1e-12
# Half size of the square around the main peak that is excluded when looking
# for the second-highest peak (pixels); covers the main lobe of a windowed peak.
_PEAK_EXCLUSION = 2
# Row and column offsets of a peak's four neighbours: (row -1, row +1, col -1, col +1).
_NEIGHBOUR_ROWS = (-1, 1, 0, 0)
_NEIGHBOUR_COLS = (0, 0, -1, 1)


def hann_window(shape: tuple[int, int]) -> np.ndarray:
    """Separable 2D Hann window, float32, zero-free (periodic form shifted by half a sample).

    Parameters
    ----------
    shape : (int, int)
        ``(rows, cols)``.

    Returns
    -------
    (rows, cols) float32 ndarray
    """
    rows = np.sin(np.pi * (np.arange(shape[0]) + 0.5) / shape[0]) ** 2
    cols = np.sin(np.pi * (np.arange(shape[1]) + 0.5) / shape[1]) ** 2
    return np.outer(rows, cols).astype(np.float32)


def windowed_spectra(stack: np.ndarray, window: np.ndarray, *, workers: int = 1) -> np.ndarray:
    """Real FFTs of images with each image's mean removed and ``window`` applied.

    Parameters
    ----------
    stack : (T, H, W) ndarray
    window : (H, W) ndarray
        E.g. :func:`hann_window`.
    workers : int, keyword-only
        FFT threads.

    Returns
    -------
    (T, H, W // 2 + 1) complex ndarray
    """
    return scipy.fft.rfft2((stack - stack.mean(axis=(1, 2), keepdims=True)) * window, workers=workers)


@lru_cache(maxsize=16)
def gaussian_lowpass(shape: tuple[int, int], sigma: float) -> np.ndarray:
    """Gaussian weight of the ``rfft2`` half plane, ``exp(-|f|^2 / (2 sigma^2))``.

    Weighting the phase-only cross-power spectrum with it convolves the
    correlation surface with a Gaussian of ``1 / (2 pi sigma)`` pixels
    standard deviation: frequencies where image noise outweighs the texture
    no longer count as much as the rest, so a noisy pair's peak stands out.

    Parameters
    ----------
    shape : (int, int)
        ``(rows, cols)`` of the images.
    sigma : float
        Standard deviation in cycles per pixel (> 0).

    Returns
    -------
    (rows, cols // 2 + 1) float32 ndarray
        Read-only (shared between calls).
    """
    if not sigma > 0:
        raise ValueError(f"expected sigma > 0 cycles per pixel, got {sigma}")
    fr = scipy.fft.fftfreq(shape[0])[:, None]
    fc = scipy.fft.rfftfreq(shape[1])[None, :]
    weight = np.exp(-0.5 * (fr * fr + fc * fc) / (sigma * sigma)).astype(np.float32)
    weight.flags.writeable = False
    return weight


@lru_cache(maxsize=16)
def gaussian_highpass(shape: tuple[int, int], bins: float) -> np.ndarray:
    """Gaussian high-pass weight of the ``rfft2`` half plane, ``1 - exp(-|k|^2 / (2 bins^2))``.

    ``k`` is the frequency in samples of the spectrum (cycles per image
    side), so the weight takes away the same few lowest frequencies whatever
    the image size: those the window's own spectrum (about 2 samples wide
    for a Hann window) and structures larger than the image fill.

    Parameters
    ----------
    shape : (int, int)
        ``(rows, cols)`` of the images.
    bins : float
        Standard deviation in frequency samples (> 0).

    Returns
    -------
    (rows, cols // 2 + 1) float32 ndarray
        0 at the zero frequency; read-only (shared between calls).
    """
    if not bins > 0:
        raise ValueError(f"expected bins > 0 frequency samples, got {bins}")
    kr = scipy.fft.fftfreq(shape[0], d=1.0 / shape[0])[:, None]
    kc = scipy.fft.rfftfreq(shape[1], d=1.0 / shape[1])[None, :]
    weight = (-np.expm1(-0.5 * (kr * kr + kc * kc) / (bins * bins))).astype(np.float32)
    weight.flags.writeable = False
    return weight


def normalized_cross_power(spectra_a: np.ndarray, spectra_b: np.ndarray, *,
                           lowpass_sigma: float | None = None, highpass_bins: float = 0.0) -> np.ndarray:
    """Phase-only cross-power spectrum ``conj(A) B / |A B|``, optionally band-passed.

    Parameters
    ----------
    spectra_a, spectra_b : (T, H, W//2+1) complex ndarray
        ``rfft2`` spectra of images ``(H, W)`` with even ``W``.
    lowpass_sigma : float or None, keyword-only
        When given, the spectrum is weighted by :func:`gaussian_lowpass` of
        this standard deviation (cycles per pixel); the peak stays where it
        is and its value drops below 1.
    highpass_bins : float, keyword-only
        When > 0, the spectrum is also weighted by :func:`gaussian_highpass`
        of this standard deviation (frequency samples).

    Returns
    -------
    (T, H, W//2+1) complex ndarray
    """
    cross = np.conj(spectra_a)
    cross *= spectra_b
    magnitude = np.abs(cross)
    floor = _POWER_FLOOR * magnitude.max(axis=(-2, -1), keepdims=True) + np.finfo(np.float32).tiny
    np.maximum(magnitude, floor, out=magnitude)
    # Multiplying by the real reciprocal is several times faster than a complex division.
    np.reciprocal(magnitude, out=magnitude)
    shape = (cross.shape[-2], 2 * (cross.shape[-1] - 1))
    if lowpass_sigma is not None:
        magnitude *= gaussian_lowpass(shape, lowpass_sigma)
    if highpass_bins > 0:
        magnitude *= gaussian_highpass(shape, highpass_bins)
    cross *= magnitude
    return cross


def correlation_surface(cross_power: np.ndarray, shape: tuple[int, int], *, workers: int = 1) -> np.ndarray:
    """Real correlation surfaces ``irfft2(cross_power)``, shape ``(T, H, W)``."""
    return scipy.fft.irfft2(cross_power, s=shape, axes=(-2, -1), workers=workers)


@dataclass(frozen=True)
class Peaks:
    """Highest peak of each correlation surface.

    Attributes
    ----------
    shift : (T, 2) ndarray
        Sub-pixel ``(row, col)`` position, wrapped to ``[-size/2, size/2)``.
    value : (T,) ndarray
        Surface value at the integer peak (1 for identical images).
    peak_ratio : (T,) ndarray
        Peak value over the highest value outside the peak's main lobe.
    peak_to_noise : (T,) ndarray
        ``(peak - mean) / std`` of the surface.
    """

    shift: np.ndarray
    value: np.ndarray
    peak_ratio: np.ndarray
    peak_to_noise: np.ndarray


def _wrap(index: np.ndarray, size: int) -> np.ndarray:
    return (index + size // 2) % size - size // 2


def find_peaks(surface: np.ndarray) -> Peaks:
    """Locate the highest peak of each surface with a sub-pixel parabolic fit.

    Parameters
    ----------
    surface : (T, H, W) ndarray
        Correlation surfaces (circular).

    Returns
    -------
    Peaks
    """
    t, h, w = surface.shape
    flat = surface.reshape(t, -1)
    arg = np.argmax(flat, axis=1)
    r, c = np.divmod(arg, w)
    tiles = np.arange(t)
    value = flat[tiles, arg]
    # The four neighbours (row -1, row +1, col -1, col +1) of every peak in one gather; then the
    # vertex of the parabola through each axis' three values, both axes at once.
    near = surface[tiles[:, None], (r[:, None] + _NEIGHBOUR_ROWS) % h, (c[:, None] + _NEIGHBOUR_COLS) % w]
    minus, plus = near[:, 0::2], near[:, 1::2]  # (T, 2): (row, col)
    denom = minus - 2.0 * value[:, None] + plus
    curved = np.abs(denom) > 1e-12
    sub = np.where(curved, 0.5 * (minus - plus) / np.where(curved, denom, -1.0), 0.0)
    sub = np.minimum(np.maximum(sub, -0.5), 0.5)
    shift = np.stack([_wrap(r, h) + sub[:, 0], _wrap(c, w) + sub[:, 1]], axis=1)

    mean = flat.mean(axis=1)
    std = np.sqrt(np.maximum(np.einsum("ti,ti->t", flat, flat) / flat.shape[1] - mean * mean, 0.0))
    # The highest value outside the peak's main lobe: the lobe's values are set aside, the
    # maximum taken, and the values put back (the surface is left as it was).
    offsets = np.arange(-_PEAK_EXCLUSION, _PEAK_EXCLUSION + 1)
    rr = (r[:, None, None] + offsets[None, :, None]) % h
    cc = (c[:, None, None] + offsets[None, None, :]) % w
    index = (tiles[:, None], (rr * w + cc).reshape(t, -1))
    if not flat.flags.writeable:
        flat = flat.copy()
    lobe = flat[index]
    flat[index] = -np.inf
    second = flat.max(axis=1)
    flat[index] = lobe
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(second > 0, value / np.where(second > 0, second, 1.0), np.inf)
        ratio = np.where(value > 0, ratio, 0.0)
        pnr = np.where(std > 0, (value - mean) / np.where(std > 0, std, 1.0), 0.0)
    return Peaks(shift=shift, value=value, peak_ratio=ratio, peak_to_noise=pnr)


@lru_cache(maxsize=16)
def _frequency_band(shape: tuple[int, int], max_frequency: float):
    """Flat indices of the rfft2 half plane with 0 < |f| <= max_frequency, their frequencies
    ``(B, 2)`` (cycles per pixel, ``(row, col)``) and the products ``(B, 3)`` of the normal equations."""
    fr = scipy.fft.fftfreq(shape[0])[:, None]
    fc = scipy.fft.rfftfreq(shape[1])[None, :]
    radius = np.hypot(fr, fc)
    band = np.flatnonzero((radius <= max_frequency) & (radius > 0))
    f_r = np.broadcast_to(fr, radius.shape).ravel()[band]
    f_c = np.broadcast_to(fc, radius.shape).ravel()[band]
    freqs = np.stack([f_r, f_c], axis=1).astype(np.float32)
    products = np.stack([f_r * f_r, f_r * f_c, f_c * f_c], axis=1).astype(np.float32)
    return band, freqs, products


def refine_shift_phase_plane(spectra_a: np.ndarray, spectra_b: np.ndarray, shift: np.ndarray,
                             shape: tuple[int, int], *, max_frequency: float = 0.35,
                             weight_power: float = 0.25, iterations: int = 2) -> np.ndarray:
    """Refine shifts by a weighted least-squares fit of the cross-spectrum's phase plane.

    For ``b(x) = a(x - d)`` the phase of ``conj(A) B`` is ``-2 pi f . d`` at
    frequency ``f`` (cycles per pixel). After removing the current estimate
    the residual phase is small and, weighted by ``|A B| ** weight_power``
    over frequencies up to ``max_frequency``, gives the residual shift in
    closed form. A small power keeps the strong low frequencies, whose phase
    the window distorts most when the shift is large, from dominating the
    fit. For shifts of a small fraction of a pixel the window distortion is
    negligible and the power 1 (weight ``|A B|``) is preferable: with white
    image noise the phase variance at a frequency is about
    ``sigma^2 (1/|A|^2 + 1/|B|^2) / 2``, so ``|A B|`` approximates
    inverse-variance weighting for ``|A| ~ |B|``.

    Parameters
    ----------
    spectra_a, spectra_b : (T, H, W//2+1) complex ndarray
        ``rfft2`` spectra of the (windowed) images.
    shift : (T, 2) ndarray
        Initial ``(row, col)`` shifts, within half a pixel of the truth.
    shape : (int, int)
        ``(H, W)`` of the images.
    max_frequency : float, keyword-only
        Largest frequency used, cycles per pixel.
    weight_power : float, keyword-only
        Exponent of the cross-spectrum magnitude used as weight.
    iterations : int, keyword-only

    Returns
    -------
    (T, 2) ndarray
        Refined shifts.
    """
    band, freqs, products = _frequency_band(tuple(shape), float(max_frequency))
    cross = np.take(spectra_a.reshape(len(spectra_a), -1), band, axis=1)
    np.conj(cross, out=cross)
    cross *= np.take(spectra_b.reshape(len(spectra_b), -1), band, axis=1)
    weight = np.abs(cross)
    if weight_power != 1.0:
        weight **= weight_power
    phase = np.angle(cross)
    # (T, 3): sums of w fr^2, w fr fc, w fc^2. The weights go in column-major, the layout BLAS
    # has always summed them in (its float32 rounding depends on it: estimates stay bit-identical).
    normal = (np.asfortranarray(weight) @ products).astype(np.float64)
    a11, a12, a22 = normal[:, 0], normal[:, 1], normal[:, 2]
    det = a11 * a22 - a12 * a12
    ok = det > 1e-12 * np.maximum(a11 * a22, 1e-300)
    safe = np.where(ok, det, 1.0)
    shift = np.array(shift, dtype=np.float64)
    two_pi = np.float32(2 * np.pi)
    residual = np.empty(phase.shape, dtype=np.float32)
    turns = np.empty_like(residual)
    for _ in range(iterations):
        # Residual phase after removing the current shift, wrapped to [-pi, pi): ~ -2 pi f . delta.
        # (In place; the same float32 operations as phase + 2 pi (shift . f) - 2 pi round(...).)
        np.matmul(shift.astype(np.float32), freqs.T, out=residual)
        residual *= two_pi
        residual += phase
        np.divide(residual, two_pi, out=turns)
        np.round(turns, out=turns)
        turns *= two_pi
        residual -= turns
        residual *= weight
        rhs = -(residual @ freqs).astype(np.float64) / (2 * np.pi)  # (T, 2)
        delta = np.stack([(a22 * rhs[:, 0] - a12 * rhs[:, 1]) / safe,
                          (a11 * rhs[:, 1] - a12 * rhs[:, 0]) / safe], axis=1)
        delta = np.where(ok[:, None], np.clip(delta, -1.0, 1.0), 0.0)
        shift = shift + delta
    return shift


def phase_correlation(a: np.ndarray, b: np.ndarray, *, refine: bool = True,
                      workers: int = 1) -> tuple[np.ndarray, Peaks]:
    """Shift ``d`` with ``b(x) = a(x - d)`` of image pairs (mean removed, Hann window).

    Parameters
    ----------
    a, b : (T, H, W) or (H, W) array_like
    refine : bool, keyword-only
        Refine the parabolic peak by the phase-plane fit.
    workers : int, keyword-only
        FFT threads.

    Returns
    -------
    shift : (T, 2) or (2,) ndarray
        ``(row, col)`` shift in pixels.
    peaks : Peaks
    """
    a = np.asarray(a, dtype=np.float32)
    b = np.asarray(b, dtype=np.float32)
    single = a.ndim == 2
    if single:
        a, b = a[None], b[None]
    if a.shape != b.shape or a.ndim != 3:
        raise ValueError(f"expected two stacks of equal shape (T, H, W), got {a.shape} and {b.shape}")
    shape = a.shape[1:]
    window = hann_window(shape)
    fa = windowed_spectra(a, window, workers=workers)
    fb = windowed_spectra(b, window, workers=workers)
    peaks = find_peaks(correlation_surface(normalized_cross_power(fa, fb), shape, workers=workers))
    shift = peaks.shift
    if refine:
        shift = refine_shift_phase_plane(fa, fb, shift, shape)
    return (shift[0] if single else shift), peaks
