"""Camera trajectories: poses ``T_0k`` of a sequence in frame 0's coordinates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Trajectory"]


@dataclass(frozen=True)
class Trajectory:
    """Poses ``T_0k`` of a sequence.

    Attributes
    ----------
    timestamps : (N,) ndarray
        Seconds, or frame indices when real times are unknown.
    positions : (N, 3) ndarray
        Camera-k origin in camera-0 coordinates (up to scale for estimates).
    rotations : (N, 3, 3) ndarray
        ``R_0k``: maps camera-k directions to camera-0 directions.
    """

    timestamps: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.timestamps)
        if self.positions.shape != (n, 3) or self.rotations.shape != (n, 3, 3):
            raise ValueError(
                f"expected positions ({n}, 3) and rotations ({n}, 3, 3), got "
                f"{self.positions.shape} and {self.rotations.shape}"
            )

    def __len__(self) -> int:
        return len(self.timestamps)
