"""TUM trajectory text files: ``timestamp tx ty tz qx qy qz qw`` per line.

Line k is the pose of camera k in camera 0's frame (``T_0k`` maps camera-k
coordinates to camera-0 coordinates); ``#`` starts a comment line.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from ifmi.errors import InputError, InputWarning
from ifmi.geometry.rotations import matrix_from_quat_xyzw, quat_xyzw_from_matrix
from ifmi.geometry.trajectory import Trajectory
from ifmi.io.atomic import atomic_write_text
from ifmi.io.text_file import number_from_text, read_text_file

__all__ = ["Trajectory", "read_tum", "write_tum", "format_tum", "QUATERNION_NORM_TOLERANCE"]

#: Largest accepted ``| |q| - 1 |`` of a line's quaternion. Rounding to four
#: decimals moves the norm by under 4e-4; a norm off by more than 1 % is not
#: rounding but columns in another order (positions read as a quaternion).
QUATERNION_NORM_TOLERANCE = 1e-2


def read_tum(path: str | os.PathLike) -> Trajectory:
    """Read a TUM trajectory file.

    Raises
    ------
    InputError
        Missing file, a line without 8 numbers, a quaternion that is not of
        unit norm (within :data:`QUATERNION_NORM_TOLERANCE`), or no poses.

    Warns
    -----
    InputWarning
        The first pose is the identity written in ``qw qx qy qz`` order
        (``0 0 0 1 0 0 0`` after the timestamp reads as a half turn about x
        at the origin): the file's quaternions are likely in that order.
    """
    path = Path(path)
    # A byte-order mark (Windows editors write one) is skipped, not part of the first timestamp.
    lines = read_text_file(path, what="trajectory file", encoding="utf-8-sig").splitlines()
    rows = []
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        tokens = text.replace(",", " ").split()
        if len(tokens) != 8:
            raise InputError(path, f"line {number}: expected 8 values (t tx ty tz qx qy qz qw), got {len(tokens)}")
        try:
            values = [number_from_text(tok) for tok in tokens]
        except ValueError:
            raise InputError(path, f"line {number}: non-numeric value") from None
        if not np.all(np.isfinite(values)):
            raise InputError(path, f"line {number}: non-finite value")
        norm = float(np.linalg.norm(values[4:]))
        if norm < 1e-9:
            raise InputError(path, f"line {number}: zero quaternion")
        if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
            raise InputError(path, f"line {number}: quaternion (qx qy qz qw) of norm {norm:.4g}, "
                                   f"expected 1 within {QUATERNION_NORM_TOLERANCE:g} "
                                   "(columns: t tx ty tz qx qy qz qw)")
        rows.append(values)
        if len(rows) == 1:
            _warn_if_scalar_first_identity(path, number, values)
    if not rows:
        raise InputError(path, "no poses in trajectory file")
    data = np.asarray(rows)
    return Trajectory(timestamps=data[:, 0], positions=data[:, 1:4],
                      rotations=matrix_from_quat_xyzw(data[:, 4:8]))


def _warn_if_scalar_first_identity(path: Path, number: int, values: list) -> None:
    """Warn when the first pose is ``0 0 0  1 0 0 0``: the identity in w x y z order, a half turn
    about x in TUM's x y z w. Trajectories start at the identity (frame 0 is camera 0)."""
    position, quaternion = np.asarray(values[1:4]), np.asarray(values[4:8]) / np.linalg.norm(values[4:8])
    if np.allclose(position, 0.0, atol=1e-9) and abs(quaternion[0]) > 1.0 - 1e-9:
        warnings.warn(f"{path}: line {number}: the first pose reads as a half turn about x at the origin "
                      "(qx = 1); if it is meant as the identity the quaternions are in w x y z order, "
                      "but TUM files hold qx qy qz qw", InputWarning, stacklevel=3)


def format_tum(trajectory: Trajectory, *, header: str = "") -> str:
    """TUM text of ``trajectory``; ``header`` lines are written as ``#`` comments."""
    q = quat_xyzw_from_matrix(trajectory.rotations)
    out = [f"# {ln}" for ln in header.splitlines()]
    out.append("# timestamp tx ty tz qx qy qz qw")
    for t, p, qq in zip(trajectory.timestamps, trajectory.positions, q):
        out.append(" ".join([f"{t:.6f}"] + [f"{v:.9f}" for v in p] + [f"{v:.12f}" for v in qq]))
    return "\n".join(out) + "\n"


def write_tum(path: str | os.PathLike, trajectory: Trajectory, *, header: str = "") -> None:
    """Write ``trajectory`` atomically as a TUM file."""
    atomic_write_text(path, format_tum(trajectory, header=header))
