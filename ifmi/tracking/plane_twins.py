"""The tracker's record of planar pairs, and the trajectory re-chained with the sequence's choice of twin.

Each accepted 5-point pair is tested for a plane (:func:`ifmi.backend.plane_twin.planar_pair`);
when the trajectory is asked for, the planar pairs' twins are settled over the
whole sequence (:func:`ifmi.backend.plane_twin.resolve_plane_twins`), the
swapped pairs' relative poses replaced and the frames re-chained. Each planar
pair's record says ``kept``, ``homography`` or ``swapped`` in the ``plane_twin``
column of ``frames.csv`` (:func:`_label`; empty for other pairs); the record's
own estimate (its ``rotation_rad``) stays the pair's 5-point estimate.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ifmi.backend.plane_twin import PlaneTwinOptions, planar_pair, rechained, replaces_estimate, resolve_plane_twins

__all__ = ["PLANE_TWIN", "PlaneTwinChain"]

# frames.csv column: "kept", "homography" or "swapped" on a planar pair, empty elsewhere.
PLANE_TWIN = "plane_twin"


def _label(choice: int, candidates, replaced: bool) -> str:
    """``plane_twin`` of a planar pair: ``swapped`` when the chosen decomposition is the twin of the
    one nearest the 5-point estimate; else ``homography`` when that nearest decomposition replaced
    the 5-point pose, ``kept`` when the pose is the 5-point one, unchanged."""
    if choice != candidates.current:
        return "swapped"
    return "homography" if replaced else "kept"


class PlaneTwinChain:
    """Planar pairs of a tracked sequence (see the module docstring).

    Parameters
    ----------
    options : PlaneTwinOptions, keyword-only
    """

    def __init__(self, *, options: PlaneTwinOptions = PlaneTwinOptions()):
        self.options = options
        self._planar: dict = {}

    def observe(self, frame: int, corr, pose, info, *, threshold_rad: float) -> None:
        """Test frame ``frame``'s accepted pair for a plane.

        ``corr`` holds the pair's rays (``rays_a``, ``rays_b``, ``rays_per_measurement``),
        ``pose`` and ``info`` the back end's estimate (:func:`ifmi.backend.relative_pose.relative_pose_from_rays`);
        only 5-point estimates with a noise level are tested.
        """
        self._planar.pop(frame, None)
        noise = getattr(getattr(info, "selection", None), "noise_sigma_rad", np.nan)
        if not self.options.enabled or info.model != "5pt" or not noise > 0:
            return
        mask = np.asarray(info.inlier_mask, dtype=bool)
        candidates = planar_pair(corr.rays_a[mask], corr.rays_b[mask], pose.rotation, pose.translation_direction,
                                 noise_sigma_rad=noise, threshold_rad=threshold_rad,
                                 rays_per_measurement=corr.rays_per_measurement, options=self.options)
        if candidates is not None:
            self._planar[frame] = candidates

    def apply(self, rotations: np.ndarray, positions: np.ndarray, records: list, references: np.ndarray) -> tuple:
        """``(rotations, positions, records)`` with the sequence's twins (see the module docstring).

        Parameters
        ----------
        rotations : (K, 3, 3) ndarray
            Chained ``R_0k``.
        positions : (K, 3) ndarray
        records : list of FrameRecord
            One per frame.
        references : (K,) int ndarray
            The frame each frame is chained from (a failed frame holds the pose of the one before it).
        """
        if not self._planar:
            return rotations, positions, records
        relative = np.einsum("kji,kjl->kil", rotations[references], rotations)
        choices = resolve_plane_twins(references, relative, self._planar, options=self.options)
        replaced = {k: (self._planar[k].rotations[c], self._planar[k].translations[c]) for k, c in choices.items()
                    if replaces_estimate(self._planar[k], c, options=self.options)}
        if replaced:
            rotations, positions = rechained(rotations, positions, references, replaced)
        labelled = [replace(r, diagnostics={**r.diagnostics, PLANE_TWIN: _label(
                        choices[r.frame], self._planar[r.frame], r.frame in replaced)})
                    if r.frame in choices else r for r in records]
        return rotations, positions, labelled
