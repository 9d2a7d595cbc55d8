"""Coarse stage: the large part of a frame pair's rotation from whole low-resolution panoramas.

Phase correlation on a tile only measures shifts below half a tile, so fast
motion has to be removed before the tiles look. The panorama makes this
cheap: a rotation about the mirror axis (yaw) is a circular horizontal
shift of the whole panorama, and a tilt moves each azimuth sector up or down
along a sinusoid of the azimuth. The coarse stage works on panoramas
downsampled to ``GlobalMotionConfig.width`` columns:

1. *yaw search*: frame b's panorama, warped by the current rotation, is
   phase-correlated with frame a's over its whole width (Hann window along
   the rows only, so the circular column shift of any yaw is found);
2. *sector refinement*: the panoramas are cut into ``sectors`` full-height
   azimuth sectors; each sector's shift ``(row, col)`` between a and b
   (warped by the current rotation) turns its centre into a ray pair, and
   the rotation follows from all pairs by a weighted least-squares fit
   (Kabsch); sectors whose residual is far above the others' (parallax,
   moving objects) are left out. Frame b is warped again with the new
   rotation and the sectors measured again, ``iterations`` times.

A rotation ``R_ab`` (frame-b directions to frame-a directions) is found
whatever the yaw, and tilts up to about a quarter of the band's height per
pass. Its accuracy is a fraction of a coarse pixel, enough for the tiles,
which measure the remaining motion at full resolution.

Panorama pixels are ``(row, col)``; the coarse panorama's pixel ``(i, j)``
covers full-resolution ``((i + 0.5) s_r - 0.5, (j + 0.5) s_c - 0.5)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
import scipy.fft

from ifmi.geometry.rotations import matrix_from_rpy
from ifmi.spectral.phase_correlation import (correlation_surface, find_peaks, hann_window, normalized_cross_power,
                                windowed_spectra)
from ifmi.spectral.panorama import PanoramaMapping, rays_from_panorama_pixels

__all__ = ["GlobalMotionConfig", "GlobalMotion", "GlobalMotionEstimator", "rotation_from_ray_pairs"]

# Fewest coarse-panorama columns of a sector: a Hann-windowed phase correlation over fewer
# leaves no usable peak (the default 12 sectors of a 128-column panorama have 10).
_MIN_SECTOR_COLUMNS = 8
# Most starts of the wide search's grid: each costs a yaw search of the coarse panorama (0.4 ms
# at its default 128 columns), so 1024 starts keep a searched pair under half a second; a step
# of 0.01 degrees (2.5 million starts) took minutes per pair, and 1e-300 failed allocating them.
_MAX_WIDE_STARTS = 1024
# Most sector passes: each fits the sectors again at the last rotation (default 2 passes); 100
# added 0.2 s to seven fast 256 px pairs, while 10**20 never ended (the passes stop only when too
# few sectors are clear).
_MAX_SECTOR_ITERATIONS = 100


@dataclass(frozen=True)
class GlobalMotionConfig:
    """Options of the coarse stage.

    Attributes
    ----------
    width : int
        Columns of the coarse panorama (360 degrees); the height keeps the
        panorama's aspect. Capped at the panorama's own width.
    sectors : int
        Azimuth sectors measured for the tilt (at least 3 are needed for
        a rotation; more average parallax and texture gaps), each at least
        8 columns of the coarse panorama wide.
    iterations : int
        Sector passes after the yaw search (at most 100).
    min_peak_ratio : float
        A sector (or the yaw search) whose correlation peak ratio is below
        this does not count.
    min_sectors : int
        Fewer counted sectors than this keeps the yaw search's rotation.
    outlier_factor : float
        A sector whose residual exceeds this many times the median residual
        (and one coarse pixel) is left out of the final fit.
    confirm_angle_rad : float
        When the search from the first starting rotation moves it by more
        than this (radians), the other starts are searched too and the best
        match wins; a good prediction is only corrected by a few degrees,
        while a wrong peak of a repetitive scene moves it far.
    wide_tilt_max_deg, wide_tilt_step_deg : float
        Grid of the wide search (:meth:`GlobalMotionEstimator.wide_search`):
        starts tilted about the two horizontal axes by multiples of the step
        up to the maximum (degrees; 8 starts with the defaults; the sectors
        reach about 8 degrees of yaw and of tilt from a start, so the grid
        covers tilts between frames up to about 15 degrees; a 6-degree step
        up to 12, 24 starts, gave the same results on the lawn pairs that
        need it at twice the cost).
        ``wide_tilt_max_deg = 0`` turns the wide search off. The grid
        holds at most 1024 starts (728 in steps of 0.6 degrees up to 8).
    wide_candidates : int
        The wide search runs the yaw search from every start of the grid
        and the sector passes only from this many, those whose yaw
        correlation peaks clearest (from a start near the true tilt the
        peak ratio was 2.4 to 6.8 on lawn pairs, from the others mostly
        1.0 to 2.3). A pair that fails anyway is searched from every start
        (:meth:`GlobalMotionEstimator.wide_search`, ``every_start``): on the
        first pairs of translated sets at about 26 degrees per frame (the
        atelier and office renders of seeds 11 and 5, every 10th frame) the
        two clearest peaks were wrong starts, 0.17-0.47 rad off, while the
        best of all eight came within 0.04-0.09 rad.
    confirm_mismatch_ratio : float
        A result of the search from another start (see
        ``confirm_angle_rad``) that lies more than ``confirm_angle_rad``
        from the first start's result replaces it only when its mismatch
        ``1 - score`` is at most this fraction of that one's. In a room of
        one texture seen from near its middle (brick on every wall) the
        panorama turned half round matches about as well as the true one:
        on a translated fast set of a room never used before (the atelier,
        every 10th frame) the search from the identity landed 3.12 rad off
        with a score of 0.5912, the search from the prediction 0.034 rad
        off with 0.5880, and the track never recovered (2.65 rad ATE). Over
        every such pair of the 126 fast 256 px sets, both modes (25 pairs
        with one of the two results right and the other more than 0.1 rad
        off), a right result from another start left 0.03-0.26 of the
        first's mismatch, a wrong one 0.99 or more of it.
    wide_mismatch_ratio : float
        A wide search result is clearly better than the rotation found
        before (:meth:`GlobalMotionEstimator.clearly_better`) when it lies
        more than ``confirm_angle_rad`` from it and its mismatch
        ``1 - score`` is at most this fraction of that one's. A wrong yaw
        leaves a clear mismatch that the right one removes (lawn pairs
        tilted by 10 degrees: 0.037 against 0.005), while under parallax
        every coarse rotation leaves most of it (office with translation:
        0.32 against 0.30), and there the scores do not rank rotations a
        few degrees apart: a result that only matches better is taken
        only for a pair that cannot be solved otherwise
        (the rescue stage of :mod:`ifmi.spectral.pair_pipeline`).
    settled_shift_px : float
        When the whole-panorama shift from a start is below this (coarse
        pixels) along both axes, the start is returned as it is and the
        sector passes are skipped (the usual case while tracking, which
        keeps the stage cheap); a tilt error the whole-panorama shift does
        not show is then left to the tiles, whose failure triggers the
        search from the identity.
    """

    width: int = 128
    sectors: int = 12
    iterations: int = 2
    min_peak_ratio: float = 1.2
    min_sectors: int = 4
    outlier_factor: float = 3.0
    confirm_angle_rad: float = 0.1
    settled_shift_px: float = 0.5
    wide_tilt_max_deg: float = 8.0
    wide_tilt_step_deg: float = 8.0
    wide_candidates: int = 2
    wide_mismatch_ratio: float = 0.5
    confirm_mismatch_ratio: float = 0.5

    def __post_init__(self) -> None:
        if self.width < 32 or not 3 <= self.sectors <= self.width // _MIN_SECTOR_COLUMNS or self.iterations < 0:
            raise ValueError(f"expected width >= 32, 3 <= sectors <= width // {_MIN_SECTOR_COLUMNS} "
                             f"({self.width // _MIN_SECTOR_COLUMNS}), iterations >= 0; got "
                             f"{self.width}, {self.sectors}, {self.iterations}")
        if not 3 <= self.min_sectors <= self.sectors:
            raise ValueError(f"expected 3 <= min_sectors <= sectors, got {self.min_sectors}, {self.sectors}")
        if self.min_peak_ratio < 0 or not self.outlier_factor > 1 or not self.confirm_angle_rad > 0 \
                or self.settled_shift_px < 0 or self.wide_tilt_max_deg < 0 or not self.wide_tilt_step_deg > 0 \
                or not 0 < self.wide_mismatch_ratio <= 1 or self.wide_candidates < 1 \
                or not 0 < self.confirm_mismatch_ratio <= 1:
            raise ValueError(f"expected min_peak_ratio >= 0, outlier_factor > 1, confirm_angle_rad > 0, "
                             f"settled_shift_px >= 0, wide_tilt_max_deg >= 0, wide_tilt_step_deg > 0, "
                             f"0 < wide_mismatch_ratio <= 1, wide_candidates >= 1, "
                             f"0 < confirm_mismatch_ratio <= 1; got "
                             f"{self.min_peak_ratio}, {self.outlier_factor}, {self.confirm_angle_rad}, "
                             f"{self.settled_shift_px}, {self.wide_tilt_max_deg}, {self.wide_tilt_step_deg}, "
                             f"{self.wide_mismatch_ratio}, {self.wide_candidates}, {self.confirm_mismatch_ratio}")
        self._check_search_sizes()

    def _check_search_sizes(self) -> None:
        """Bounds of the work a pair may cost: sector passes and starts of the wide search's grid."""
        if self.iterations > _MAX_SECTOR_ITERATIONS:
            raise ValueError(f"expected iterations <= {_MAX_SECTOR_ITERATIONS} sector passes, got {self.iterations}")
        steps = _wide_steps(self)
        starts = (2 * steps + 1) * (2 * steps + 1) - 1
        if not starts <= _MAX_WIDE_STARTS:
            count = f"{starts:.0f}" if starts < 1e15 else f"{starts:.3g}"
            raise ValueError(f"expected a wide search grid of at most {_MAX_WIDE_STARTS} starts, got "
                             f"{count} (wide_tilt_max_deg {self.wide_tilt_max_deg:g} in steps of "
                             f"wide_tilt_step_deg {self.wide_tilt_step_deg:g}); expected a larger step or a "
                             "smaller maximum")


def _wide_steps(config: GlobalMotionConfig) -> float:
    """Steps of the wide search's grid each side of its start, along each axis (may be infinite)."""
    return float(np.floor(config.wide_tilt_max_deg / config.wide_tilt_step_deg + 1e-9))


@dataclass(frozen=True)
class GlobalMotion:
    """Result of :meth:`GlobalMotionEstimator.estimate`.

    Attributes
    ----------
    rotation : (3, 3) ndarray
        ``R_ab``; the starting rotation when ``success`` is false.
    success : bool
    reason : str
        Empty on success.
    yaw_peak_ratio : float
        Peak ratio of the whole-panorama correlation.
    n_sectors : int
        Sectors used in the last fit (0 when only the yaw search counted).
    score : float
        Normalised cross-correlation of panorama a with panorama b warped
        by ``rotation`` (1 for a perfect match of a pure rotation).
    """

    rotation: np.ndarray
    success: bool
    reason: str
    yaw_peak_ratio: float
    n_sectors: int
    score: float


def _angle(rotation: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))


def rotation_from_ray_pairs(rays_a: np.ndarray, rays_b: np.ndarray,
                            weights: np.ndarray | None = None) -> np.ndarray:
    """Rotation ``R`` minimising ``sum w |r_a - R r_b|^2`` (Kabsch).

    Parameters
    ----------
    rays_a, rays_b : (N, 3) ndarray
        Unit rays, ``N >= 2`` not all parallel.
    weights : (N,) ndarray, optional
        Non-negative; default all 1.

    Returns
    -------
    (3, 3) ndarray
    """
    w = np.ones(len(rays_a)) if weights is None else np.asarray(weights, dtype=np.float64)
    h = (rays_b * w[:, None]).T @ rays_a
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


class _ReferenceSpectra:
    """Spectra of panorama a, computed once per :meth:`GlobalMotionEstimator.estimate` on first use."""

    def __init__(self, estimator: "GlobalMotionEstimator", coarse_a: np.ndarray):
        self._estimator = estimator
        self.coarse = coarse_a

    @cached_property
    def whole(self) -> np.ndarray:
        return self._estimator._yaw_spectrum(self.coarse)

    @cached_property
    def sectors(self) -> np.ndarray:
        return self._estimator._sector_spectra(self.coarse)


class GlobalMotionEstimator:
    """Coarse rotation between two panoramas of one :class:`~ifmi.spectral.panorama.PanoramaMapping`.

    Parameters
    ----------
    mapping : PanoramaMapping
    config : GlobalMotionConfig, keyword-only
    """

    def __init__(self, mapping: PanoramaMapping, *, config: GlobalMotionConfig = GlobalMotionConfig()):
        self.mapping = mapping
        self.config = config
        width = min(config.width, mapping.width)
        height = max(8, int(round(mapping.height * width / mapping.width)))
        self.shape = (height, width)
        self.scale = np.array([mapping.height / height, mapping.width / width])
        rows, cols = np.mgrid[0:height, 0:width].astype(np.float64)
        full = self._full_from_coarse(np.stack([rows, cols], axis=-1))
        self.rays32 = rays_from_panorama_pixels(mapping, full).astype(np.float32)
        self.sector_width = width // config.sectors
        self.row_window = np.sin(np.pi * (np.arange(height) + 0.5) / height).astype(np.float32)[:, None] ** 2
        self.sector_window = hann_window((height, self.sector_width))
        # Sector centres (coarse (row, col)) and the sectors' first column.
        self.sector_cols = (np.arange(config.sectors) * width) // config.sectors
        self.sector_centres = np.stack([np.full(config.sectors, (height - 1) / 2.0),
                                        self.sector_cols + (self.sector_width - 1) / 2.0], axis=1)

    def _full_from_coarse(self, coarse: np.ndarray) -> np.ndarray:
        return (coarse + 0.5) * self.scale - 0.5

    def coarse_panorama(self, panorama: np.ndarray) -> np.ndarray:
        """Downsampled panorama ``(h, w)`` float32 of a full ``(height, width)`` one (area averaging)."""
        if panorama.shape != (self.mapping.height, self.mapping.width):
            raise ValueError(f"expected a panorama of shape {(self.mapping.height, self.mapping.width)}, "
                             f"got {panorama.shape}")
        return cv2.resize(panorama, self.shape[::-1], interpolation=cv2.INTER_AREA).astype(np.float32)

    def warped(self, coarse_b: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """Coarse panorama of b resampled onto a's grid under ``R_ab`` (bilinear; rows past the band replicated)."""
        if np.array_equal(rotation, np.eye(3)):
            return coarse_b
        # panorama_pixels_from_rays in float32 (a coarse pixel is far above its rounding), then coarse pixels.
        rays = self.rays32 @ rotation.astype(np.float32)
        x, y, z = rays[..., 0], rays[..., 1], rays[..., 2]
        m = self.mapping
        theta = np.arctan2(z, np.hypot(x, y))
        rows = ((m.elevation_top_rad - theta) / m.elevation_step_rad + 0.5) / self.scale[0] - 0.5
        cols = np.mod(np.arctan2(y, x) * (self.shape[1] / (2 * np.pi)), self.shape[1])
        # Column of the coarse grid: (full + 0.5) / s - 0.5 with full = phi W / (2 pi).
        cols = cols - 0.5 / self.scale[1] * (self.scale[1] - 1)
        pad = 2
        wrapped = np.concatenate([coarse_b[:, -pad:], coarse_b, coarse_b[:, :pad]], axis=1)
        return cv2.remap(wrapped, (cols + pad).astype(np.float32), rows.astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def _ray_pairs(self, centres: np.ndarray, shifts: np.ndarray, rotation: np.ndarray):
        """Rays of a at ``centres`` and of b where a warped b shows them (``centres + shifts``)."""
        rays_a = rays_from_panorama_pixels(self.mapping, self._full_from_coarse(centres))
        rays_b = rays_from_panorama_pixels(self.mapping, self._full_from_coarse(centres + shifts)) @ rotation
        return rays_a, rays_b

    def _yaw_spectrum(self, image: np.ndarray) -> np.ndarray:
        """Spectrum ``(1, h, w//2+1)`` of a whole coarse panorama, mean removed, windowed along the rows."""
        return scipy.fft.rfft2((image - image.mean()) * self.row_window)[None]

    def _sector_spectra(self, image: np.ndarray) -> np.ndarray:
        """Spectra ``(S, h, sector_width//2+1)`` of a coarse panorama's sectors, each mean-free and Hann-windowed."""
        cols = self.sector_cols[:, None] + np.arange(self.sector_width)
        sectors = np.moveaxis(image[:, cols], 1, 0)
        return windowed_spectra(sectors, self.sector_window)

    def _yaw_search(self, spectrum_a: np.ndarray, warped_b: np.ndarray, *,
                    max_col_shift: float | None = None) -> tuple[np.ndarray, float]:
        """Whole-panorama shift ``(row, col)`` of warped b against a (a's :meth:`_yaw_spectrum`), and its peak
        ratio; with ``max_col_shift`` (coarse columns) the peak is taken among shifts up to that."""
        surface = correlation_surface(normalized_cross_power(spectrum_a, self._yaw_spectrum(warped_b)), self.shape)
        if max_col_shift is not None:
            width = self.shape[1]
            shifts = (np.arange(width) + width // 2) % width - width // 2
            surface[..., np.abs(shifts) > max_col_shift] = surface.min()
        peaks = find_peaks(surface)
        return peaks.shift[0], float(peaks.peak_ratio[0])

    def _sector_fit(self, sectors_a: np.ndarray, warped_b: np.ndarray, rotation: np.ndarray):
        """Refined ``R_ab`` from the sector shifts (a's :meth:`_sector_spectra`), and the number of
        sectors used (None if too few)."""
        c = self.config
        shape = (self.shape[0], self.sector_width)
        peaks = find_peaks(correlation_surface(normalized_cross_power(sectors_a, self._sector_spectra(warped_b)),
                                               shape))
        shifts = peaks.shift
        limit = np.array(shape) / 2.0
        ok = (peaks.peak_ratio >= c.min_peak_ratio) & np.all(np.abs(shifts) < limit, axis=1)
        if ok.sum() < c.min_sectors:
            return None, int(ok.sum())
        rays_a, rays_b = self._ray_pairs(self.sector_centres[ok], shifts[ok], rotation)
        weights = peaks.value[ok]
        fitted = rotation_from_ray_pairs(rays_a, rays_b, weights)
        residual = np.linalg.norm(rays_a - rays_b @ fitted.T, axis=1)
        pixel = self.mapping.elevation_step_rad * self.scale[0]
        keep = residual <= max(c.outlier_factor * np.median(residual), pixel)
        if keep.sum() >= c.min_sectors and not keep.all():
            fitted = rotation_from_ray_pairs(rays_a[keep], rays_b[keep], weights[keep])
        return fitted, int(keep.sum())

    def score(self, coarse_a: np.ndarray, warped_b: np.ndarray) -> float:
        """Normalised cross-correlation of two coarse panoramas on one grid."""
        a = coarse_a - coarse_a.mean()
        b = warped_b - warped_b.mean()
        norm = float(np.sqrt(np.vdot(a, a) * np.vdot(b, b)))
        return float(np.vdot(a, b)) / norm if norm > 0 else 0.0

    def estimate(self, coarse_a: np.ndarray, coarse_b: np.ndarray, *,
                 priors: tuple = (None,)) -> GlobalMotion:
        """Coarse ``R_ab`` of two coarse panoramas (:meth:`coarse_panorama`).

        The search runs from the first starting rotation in ``priors``, and
        from the others when it moved the first by more than
        ``config.confirm_angle_rad``; the result whose warped panorama b
        matches a best (:meth:`score`) is returned, and a start that matches
        better than every search result is kept unchanged (a search that
        locked onto a wrong peak of a repetitive scene does not replace a
        good prediction). A result from another start that lies far from
        the first start's must match clearly better
        (``config.confirm_mismatch_ratio``).

        Parameters
        ----------
        coarse_a, coarse_b : (h, w) float32 ndarray
        priors : tuple of (3, 3) ndarray or None, keyword-only
            Starting ``R_ab`` values (predictions); None is the identity.

        Returns
        -------
        GlobalMotion
        """
        best = None
        reference = _ReferenceSpectra(self, coarse_a)
        searched = []
        for prior in priors:
            start = np.eye(3) if prior is None else np.asarray(prior, dtype=np.float64)
            if any(np.array_equal(start, other) for other in searched):
                continue  # the same search again (e.g. a prediction that is the identity) gives the same result
            searched.append(start)
            found, start_score = self._search(reference, coarse_b, start)
            if best is None and _angle(start.T @ found.rotation) <= self.config.confirm_angle_rad:
                return found
            results = [found]
            if start_score > found.score:
                results.append(GlobalMotion(start, found.success, found.reason, found.yaw_peak_ratio, 0,
                                            start_score))
            result = max(results, key=lambda result: (result.success, result.score))
            best = result if best is None or self._confirms(best, result) else best
        return best

    def _confirms(self, first: GlobalMotion, other: GlobalMotion) -> bool:
        """Whether ``other`` (from a later start) replaces ``first`` (from the first start): it succeeded where
        ``first`` failed, or matches better, clearly so when it lies more than ``confirm_angle_rad`` away."""
        if other.success != first.success:
            return other.success
        if other.score <= first.score:
            return False
        far = _angle(first.rotation.T @ other.rotation) > self.config.confirm_angle_rad
        return not far or 1.0 - other.score <= self.config.confirm_mismatch_ratio * (1.0 - first.score)

    def wide_search(self, coarse_a: np.ndarray, coarse_b: np.ndarray, *, start: np.ndarray | None,
                    current_score: float, every_start: bool = False) -> GlobalMotion | None:
        """The search from tilted copies of ``start``, when it matches better than ``current_score``.

        For pairs whose tiles failed at the rotation :meth:`estimate` gave:
        under a tilt of more than a few degrees the whole-panorama
        correlation is smeared and its peak, weak or not, can lie at any
        yaw. From a start near the true tilt the peak is clear and the
        sectors converge. The starts are ``start`` tilted about a's two
        horizontal axes by the grid of ``config.wide_tilt_step_deg`` up to
        ``config.wide_tilt_max_deg``.

        Parameters
        ----------
        coarse_a, coarse_b : (h, w) float32 ndarray
        start : (3, 3) ndarray or None, keyword-only
            ``R_ab`` the grid is centred on (None: the identity).
        current_score : float, keyword-only
            :meth:`score` of the ``R_ab`` found before (by :meth:`estimate`).
        every_start : bool, keyword-only
            Run the sector passes from every start of the grid instead of
            the ``config.wide_candidates`` clearest.

        Returns
        -------
        GlobalMotion or None
            The best search from the grid, if it succeeded and matches
            better than ``current_score``; else None. Whether it is clearly
            better, far from that rotation and removing most of its
            mismatch, :meth:`clearly_better` tells.
        """
        c = self.config
        start = np.eye(3) if start is None else np.asarray(start, dtype=np.float64)
        reference = _ReferenceSpectra(self, coarse_a)
        starts = self._tilted_starts(start)
        # Only the starts whose yaw search peaks clearest get the sector passes.
        ratios = [self._yaw_search(reference.whole, self.warped(coarse_b, tilted))[1] for tilted in starts]
        clearest = np.argsort(ratios, kind="stable")[::-1][:len(starts) if every_start else c.wide_candidates]
        # Every candidate is searched: the clearest can land on the same wrong yaw as before.
        wide = max((self._search(reference, coarse_b, starts[k])[0] for k in clearest),
                   key=lambda result: (result.success, result.score), default=None)
        if wide is None or not wide.success or wide.score <= current_score:
            return None
        return wide

    def search_near(self, coarse_a: np.ndarray, coarse_b: np.ndarray, *, starts: np.ndarray,
                    max_yaw_rad: float) -> GlobalMotion:
        """The search of :meth:`estimate` from each of ``starts`` with its yaw kept near the start; the best match.

        The whole-panorama peak is taken among shifts of at most
        ``max_yaw_rad`` about the panorama axis, so a scene that matches
        itself farther round (a room turned half round) cannot pull the
        search there; the sector passes follow as usual.

        Parameters
        ----------
        coarse_a, coarse_b : (h, w) float32 ndarray
        starts : (K, 3, 3) ndarray, keyword-only
            Starting ``R_ab`` values, ``K >= 1``.
        max_yaw_rad : float, keyword-only
            Largest yaw correction of the whole-panorama search, radians.

        Returns
        -------
        GlobalMotion
            The result whose warped panorama b matches a best (:meth:`score`;
            successful results first).
        """
        reference = _ReferenceSpectra(self, coarse_a)
        max_col_shift = max_yaw_rad * self.shape[1] / (2 * np.pi)
        found = [self._search(reference, coarse_b, np.asarray(start, dtype=np.float64),
                              max_col_shift=max_col_shift)[0] for start in starts]
        return max(found, key=lambda result: (result.success, result.score))

    def clearly_better(self, found: GlobalMotion, *, current_rotation: np.ndarray, current_score: float) -> bool:
        """Whether ``found`` lies more than ``config.confirm_angle_rad`` from ``current_rotation`` and
        leaves at most ``config.wide_mismatch_ratio`` of its mismatch ``1 - current_score``."""
        c = self.config
        return (_angle(current_rotation.T @ found.rotation) > c.confirm_angle_rad
                and 1.0 - found.score <= c.wide_mismatch_ratio * (1.0 - current_score))

    def _tilted_starts(self, start: np.ndarray) -> np.ndarray:
        """``start`` tilted (on the left, about a's horizontal axes) by the wide search's grid, (K, 3, 3)."""
        c = self.config
        steps = int(_wide_steps(c))
        tilts = np.radians(np.arange(-steps, steps + 1) * c.wide_tilt_step_deg)
        roll, pitch = (grid.ravel() for grid in np.meshgrid(tilts, tilts, indexing="ij"))
        tilted = (roll != 0) | (pitch != 0)
        rpy = np.stack([roll[tilted], pitch[tilted], np.zeros(int(tilted.sum()))], axis=1)
        return matrix_from_rpy(rpy) @ start

    def _search(self, reference: _ReferenceSpectra, coarse_b: np.ndarray, start: np.ndarray, *,
                max_col_shift: float | None = None) -> tuple[GlobalMotion, float]:
        """Yaw search (its shift up to ``max_col_shift`` coarse columns, if given) and sector passes from
        ``start``; the result and the start's own :meth:`score`."""
        c = self.config
        coarse_a = reference.coarse
        rotation = start
        warped_b = self.warped(coarse_b, rotation)
        start_score = self.score(coarse_a, warped_b)
        shift, yaw_ratio = self._yaw_search(reference.whole, warped_b, max_col_shift=max_col_shift)
        if yaw_ratio >= c.min_peak_ratio and np.all(np.abs(shift) < c.settled_shift_px):
            # The start already lines the panoramas up; the tiles measure what is left.
            return GlobalMotion(start, True, "", yaw_ratio, 0, start_score), start_score
        shifts = np.broadcast_to(shift, self.sector_centres.shape)
        rotation = rotation_from_ray_pairs(*self._ray_pairs(self.sector_centres, shifts, rotation))
        used = 0
        warped_b = self.warped(coarse_b, rotation)
        for _ in range(c.iterations):
            fitted, count = self._sector_fit(reference.sectors, warped_b, rotation)
            if fitted is None:
                break
            rotation, used = fitted, count
            warped_b = self.warped(coarse_b, rotation)
        score = self.score(coarse_a, warped_b)
        if used == 0 and yaw_ratio < c.min_peak_ratio:
            # Neither the whole panorama nor enough sectors agree on a motion.
            return GlobalMotion(start, False, f"no clear whole-panorama peak (ratio {yaw_ratio:.2f}) "
                                f"and fewer than {c.min_sectors} clear sectors", yaw_ratio, 0, score), start_score
        return GlobalMotion(rotation, True, "", yaw_ratio, used, score), start_score
