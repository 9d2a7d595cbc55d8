"""Shared by the tests: the rotation error of a pair's kept tiles, registered at a given prediction."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ifmi.backend.relative_pose import rotation_from_rays
from ifmi.spectral.ifmi_front_end import IfmiFrontEnd
from ifmi.spectral.panorama import rays_from_panorama_pixels


def kept_tiles_rotation_error(model, config, frames, rotation) -> float:
    """Angle (rad) between ``rotation`` and the rotation fitted to the kept tiles' centres.

    Frame 1 is registered against frame 0 with ``rotation`` (``R_01``) as
    the prediction; with the exact rotation, what is left is the
    registration's own error.
    """
    fe = IfmiFrontEnd(model, config)
    a, b = fe.prepare(frames[0]), fe.prepare(frames[1])
    match = fe.tiles_at(a, b, rotation)
    fe.keep_tracking(b, match)
    offsets_a, _, placed, _ = match.offsets_a, match.linear_a, match.placed, match.n_new
    ok = placed.valid
    fitted = rotation_from_rays(rays_from_panorama_pixels(fe.mapping, offsets_a[ok]),
                                rays_from_panorama_pixels(fe.mapping, placed.offsets[ok]))
    return float(np.linalg.norm(Rotation.from_matrix(rotation.T @ fitted).as_rotvec()))
