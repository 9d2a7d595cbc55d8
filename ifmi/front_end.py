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

A front end may also have ``accept_pose(state, rotation)``: the odometry
then passes it the pose ``R_0k`` ((3, 3)) it settled on for every
successfully estimated frame, before that frame can serve as a reference
(the iFMI front end ties its tracked tiles to it). Failed frames are never
passed.

A front end may also have ``refine_correspondences(state_a, state_b, first,
*, rotation_ab) -> Correspondences or None``: once the back end has solved
a pair from ``first`` (what ``correspondences`` returned), the odometry
passes it the solved ``R_ab`` ((3, 3)). Correspondences it returns are
solved again and replace the first solution when that succeeds (the iFMI
front end registers a weak pair's tiles again at that rotation and averages
the two registrations' matches); None keeps the first solution, and so do
failed correspondences, whose reason goes into the frame's diagnostics.

This module imports nothing else of :mod:`ifmi`, so any front end can import
it without import cycles.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["Correspondences", "FrontEnd"]


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
