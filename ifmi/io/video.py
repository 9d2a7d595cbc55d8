"""Video files as frame sequences: frames decoded in order by OpenCV, timestamps from the container.

A phone filming through a clip-on omni lens gives a video, not an image
folder. :class:`VideoFrames` yields its frames one by one (8-bit gray, or
RGB) as OpenCV's ``VideoCapture`` decodes them, and records each frame's
presentation time (``CAP_PROP_POS_MSEC``) in seconds.
:meth:`VideoFrames.spread_frames` gives a few frames spread over the whole
clip (by seeking, or by one decoding pass that keeps a bounded number of
frames), e.g. to decide the mirror band from more than the first frame.
Problems raise :class:`~ifmi.errors.InputError` naming the file.
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

    def spread_frames(self, count: int) -> list[np.ndarray]:
        """Up to ``count`` frames spread evenly over the clip, from its first frame to its end.

        With a declared frame count, each frame is read by seeking to it
        (the first and the last frame included).
        When the container declares none, or a seek yields no frame (a
        count larger than the frames that decode), one decoding pass keeps
        every ``s``-th frame, doubling ``s`` whenever more than ``2 count``
        are kept, so memory stays bounded whatever the clip's length; the
        ``count`` returned are spread over those kept (the last of them
        less than ``s`` frames from the end). Does not touch
        :attr:`timestamps`.

        Parameters
        ----------
        count : int
            Number of frames wanted, >= 1.

        Returns
        -------
        list of (H, W) or (H, W, 3) uint8 ndarray
            In clip order; fewer than ``count`` when the clip is shorter.

        Raises
        ------
        InputError
            No frame decodes, or a frame's size differs from ``size``.
        """
        if count < 1:
            raise ValueError(f"expected count >= 1, got {count}")
        if self.frame_count > 0:
            wanted = np.unique(np.linspace(0, self.frame_count - 1, min(count, self.frame_count)).round())
            frames = self._frames_by_seeking([int(k) for k in wanted])
            if frames is not None:
                return frames
        return self._frames_by_one_pass(count)

    def _frames_by_seeking(self, indices: list[int]) -> list[np.ndarray] | None:
        """The frames at ``indices``, each read after a seek; None when a seek yields no frame."""
        capture = self._open()
        try:
            frames = []
            for index in indices:
                capture.set(cv2.CAP_PROP_POS_FRAMES, index)
                ok, frame = capture.read()
                if not ok:
                    return None
                frames.append(self._converted(frame, index))
            return frames
        finally:
            capture.release()

    def _frames_by_one_pass(self, count: int) -> list[np.ndarray]:
        """``count`` frames spread over the clip, from one decoding pass with bounded memory."""
        capture = self._open()
        kept: list[tuple[int, np.ndarray]] = []
        stride = 1
        try:
            index = 0
            while capture.grab():
                if index % stride == 0:
                    ok, frame = capture.retrieve()
                    if ok:
                        kept.append((index, self._converted(frame, index)))
                    if len(kept) > 2 * count:
                        stride *= 2
                        kept = [(k, f) for k, f in kept if k % stride == 0]
                index += 1
        finally:
            capture.release()
        if not kept:
            raise InputError(self.path, "no frames could be decoded")
        chosen = np.unique(np.linspace(0, len(kept) - 1, min(count, len(kept))).round().astype(int))
        return [kept[k][1] for k in chosen]
