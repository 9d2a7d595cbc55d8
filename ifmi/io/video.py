"""Video files as frame sequences: frames decoded in order by OpenCV, timestamps from the container.

A phone filming through a clip-on omni lens gives a video, not an image
folder. :class:`VideoFrames` yields its frames one by one (8-bit gray, or
RGB) as OpenCV's ``VideoCapture`` decodes them, and records each frame's
presentation time (``CAP_PROP_POS_MSEC``) in seconds. Problems raise
:class:`~ifmi.errors.InputError` naming the file.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["VideoFrames", "VIDEO_SUFFIXES", "is_video_path"]

# File types read as videos (lower case); anything else is a dataset folder.
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm")
# Milliseconds per second (CAP_PROP_POS_MSEC is in milliseconds).
_MS_PER_S = 1000.0


def is_video_path(path: str | os.PathLike) -> bool:
    """True when ``path`` names a file with a video suffix (:data:`VIDEO_SUFFIXES`)."""
    path = Path(path)
    return path.suffix.lower() in VIDEO_SUFFIXES and not path.is_dir()


class VideoFrames:
    """Frames of a video file, decoded lazily in order.

    Parameters
    ----------
    path : path-like
    size : (int, int), optional, keyword-only
        Expected ``(height, width)`` of every frame (the calibration's).
    gray : bool, keyword-only
        Yield ``(H, W)`` gray frames (default); otherwise ``(H, W, 3)`` RGB.

    Attributes
    ----------
    timestamps : list of float
        Presentation time of each frame yielded so far, seconds from the
        container (the frame index over the nominal rate when the container
        gives none).

    Raises
    ------
    InputError
        Missing file, a file OpenCV cannot open as a video, no frames, or a
        first frame whose size differs from ``size``.
    """

    def __init__(self, path: str | os.PathLike, *, size: tuple[int, int] | None = None, gray: bool = True):
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(self.path, "video file not found")
        self.size = None if size is None else tuple(int(v) for v in size)
        self.gray = gray
        self.timestamps: list[float] = []
        capture = self._open()
        self.frame_count = max(int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), 0)
        self.fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
        capture.release()

    def _open(self) -> cv2.VideoCapture:
        capture = cv2.VideoCapture(str(self.path))
        if not capture.isOpened():
            raise InputError(self.path, "not a video OpenCV can read")
        return capture

    def __len__(self) -> int:
        """Frame count the container declares (may differ from the frames decoded)."""
        return self.frame_count

    def _converted(self, frame: np.ndarray, index: int) -> np.ndarray:
        if self.size is not None and frame.shape[:2] != self.size:
            raise InputError(self.path, f"frame {index} is {frame.shape[0]}x{frame.shape[1]} (height x width), "
                                        f"but the calibration names {self.size[0]}x{self.size[1]}")
        if frame.ndim == 2:
            return frame if self.gray else np.repeat(frame[..., None], 3, axis=2)
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY if self.gray else cv2.COLOR_BGR2RGB)

    def __iter__(self) -> Iterator[np.ndarray]:
        self.timestamps = []
        capture = self._open()
        try:
            index = 0
            while True:
                ok, frame = capture.read()
                if not ok:
                    break
                milliseconds = capture.get(cv2.CAP_PROP_POS_MSEC)
                if not np.isfinite(milliseconds) or (index > 0 and milliseconds <= 0):
                    milliseconds = index * _MS_PER_S / self.fps if self.fps > 0 else index * _MS_PER_S
                self.timestamps.append(milliseconds / _MS_PER_S)
                yield self._converted(frame, index)
                index += 1
            if index == 0:
                raise InputError(self.path, "no frames could be decoded")
        finally:
            capture.release()
