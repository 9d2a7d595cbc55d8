"""The front-end contract: what every estimation method (built in or third party) provides.

A *front end* turns images into ray correspondences; the relative-pose back
end (:mod:`ifmi.backend.relative_pose`) and the trajectory chaining
(:mod:`ifmi.tracking.odometry`) are shared by every method, so comparisons isolate the
front end. A method is a factory ``factory(model, config) -> FrontEnd`` that
receives the camera model and the whole :class:`ifmi.pipeline.EstimateConfig`
(see :mod:`ifmi.tracking.methods` for how methods are named and found). A front end
has two methods:

``prepare(image) -> state``
    per-frame work that does not depend on the other frame (panorama, tile
    spectra, keypoints); ``image`` is ``(H, W)`` or ``(H, W, 3)`` uint8. The
    odometry keeps the state of a keyframe, so it is prepared once;
``correspondences(state_a, state_b) -> Correspondences``
    matching of a reference frame ``a`` against frame ``b``. A front end
    whose ``uses_prior_rotation`` attribute is true is called with the
    keyword ``prior_rotation`` (a predicted ``R_ab``, (3, 3)) as well.

A front end whose ``prepares_in_background`` attribute is true has the next
frame read and prepared in a background thread while the current pair is
matched and solved (both cores at work where the preparation releases the
GIL, as OpenCV's resampling does); its ``prepare`` must then neither read
nor change anything that matching changes.

A front end may also have ``accept_pose(state, rotation)``: the odometry
then passes it the pose ``R_0k`` ((3, 3)) it settled on for every
successfully estimated frame, before that frame can serve as a reference
(the iFMI front end ties its tracked tiles to it). Failed frames are never
passed.

A front end may also have ``refine_correspondences(state_a, state_b, first,
*, rotation_ab) -> Correspondences or None``: once the back end has solved
a pair from ``first`` (what ``correspondences`` returned), the odometry
passes it the solved ``R_ab`` ((3, 3)). Correspondences it returns are
solved again and replace the first solution when that succeeds; None keeps
the first solution, and so do failed correspondences, whose reason goes
into the frame's diagnostics (column :data:`REFINE_FAILURE`).

The odometry runs every pair through ``solve_pair(state_a, state_b, *,
prior_rotation, solve) -> SolvedPair`` (``solve(correspondences) -> (pose,
info)`` is its back end). :class:`FrontEndBase` gives every optional part a
default: no prior rotation, an ``accept_pose`` and a
``refine_correspondences`` that do nothing, and :func:`default_solve_pair`
(match, solve, refine, solve again). A front end that derives from it may
replace ``solve_pair`` with a pipeline of its own (the iFMI front end's:
:mod:`ifmi.spectral.pair_pipeline`); any other object with the methods above is
given the defaults for what it lacks by :func:`with_contract_defaults`, once.

This module imports nothing else of :mod:`ifmi`, so any front end can import
it without import cycles.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

__all__ = ["Correspondences", "FrontEnd", "FrontEndBase", "SolvedPair", "REFINE_FAILURE", "DEFAULT_STAGE_COLUMNS",
           "default_solve_pair", "with_contract_defaults"]

# Diagnostics column of a pair whose refined correspondences failed (their reason).
REFINE_FAILURE = "refine_failure"
# Diagnostics columns of default_solve_pair: the wall time (milliseconds) of matching, of the first
# solve, and of refining and solving again.
DEFAULT_STAGE_COLUMNS = ("t_match_ms", "t_solve_ms", "t_refine_ms")


@dataclass(frozen=True)
class Correspondences:
    """Matched points of a frame pair.

    Attributes
    ----------
    pixels_a, pixels_b : (N, 2) ndarray
        Image ``(row, col)`` of each match in frame a and frame b (pixels,
        0-based, pixel centres at integers).
    rays_a, rays_b : (N, 3) ndarray
        Unit rays of those pixels in the camera frame.
    diagnostics : dict
        JSON-serialisable scalars (counts, quality figures).
    success : bool
    reason : str
        Empty on success, else why matching failed.
    rays_per_measurement : int
        Consecutive matches that come from one measurement and share its
        error (flow points of one tile); 1 for keypoint matches.
    """

    pixels_a: np.ndarray
    pixels_b: np.ndarray
    rays_a: np.ndarray
    rays_b: np.ndarray
    diagnostics: dict = field(default_factory=dict)
    success: bool = True
    reason: str = ""
    rays_per_measurement: int = 1

    @staticmethod
    def failed(reason: str, diagnostics: dict | None = None) -> "Correspondences":
        """Empty correspondences flagged as failed with ``reason``.

        Parameters
        ----------
        reason : str
            Why matching failed (one line, shown in ``frames.csv``).
        diagnostics : dict, optional
            JSON-serialisable scalars kept with the failure.

        Returns
        -------
        Correspondences
            ``(0, 2)`` pixels and ``(0, 3)`` rays, ``success`` false.
        """
        empty2, empty3 = np.zeros((0, 2)), np.zeros((0, 3))
        return Correspondences(empty2, empty2, empty3, empty3, dict(diagnostics or {}),
                               success=False, reason=reason)


@runtime_checkable
class FrontEnd(Protocol):
    """Per-frame preparation and pairwise matching (see the module docstring)."""

    def prepare(self, image: np.ndarray) -> Any:
        """Per-frame state of ``image`` ((H, W) or (H, W, 3) uint8)."""

    def correspondences(self, state_a: Any, state_b: Any) -> Correspondences:
        """Matches of reference frame a against frame b."""


@dataclass(frozen=True)
class SolvedPair:
    """A pair after matching and solving.

    Attributes
    ----------
    correspondences : Correspondences
        The matches the pose was solved from (or the failed ones).
    pose : object or None
        The back end's pose (``rotation`` ``R_ab``, ``translation_direction``); None when matching failed.
    info : object or None
        The back end's fit report (``success``, ``reason``, ``n_inliers``, ...); None when matching failed.
    """

    correspondences: Correspondences
    pose: Any = None
    info: Any = None


def default_solve_pair(front_end, state_a: Any, state_b: Any, *, prior_rotation: np.ndarray | None,
                       solve: Callable) -> SolvedPair:
    """Match a pair (with the prediction when the front end uses one), solve it, and solve again what
    ``refine_correspondences`` returns for the solution (kept when that succeeds). The wall time of
    each step goes into the diagnostics (:data:`DEFAULT_STAGE_COLUMNS`)."""
    started = time.perf_counter()
    times = dict.fromkeys(DEFAULT_STAGE_COLUMNS, 0.0)

    def lap(column: str) -> None:
        nonlocal started
        now = time.perf_counter()
        times[column], started = 1e3 * (now - started), now

    def timed(corr: Correspondences) -> Correspondences:
        return replace(corr, diagnostics={**corr.diagnostics, **times})

    if front_end.uses_prior_rotation:
        corr = front_end.correspondences(state_a, state_b, prior_rotation=prior_rotation)
    else:
        corr = front_end.correspondences(state_a, state_b)
    lap("t_match_ms")
    if not corr.success:
        return SolvedPair(timed(corr))
    pose, info = solve(corr)
    lap("t_solve_ms")
    if info.success:
        refined = front_end.refine_correspondences(state_a, state_b, corr, rotation_ab=pose.rotation)
        if refined is not None and not refined.success:
            corr = replace(corr, diagnostics={**corr.diagnostics, REFINE_FAILURE: refined.reason})
        elif refined is not None:
            pose_refined, info_refined = solve(refined)
            if info_refined.success:
                corr, pose, info = refined, pose_refined, info_refined
        lap("t_refine_ms")
    return SolvedPair(timed(corr), pose, info)


class FrontEndBase:
    """Defaults of the optional parts of the contract (see the module docstring); subclasses provide
    ``prepare`` and ``correspondences``."""

    uses_prior_rotation: bool = False
    prepares_in_background: bool = False

    def accept_pose(self, state: Any, rotation: np.ndarray) -> None:
        """Told the settled pose ``R_0k`` of a successfully estimated frame; nothing by default."""

    def refine_correspondences(self, state_a: Any, state_b: Any, first: Correspondences, *,
                               rotation_ab: np.ndarray) -> Correspondences | None:
        """Matches to solve again at the solved ``R_ab``; None (keep the first solution) by default."""
        return None

    def solve_pair(self, state_a: Any, state_b: Any, *, prior_rotation: np.ndarray | None,
                   solve: Callable) -> SolvedPair:
        """The pair matched and solved: :func:`default_solve_pair`."""
        return default_solve_pair(self, state_a, state_b, prior_rotation=prior_rotation, solve=solve)


class _WithDefaults(FrontEndBase):
    """A front end with the contract's optional parts it lacks taken from :class:`FrontEndBase`."""

    def __init__(self, front_end) -> None:
        self.inner = front_end
        self.prepare = front_end.prepare
        self.correspondences = front_end.correspondences
        self.uses_prior_rotation = bool(getattr(front_end, "uses_prior_rotation", False))
        self.prepares_in_background = bool(getattr(front_end, "prepares_in_background", False))
        for name in ("accept_pose", "refine_correspondences"):
            if callable(getattr(front_end, name, None)):
                setattr(self, name, getattr(front_end, name))


def with_contract_defaults(front_end) -> FrontEndBase:
    """``front_end`` itself when it derives from :class:`FrontEndBase`, else a wrapper with the
    documented optional parts it has and the defaults of the others."""
    return front_end if isinstance(front_end, FrontEndBase) else _WithDefaults(front_end)
