"""Bundle adjustment of camera poses over points seen in several frames.

One pair's rays fix its translation direction only loosely when the step
is short: the parallax of a 1-2 cm step is a few milliradians, about the
noise of one ray, and the pair's solver then lets the rotation take up part
of it. A point seen in three or more frames ties
the pairs together: its depth, fixed by the longer steps, turns a short
step's parallax into a translation instead of a tilt. This module refines
the poses of a window of frames and the depths of the points they share.

Conventions
-----------
* Frame ``k``'s pose is ``R_0k`` (maps camera-k directions into the world,
  i.e. camera 0's coordinates) and its centre ``p_k`` in the world, as in
  :mod:`ifmi.tracking.odometry`: ``X_0 = R_0k @ X_k + p_k``.
* An observation is a unit ray in its camera's coordinates. All
  observations of one track are one scene point.
* A track's point is its first observation's ray (in frame order) at
  inverse depth ``rho`` from that frame's centre:
  ``X_0 = p_a + R_0a @ u_a / rho``; ``rho = 0`` is a point at infinity.
  Starting values are triangulated and never negative; the fit itself is
  not bounded, so a far point's noise may carry it slightly past infinity.
* The residual of another observation ``u_f`` is the predicted ray's
  offset from it in a tangent basis of ``u_f`` (two components, radians
  for small errors). Rotations are updated on the right,
  ``R <- R @ exp([delta]_x)``.
* Translation has no scale of its own: it is fixed by the frames held
  when two of them are apart, and otherwise by holding the mean inverse
  depth of the window's points at its starting value.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ifmi.options import check_finite_fields
from ifmi.geometry.rotations import cross_product_matrix

__all__ = [
    "BundleAdjustmentOptions",
    "TrackObservations",
    "BundleAdjustmentInfo",
    "tracks_from_pair_rays",
    "poses_from_bundle_adjustment",
    "poses_from_sliding_window",
]

# Most Levenberg-Marquardt iterations: the default 15 settle a window; 1000 added 2 s to seven
# 256 px pairs at a window of 4 with tolerance 0, while 10**20 never ended (with tolerance 0 only
# the count stops the iterations).
_MAX_ITERATIONS = 1000


@dataclass(frozen=True)
class BundleAdjustmentOptions:
    """Options of :func:`poses_from_bundle_adjustment`.

    Attributes
    ----------
    window : int
        Frames adjusted together by :func:`poses_from_sliding_window` (a
        fixed-lag smoother); 0 turns the adjustment off, else at least 2.
    match_tolerance_rad : float
        Rays of one frame closer than this (chord length of unit rays,
        about radians) are one observation of one point
        (:func:`tracks_from_pair_rays`). Rays handed on unchanged agree to
        rounding; 1e-4 rad is 1/250 of a pixel of a 256 px panorama.
    robust_scale_rad : float or None
        Scale of the soft-L1 loss on each residual's length (radians); a
        residual this large counts about half as much as under least
        squares. None: the relative-pose RANSAC threshold (set by the
        tracker).
    iterations : int
        Most Levenberg-Marquardt iterations, 1 to 1000.
    initial_damping : float
        Levenberg-Marquardt damping at the start, relative to the diagonal.
    tolerance : float
        Stop when an accepted step lowers the cost by less than this
        fraction of it.
    gauge_weight : float
        Weight (per radian of residual) of the residual that holds the
        window's mean inverse depth at its starting value (the scale gauge),
        used only when the held frames the window sees share one centre.
    """

    window: int = 0
    match_tolerance_rad: float = 1e-4
    robust_scale_rad: float | None = None
    iterations: int = 15
    initial_damping: float = 1e-4
    tolerance: float = 1e-6
    gauge_weight: float = 10.0

    def __post_init__(self) -> None:
        check_finite_fields(self, ("match_tolerance_rad", "robust_scale_rad", "initial_damping", "tolerance",
                                   "gauge_weight"))
        if self.window < 0 or self.window == 1:
            raise ValueError(f"window must be 0 (off) or at least 2 frames, got {self.window}")
        if (self.robust_scale_rad is not None and self.robust_scale_rad <= 0) or self.gauge_weight <= 0 \
                or self.initial_damping <= 0 or self.match_tolerance_rad < 0:
            raise ValueError(f"robust_scale_rad, gauge_weight and initial_damping must be > 0 and "
                             f"match_tolerance_rad >= 0, got {self.robust_scale_rad}, {self.gauge_weight}, "
                             f"{self.initial_damping}, {self.match_tolerance_rad}")
        if not 1 <= self.iterations <= _MAX_ITERATIONS or self.tolerance < 0:
            raise ValueError(f"iterations must be from 1 to {_MAX_ITERATIONS} and tolerance >= 0, got "
                             f"{self.iterations}, {self.tolerance}")

    def shutter_conflict(self, readout: float) -> str | None:
        """Why this window cannot run with a rolling-shutter read-out time ``readout`` (a fraction of
        the frame interval), or None: a rolling-shutter fit moves each pair's rays by its own
        velocities, so a ray handed to two pairs is no longer one ray."""
        if self.window and readout != 0.0:
            return f"a bundle-adjustment window ({self.window} frames) needs a global shutter, got a " \
                   f"read-out time of {readout}"
        return None


@dataclass(frozen=True)
class TrackObservations:
    """Rays of scene points, each seen in one or more frames.

    Attributes
    ----------
    track : (M,) int ndarray
        Point of each observation (0 .. T-1).
    frame : (M,) int ndarray
        Frame of each observation; at most one per (track, frame).
    rays : (M, 3) float ndarray
        Unit rays in each frame's camera coordinates.
    """

    track: np.ndarray
    frame: np.ndarray
    rays: np.ndarray

    def __post_init__(self) -> None:
        m = len(self.track)
        if self.frame.shape != (m,) or self.rays.shape != (m, 3):
            raise ValueError(f"expected track (M,), frame (M,) and rays (M, 3), got {self.track.shape}, "
                             f"{self.frame.shape} and {self.rays.shape}")


@dataclass(frozen=True)
class BundleAdjustmentInfo:
    """Diagnostics of :func:`poses_from_bundle_adjustment`.

    Attributes
    ----------
    iterations : int
        Accepted Levenberg-Marquardt steps.
    initial_cost, final_cost : float
        Robust cost (half the sum of the loss over residuals, radians squared).
    tracks, observations : int
        Points with at least two observations and a free frame, and their
        observations besides each point's first.
    noise_rad : float
        Ray noise the final residuals imply: their median length over the
        median of a unit two-dimensional Gaussian's (sqrt(2 ln 2)); NaN without residuals.
    free_frames : int
        Frames adjusted.
    """

    iterations: int
    initial_cost: float
    final_cost: float
    tracks: int
    observations: int
    noise_rad: float
    free_frames: int


def tracks_from_pair_rays(pairs, *, tolerance_rad: float) -> TrackObservations:
    """Join the correspondences of frame pairs into tracks.

    A ray of frame ``k`` in one pair and a ray of frame ``k`` in another
    pair that lie within ``tolerance_rad`` of each other are taken to be
    one observation of one point: front ends that detect or place their
    features once per frame (keypoints; iFMI's tracked tiles) hand the same
    ray to every pair the frame is in.

    Parameters
    ----------
    pairs : iterable of (int, int, (N, 3) ndarray, (N, 3) ndarray)
        Frame a, frame b and the corresponding unit rays of each pair
        (row i of both is one correspondence).
    tolerance_rad : float, keyword-only
        Largest angle between two rays of one frame taken as the same.

    Returns
    -------
    TrackObservations
        One observation per (track, frame); a frame's rays merged into one
        observation keep the first pair's ray.
    """
    frames, rays, links, start = [], [], [], 0
    for a, b, rays_a, rays_b in pairs:
        n = len(rays_a)
        frames += [np.full(n, a), np.full(n, b)]
        rays += [np.asarray(rays_a, dtype=np.float64), np.asarray(rays_b, dtype=np.float64)]
        links.append(np.stack([start + np.arange(n), start + n + np.arange(n)], axis=1))
        start += 2 * n
    if not rays:
        return TrackObservations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)))
    frames, rays = np.concatenate(frames), np.concatenate(rays)
    by_frame = np.argsort(frames, kind="stable")
    bounds = np.flatnonzero(np.diff(frames[by_frame])) + 1
    links = [np.concatenate(links)] + [_same_rays(rays, index, tolerance_rad)
                                       for index in np.split(by_frame, bounds)]
    label = _components(len(rays), np.concatenate(links))
    keep = np.unique(np.stack([label, frames], axis=1), axis=0, return_index=True)[1]
    keep.sort()
    _, track = np.unique(label[keep], return_inverse=True)
    return TrackObservations(track.astype(int), frames[keep].astype(int), rays[keep])


def _same_rays(rays: np.ndarray, index: np.ndarray, tolerance_rad: float) -> np.ndarray:
    """(L, 2) index pairs of one frame's rays within ``tolerance_rad`` of each other (chord length)."""
    pairs = cKDTree(rays[index]).query_pairs(tolerance_rad, output_type="ndarray")
    return index[pairs].reshape(-1, 2)


def _components(count: int, edges: np.ndarray) -> np.ndarray:
    """Connected-component label of each of ``count`` nodes joined by ``edges`` (E, 2)."""
    graph = csr_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(count, count))
    return connected_components(graph, directed=False)[1]


def _tangent_bases(rays: np.ndarray) -> np.ndarray:
    """(M, 2, 3) orthonormal rows perpendicular to each unit ray (M, 3)."""
    helper = np.where(np.abs(rays[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    first = np.cross(rays, helper)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    return np.stack([first, np.cross(rays, first)], axis=1)


@dataclass(frozen=True)
class _Problem:
    """A window's observations, indexed for the solver (see :func:`_problem`)."""

    anchor_frame: np.ndarray  # (K,) frame of each residual's track anchor
    frame: np.ndarray  # (K,) frame of each residual's observation
    track: np.ndarray  # (K,) track (0 .. T-1) of each residual
    anchor_ray: np.ndarray  # (K, 3)
    bases: np.ndarray  # (K, 2, 3) tangent bases of the observed rays
    rays: np.ndarray  # (K, 3) observed rays
    free: np.ndarray  # (F,) free frames, in parameter order
    tracks: int


def _problem(observations: TrackObservations, fixed: np.ndarray) -> _Problem:
    """Keep tracks seen at least twice, at least once in a free frame; one residual per non-anchor ray."""
    track, frame, rays = observations.track, observations.frame, observations.rays
    seen = np.bincount(track, minlength=track.max(initial=-1) + 1)
    free_seen = np.bincount(track[~fixed[frame]], minlength=len(seen))
    keep = (seen[track] >= 2) & (free_seen[track] >= 1)
    track, frame, rays = track[keep], frame[keep], rays[keep]
    if not len(track):
        empty = np.zeros(0, int)
        return _Problem(empty, empty, empty, np.zeros((0, 3)), np.zeros((0, 2, 3)), np.zeros((0, 3)), empty, 0)
    _, track = np.unique(track, return_inverse=True)
    order = np.lexsort((frame, track))
    track, frame, rays = track[order], frame[order], rays[order]
    first = np.r_[True, track[1:] != track[:-1]]
    anchor = np.flatnonzero(first)[np.cumsum(first) - 1]
    rest = ~first
    return _Problem(anchor_frame=frame[anchor][rest], frame=frame[rest], track=track[rest],
                    anchor_ray=rays[anchor][rest], bases=_tangent_bases(rays[rest]), rays=rays[rest],
                    free=np.unique(frame[~fixed[frame]]), tracks=int(first.sum()))


def _scale_is_free(problem: _Problem, fixed: np.ndarray, positions: np.ndarray) -> bool:
    """Whether the held frames the window sees share one centre (then nothing fixes the scale)."""
    frames = np.union1d(problem.anchor_frame, problem.frame)
    held = positions[frames[fixed[frames]]]
    extent = np.ptp(positions[frames], axis=0).max()
    return len(held) < 2 or np.ptp(held, axis=0).max() <= 1e-9 * max(extent, np.finfo(float).tiny)


def _triangulated_inverse_depths(problem: _Problem, rotations: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(T,) inverse depths fitting each track's rays at the given poses (least squares of the
    anchor ray's offset from the other rays); the median of the determined ones where the
    baseline is too short, 1 where none is, never negative."""
    baseline = positions[problem.anchor_frame] - positions[problem.frame]
    seen = np.einsum("kij,kj->ki", rotations[problem.frame], problem.rays)
    anchor = np.einsum("kij,kj->ki", rotations[problem.anchor_frame], problem.anchor_ray)
    dc, mc = np.cross(baseline, seen), np.cross(anchor, seen)
    numerator = np.bincount(problem.track, -np.einsum("ki,ki->k", dc, mc), problem.tracks)
    denominator = np.bincount(problem.track, np.einsum("ki,ki->k", dc, dc), problem.tracks)
    determined = denominator > 1e-12 * max(denominator.max(initial=0.0), 1e-300)
    rho = np.where(determined, numerator / np.where(determined, denominator, 1.0), np.nan)
    fallback = float(np.nanmedian(np.clip(rho, 0.0, None))) if determined.any() else 1.0
    rho = np.where(np.isfinite(rho), rho, fallback if fallback > 0 else 1.0)
    return np.clip(rho, 0.0, None)


def _residuals(problem: _Problem, rotations, positions, rho, *, jacobian: bool):
    """(K, 2) residuals and, with ``jacobian``, their derivatives: (K, 2, 12) with respect to
    (anchor rotation, anchor centre, frame rotation, frame centre) and (K, 2) to the inverse depth."""
    r_a, r_f = rotations[problem.anchor_frame], rotations[problem.frame]
    baseline = positions[problem.anchor_frame] - positions[problem.frame]
    inverse_depth = rho[problem.track][:, None]
    anchor_world = np.einsum("kij,kj->ki", r_a, problem.anchor_ray)
    w = np.einsum("kji,kj->ki", r_f, inverse_depth * baseline + anchor_world)
    length = np.linalg.norm(w, axis=1, keepdims=True)
    n = w / length
    res = np.einsum("kij,kj->ki", problem.bases, n)
    if not jacobian:
        return res, None, None
    projector = (problem.bases - np.einsum("ki,kj->kij", np.einsum("kij,kj->ki", problem.bases, n), n)) \
        / length[:, None]
    p_rt = projector @ np.swapaxes(r_f, 1, 2)  # (K, 2, 3): d res / d (world vector)
    blocks = np.concatenate([-p_rt @ r_a @ cross_product_matrix(problem.anchor_ray),
                             p_rt * inverse_depth[:, :, None], projector @ cross_product_matrix(w),
                             -p_rt * inverse_depth[:, :, None]], axis=2)
    return res, blocks, np.einsum("kij,kj->ki", p_rt, baseline)


def _cost(res: np.ndarray, scale: float) -> float:
    """Soft-L1 cost of (K, 2) residuals on their lengths, ``scale`` the loss's scale (radians)."""
    squared = np.einsum("ki,ki->k", res, res) / scale ** 2
    return float(scale ** 2 * np.sum(np.sqrt(1.0 + squared) - 1.0))


@dataclass(frozen=True)
class _Normal:
    """Robustly weighted normal equations, split into frames (c, 6 per free frame) and inverse depths (r).

    ``J^T W J = [[cc, cr], [cr^T, diag(rr) + gauge^2 1 1^T]]``, ``J^T W res = [gc; gr]``.
    """

    cc: np.ndarray  # (6F, 6F)
    cr: np.ndarray  # (6F, T)
    rr: np.ndarray  # (T,)
    gc: np.ndarray  # (6F,)
    gr: np.ndarray  # (T,)


def _normal_equations(problem: _Problem, blocks, d_rho, res, *, scale: float, column: np.ndarray) -> _Normal:
    """The soft-L1 (iteratively reweighted) normal equations of the residuals."""
    count, size = len(res), 6 * len(problem.free)
    weights = 1.0 / np.sqrt(1.0 + np.einsum("ki,ki->k", res, res) / scale ** 2)
    jac = np.zeros((count, 2, size))
    rows = np.arange(count)
    for side, frames in ((0, problem.anchor_frame), (1, problem.frame)):
        index = column[frames]
        ok = index >= 0
        for j in range(6):
            jac[rows[ok], :, index[ok] + j] += blocks[ok, :, 6 * side + j]
    weighted = jac * weights[:, None, None]
    flat, flat_weighted = jac.reshape(2 * count, size), weighted.reshape(2 * count, size)
    cr = np.zeros((problem.tracks, size))
    np.add.at(cr, problem.track, np.einsum("kij,ki->kj", weighted, d_rho))
    return _Normal(cc=flat_weighted.T @ flat, cr=cr.T,
                   rr=np.bincount(problem.track, weights * np.einsum("ki,ki->k", d_rho, d_rho), problem.tracks),
                   gc=flat_weighted.T @ res.reshape(-1),
                   gr=np.bincount(problem.track, weights * np.einsum("ki,ki->k", d_rho, res), problem.tracks))


def _damped_step(normal: _Normal, gauge: float, gauge_gradient: float, damping: float) -> tuple:
    """Levenberg-Marquardt step (frames (6F,), inverse depths (T,)) by the Schur complement of the
    inverse depths, whose block is diagonal plus the gauge's rank one (Sherman-Morrison)."""
    d_cc = np.diag(normal.cc)
    cc = normal.cc + np.diag(damping * np.maximum(d_cc, 1e-12))
    rr_diagonal = normal.rr + gauge ** 2
    rr = normal.rr + damping * np.maximum(rr_diagonal, 1e-12)
    gr = normal.gr + gauge * gauge_gradient

    def solve_rr(x):  # (diag(rr) + gauge^2 1 1^T)^-1 x, x (T,) or (T, k)
        y = x / (rr[:, None] if x.ndim == 2 else rr)
        ones = 1.0 / rr
        return y - gauge ** 2 * np.outer(ones, y.sum(axis=0)).reshape(y.shape) / (1.0 + gauge ** 2 * ones.sum())

    schur = cc - normal.cr @ solve_rr(normal.cr.T)
    frames = np.linalg.solve(schur, -normal.gc + normal.cr @ solve_rr(gr))
    return frames, solve_rr(-gr - normal.cr.T @ frames)


def poses_from_bundle_adjustment(rotations: np.ndarray, positions: np.ndarray, observations: TrackObservations,
                                 *, fixed: np.ndarray, options: BundleAdjustmentOptions = BundleAdjustmentOptions()):
    """Refine the free frames' poses to the rays of the points they share.

    Parameters
    ----------
    rotations : (N, 3, 3) ndarray
        Starting ``R_0k`` of every frame the observations name.
    positions : (N, 3) ndarray
        Starting centres ``p_k`` (any scale; zeros are allowed).
    observations : TrackObservations
        Frames index the first axis of ``rotations``.
    fixed : (N,) bool ndarray, keyword-only
        Frames held at their starting pose. Hold at least one.
    options : BundleAdjustmentOptions, keyword-only

    Returns
    -------
    rotations : (N, 3, 3) ndarray
    positions : (N, 3) ndarray
        Free frames refined, the others as given.
    info : BundleAdjustmentInfo
    """
    rotations, positions = np.array(rotations, dtype=np.float64), np.array(positions, dtype=np.float64)
    fixed = np.asarray(fixed, dtype=bool)
    if rotations.shape[1:] != (3, 3) or positions.shape != (len(rotations), 3) or fixed.shape != (len(rotations),):
        raise ValueError(f"expected rotations (N, 3, 3), positions (N, 3) and fixed (N,), got {rotations.shape}, "
                         f"{positions.shape} and {fixed.shape}")
    if not fixed.any():
        raise ValueError("expected at least one fixed frame (the gauge), got none")
    if options.robust_scale_rad is None:
        raise ValueError("expected options.robust_scale_rad set, got None")
    problem = _problem(observations, fixed)
    if problem.tracks == 0:  # then no free frame sees a shared point either
        return rotations, positions, BundleAdjustmentInfo(0, 0.0, 0.0, 0, 0, float("nan"), 0)
    rho = _triangulated_inverse_depths(problem, rotations, positions)
    gauge = float(rho.mean())
    column = np.full(len(rotations), -1)
    column[problem.free] = 6 * np.arange(len(problem.free))
    scale, damping = options.robust_scale_rad, options.initial_damping
    gauge_weight = options.gauge_weight if _scale_is_free(problem, fixed, positions) else 0.0
    weight = gauge_weight / problem.tracks

    def total_cost(res, rho_now):
        return _cost(res, scale) + 0.5 * (gauge_weight * (rho_now.mean() - gauge)) ** 2

    res, blocks, d_rho = _residuals(problem, rotations, positions, rho, jacobian=True)
    cost = initial = total_cost(res, rho)
    accepted = 0
    for _ in range(options.iterations):
        normal = _normal_equations(problem, blocks, d_rho, res, scale=scale, column=column)
        while True:
            step_frames, step_rho = _damped_step(normal, weight, gauge_weight * (rho.mean() - gauge), damping)
            cams = step_frames.reshape(-1, 6)
            trial_r, trial_p = rotations.copy(), positions.copy()
            trial_r[problem.free] = trial_r[problem.free] @ Rotation.from_rotvec(cams[:, :3]).as_matrix()
            trial_p[problem.free] += cams[:, 3:]
            trial_rho = rho + step_rho
            trial_res, *_ = _residuals(problem, trial_r, trial_p, trial_rho, jacobian=False)
            trial_cost = total_cost(trial_res, trial_rho)
            if trial_cost < cost or damping > 1e8:
                break
            damping *= 10.0
        if trial_cost >= cost:
            break
        improvement = cost - trial_cost
        rotations, positions, rho, cost = trial_r, trial_p, trial_rho, trial_cost
        accepted += 1
        damping = max(damping / 10.0, 1e-12)
        res, blocks, d_rho = _residuals(problem, rotations, positions, rho, jacobian=True)
        if improvement < options.tolerance * cost:
            break
    noise = float(np.median(np.linalg.norm(res, axis=1)) / np.sqrt(2.0 * np.log(2.0)))
    return rotations, positions, BundleAdjustmentInfo(accepted, initial, cost, problem.tracks, len(problem.frame),
                                                      noise, len(problem.free))


def poses_from_sliding_window(rotations: np.ndarray, positions: np.ndarray, references: np.ndarray,
                              observations: TrackObservations, *,
                              options: BundleAdjustmentOptions = BundleAdjustmentOptions()):
    """Refine a sequence's chained poses frame by frame over the last ``options.window`` frames.

    A fixed-lag smoother. For each frame k in order, frame k is first
    chained onto its reference's refined pose with the relative pose the
    start values give (``R_rk = R_0r^T R_0k``, ``t_rk = R_0r^T (p_k - p_r)``,
    the step rescaled by the refined-over-start length of the previous
    refined step); then frames k-window+1 .. k are adjusted with the
    observations of frames up to k, earlier frames held. Frame 0 anchors
    the world. Each frame therefore uses the ``window - 1`` frames after
    it and never later ones.

    Parameters
    ----------
    rotations : (N, 3, 3) ndarray
        ``R_0k`` as chained from the frame pairs.
    positions : (N, 3) ndarray
        Centres as chained (any scale).
    references : (N,) int ndarray
        The frame each frame was chained from (``references[0] == 0``).
    observations : TrackObservations
    options : BundleAdjustmentOptions, keyword-only
        ``window`` at least 2 and ``robust_scale_rad`` set.

    Returns
    -------
    rotations : (N, 3, 3) ndarray
    positions : (N, 3) ndarray
    infos : list of BundleAdjustmentInfo
        One per adjusted window.
    """
    if options.window < 2 or options.robust_scale_rad is None:
        raise ValueError(f"expected window >= 2 and robust_scale_rad set, got {options.window} and "
                         f"{options.robust_scale_rad}")
    start_r, start_p = np.asarray(rotations, dtype=np.float64), np.asarray(positions, dtype=np.float64)
    references = np.asarray(references, dtype=int)
    if start_r.shape[1:] != (3, 3) or start_p.shape != (len(start_r), 3) or references.shape != (len(start_r),) \
            or np.any(references[1:] >= np.arange(1, len(references))) or np.any(references < 0):
        raise ValueError(f"expected rotations (N, 3, 3), positions (N, 3) and references (N,) each before its "
                         f"frame, got {start_r.shape}, {start_p.shape} and {references.shape}")
    window_of = _WindowIndex(observations)
    rotations, positions, infos, step_scale = start_r.copy(), start_p.copy(), [], 1.0
    for end in range(1, len(rotations)):
        r = references[end]
        rotations[end] = rotations[r] @ start_r[r].T @ start_r[end]
        positions[end] = positions[r] + step_scale * rotations[r] @ start_r[r].T @ (start_p[end] - start_p[r])
        first = max(end - options.window + 1, 1)
        fixed = np.ones(len(rotations), dtype=bool)
        fixed[first:end + 1] = False
        part = window_of(first, end)
        rotations, positions, info = poses_from_bundle_adjustment(rotations, positions, part, fixed=fixed,
                                                                  options=options)
        infos.append(info)
        start_step = np.linalg.norm(start_p[end] - start_p[r])
        if info.free_frames and start_step > 0:
            step_scale = float(np.linalg.norm(positions[end] - positions[r]) / start_step) or step_scale
    return rotations, positions, infos


class _WindowIndex:
    """The observations a window needs, found without scanning the whole sequence's.

    Called with ``(first, last)`` frames, it returns the observations up to
    ``last`` of the tracks seen in ``first .. last`` (the tracks that can
    reach a free frame), in their original order.
    """

    def __init__(self, observations: TrackObservations):
        self.observations = observations
        self.by_frame = np.argsort(observations.frame, kind="stable")
        self.sorted_frames = observations.frame[self.by_frame]
        self.by_track = np.argsort(observations.track, kind="stable")
        self.track_starts = np.searchsorted(observations.track[self.by_track],
                                            np.arange(observations.track.max(initial=-1) + 2))

    def __call__(self, first: int, last: int) -> TrackObservations:
        seen = self.by_frame[np.searchsorted(self.sorted_frames, first):
                             np.searchsorted(self.sorted_frames, last, side="right")]
        tracks = np.unique(self.observations.track[seen])
        starts, lengths = self.track_starts[tracks], self.track_starts[tracks + 1] - self.track_starts[tracks]
        within = np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
        index = np.sort(self.by_track[np.repeat(starts, lengths) + within])
        index = index[self.observations.frame[index] <= last]
        obs = self.observations
        return TrackObservations(obs.track[index], obs.frame[index], obs.rays[index])
