"""Frames of a sequence as the estimator receives them: an image, or a stand-in for a bad one."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["MissingFrame"]


@dataclass(frozen=True)
class MissingFrame:
    """Stands in a sequence for an image that could not be used.

    The frame is flagged as failed with ``reason`` and keeps the previous
    pose; the sequence goes on. Only the first frame must be usable, since it
    defines the reference.

    Attributes
    ----------
    source : str
        Where the image came from (a file path), for messages.
    reason : str
        Why it could not be used, one line; it names ``source``.
    """

    source: str
    reason: str
