"""Video files as frame sequences: frames decoded in order by OpenCV, times from the container.

A phone filming through a clip-on omni lens gives a video, not an image
folder. :class:`VideoFrames` yields its frames one by one (8-bit gray, or
RGB) as OpenCV's ``VideoCapture`` (FFmpeg back end) decodes them, and
records each frame's presentation time in seconds, counted from the first
frame (:attr:`VideoFrames.timestamps`).
:meth:`VideoFrames.spread_frames` gives a few frames spread over the whole
clip (by seeking, or by one decoding pass that keeps a bounded number of
frames), e.g. to decide the mirror band from more than the first frame.

Frames are read as stored: rotation metadata (a phone held upright) is not
applied, because a calibration refers to sensor pixels. Frames of a 16-bit
gray stream are decoded raw and read at the depth their samples were
recorded at, as 16-bit images are
(:func:`~ifmi.io.images.eight_bit_from_sixteen`). Damage is reported,
never passed on silently:

* FFmpeg's own lines (``[mjpeg @ 0x...] overread 8``, ``moov atom not
  found``) are captured from the C-level standard error around every call
  into the decoder (:func:`_logged`) instead of reaching the terminal. A
  frame the decoder complains about is yielded as a
  :class:`~ifmi.frames.MissingFrame` (the sequence flags it and goes on);
  a frame it rejects outright is skipped, and its time stays a gap.
* At the end of the clip one :class:`~ifmi.errors.InputWarning` tells of
  skipped frames, of fewer frames than the container declares (a truncated
  or damaged file), and of what FFmpeg said on opening it.

Not detectable through OpenCV: a change of frame size inside the stream
(OpenCV scales every frame to the size the stream header names), and damage
an inter-frame decoder conceals without a message.
Problems raise :class:`~ifmi.errors.InputError` naming the file.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, TypeVar

import cv2
import numpy as np

from ifmi.errors import InputError, InputWarning
from ifmi.frames import MissingFrame
from ifmi.io.images import eight_bit_from_sixteen
from ifmi.io.native_stderr import call_with_captured_stderr

__all__ = ["VideoFrames", "VIDEO_SUFFIXES", "is_video_path"]

# File types read as videos (lower case); anything else is a dataset folder.
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm")
# Containers that store their frame count; Matroska/WebM do not (OpenCV estimates it from the
# duration and the nominal rate, which a variable-rate clip does not follow).
_COUNTED_SUFFIXES = (".mp4", ".avi", ".mov", ".m4v")
# Containers that store no time per frame: frame k is at k / rate, so a frame lost before the
# end makes the later ones early.
_UNTIMED_SUFFIXES = (".avi",)
# Milliseconds per second (CAP_PROP_POS_MSEC is in milliseconds).
_MS_PER_S = 1000.0
# Spacing given to a frame without a presentation time when the container names no rate.
_NO_RATE_INTERVAL_S = 1.0
# FFmpeg's codec tags of 16-bit gray frames (gray16le "Y1\0\x10", gray16be "\x10\0" "1Y"), as
# CAP_PROP_CODEC_PIXEL_FORMAT gives them. OpenCV's conversion to 8 bits keeps their high byte, so
# 10- to 14-bit samples stored unscaled (a machine-vision camera's FFV1 recording) would read as a
# few gray levels; such frames are taken raw and read at their recorded depth, as 16-bit images.
_GRAY16_TAGS = (int.from_bytes(b"Y1\x00\x10", "little"), int.from_bytes(b"\x10\x001Y", "little"))
# Decoder threads: one, so that the decoder writes a frame's messages while it is grabbed, in the
# calling thread, instead of from a worker thread at any later time.
_DECODER_THREADS = 1
# Frames the decoder may reject in a row before the rest of the file counts as unreadable.
_MAX_REJECTED_IN_ROW = 64
# Decoder messages quoted in a flag, error or warning (the rest are counted).
_QUOTED_MESSAGES = 2
# The "[mjpeg @ 0x55d0c2a1b2c0] " context prefix of an FFmpeg log line.
_LOG_PREFIX = re.compile(r"^\[[^\]]*\]\s*")
# A line of OpenCV's own logger ("[ WARN:0@0.312] global cap.cpp:212 open VIDEOIO(FFMPEG): ..."):
# about the back ends OpenCV tried, not about the file; kept off the terminal, not quoted.
_OPENCV_LOG_LINE = re.compile(r"^\[\s*(FATAL|ERROR|WARN|INFO|DEBUG|VERBOSE):")

_T = TypeVar("_T")


def is_video_path(path: str | os.PathLike) -> bool:
    """True when ``path`` names a file with a video suffix (:data:`VIDEO_SUFFIXES`)."""
    path = Path(path)
    return path.suffix.lower() in VIDEO_SUFFIXES and not path.is_dir()


def _logged(call: Callable[[], _T]) -> tuple[_T, list[str]]:
    """``call()``, and the lines written to the C-level standard error meanwhile, kept instead of shown.

    FFmpeg prints its complaints to file descriptor 2, out of Python's reach;
    for the call, descriptor 2 is a temporary file. Returns the call's result
    and FFmpeg's lines, stripped of their ``[context @ 0x...]`` prefix and
    final full stop (OpenCV's own log lines are dropped).
    """
    result, written = call_with_captured_stderr(call)
    text = written.decode("utf-8", errors="replace")
    return result, [_LOG_PREFIX.sub("", line).strip().rstrip(".") for line in text.splitlines()
                    if line.strip() and not _OPENCV_LOG_LINE.match(line)]


def _quoted(messages: list[str]) -> str:
    """The first few ``messages`` joined on one line, and how many more."""
    more = f"; and {len(messages) - _QUOTED_MESSAGES} more" if len(messages) > _QUOTED_MESSAGES else ""
    return "; ".join(messages[:_QUOTED_MESSAGES]) + more


class _Capture:
    """A ``cv2.VideoCapture`` of a file, read as stored, whose log lines are kept, not printed.

    Raises
    ------
    InputError
        OpenCV cannot open the file (with what FFmpeg said), or the file
        carries rotation metadata that OpenCV cannot be told to ignore.
    """

    def __init__(self, path: Path):
        self.path = path
        self.capture, self.open_messages = _logged(self._open)
        if not self.capture.isOpened():
            self.release()
            said = f" (FFmpeg: {_quoted(self.open_messages)})" if self.open_messages else ""
            raise InputError(path, f"not a video OpenCV can read{said}")
        if int(self.capture.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT)) in _GRAY16_TAGS:
            self.capture.set(cv2.CAP_PROP_CONVERT_RGB, 0)  # raw 16-bit frames (see _GRAY16_TAGS)
        # The calibration refers to the frames as the sensor stored them: never apply the
        # display rotation a phone records.
        self.capture.set(cv2.CAP_PROP_ORIENTATION_AUTO, 0)
        self.rotation = float(self.capture.get(cv2.CAP_PROP_ORIENTATION_META)) % 360.0
        if self.rotation and self.capture.get(cv2.CAP_PROP_ORIENTATION_AUTO):
            self.release()
            raise InputError(path, f"the video asks to be shown rotated by {self.rotation:g} degrees, and "
                                   f"this OpenCV cannot turn that rotation off; expected frames as stored "
                                   f"(the calibration's sensor pixels)")

    def _open(self) -> cv2.VideoCapture:
        if cv2.videoio_registry.hasBackend(cv2.CAP_FFMPEG):
            return cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG,
                                    [cv2.CAP_PROP_N_THREADS, _DECODER_THREADS])
        return cv2.VideoCapture(str(self.path))

    def get(self, prop: int) -> float:
        return float(self.capture.get(prop))

    def grab(self) -> tuple[bool, list[str]]:
        """Decode the next frame: whether there was one, and the decoder's messages."""
        return _logged(self.capture.grab)

    def retrieve(self) -> tuple[np.ndarray | None, list[str]]:
        """The grabbed frame (BGR or gray) or None, and the messages of its conversion."""
        (ok, frame), messages = _logged(self.capture.retrieve)
        return (frame if ok else None), messages

    def seek(self, index: int) -> None:
        """Move to frame ``index`` (the next one :meth:`grab` decodes).

        Messages are dropped: they are about the frames decoded on the way
        (OpenCV seeks to an earlier frame and decodes forward).
        """
        _logged(lambda: self.capture.set(cv2.CAP_PROP_POS_FRAMES, index))

    def release(self) -> None:
        _logged(self.capture.release)


@dataclass(frozen=True)
class _Grab:
    """One frame grabbed in decoding order: ``index`` and ``seconds`` are None for a frame the
    decoder rejected; ``messages`` are the decoder's complaints about it."""

    index: int | None
    seconds: float | None
    messages: list[str]
    restamped: bool = False


class VideoFrames:
    """Frames of a video file, decoded lazily in order, as stored.

    Iterating yields each frame as an ``(H, W)`` or ``(H, W, 3)`` uint8
    array, or, for a frame that cannot be trusted, a
    :class:`~ifmi.frames.MissingFrame` whose reason names the file, the frame
    and the problem: the decoder reported damage in it (a corrupt or
    half-written frame), or a frame after the first has another size than
    ``size``. A frame the decoder rejects outright is skipped: its time is
    missing from :attr:`timestamps`. Once the clip is read, one
    :class:`~ifmi.errors.InputWarning` tells of skipped frames, of fewer
    frames than the container declares, and of FFmpeg's complaints on
    opening the file.

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
        Presentation time of each frame yielded so far (flagged ones too),
        in seconds from the first: the container's times minus the first
        frame's, whatever time the container starts at (so a lost frame
        leaves a gap in a container that stores times per frame: MP4, MOV,
        Matroska, WebM). A frame without a time, or with one not after the
        previous frame's (times that restart), is put one nominal frame
        interval after the previous one, so the timestamps increase.
    frame_count : int
        Frame count the container declares (0 when unknown).
    fps : float
        Nominal frame rate (0 when unknown).
    rotation : float
        Display rotation the file asks for, in degrees; it is not applied.

    Raises
    ------
    InputError
        Missing file, a file OpenCV cannot open as a video (with FFmpeg's
        reason), rotation metadata OpenCV cannot ignore, no frames, or a
        first frame whose size differs from ``size``.
    """

    def __init__(self, path: str | os.PathLike, *, size: tuple[int, int] | None = None, gray: bool = True):
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(self.path, "video file not found")
        self.size = None if size is None else tuple(int(v) for v in size)
        self.gray = gray
        self.timestamps: list[float] = []
        capture = _Capture(self.path)
        self.frame_count = max(int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), 0)
        self.fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
        self.rotation = capture.rotation
        capture.release()

    def __len__(self) -> int:
        """Frame count the container declares (may differ from the frames decoded)."""
        return self.frame_count

    def _size_problem(self, frame: np.ndarray, index: int) -> str | None:
        """Why ``frame`` does not fit the calibration's size, or None."""
        if self.size is None or frame.shape[:2] == self.size:
            return None
        turned = (f" (the video's rotation metadata of {self.rotation:g} degrees is not applied: "
                  f"frames are read as stored, as the calibration must be)"
                  if self.rotation % 180 and frame.shape[:2] == self.size[::-1] else "")
        return (f"frame {index} is {frame.shape[0]}x{frame.shape[1]} (height x width), "
                f"but the calibration names {self.size[0]}x{self.size[1]}{turned}")

    def _converted(self, frame: np.ndarray) -> np.ndarray:
        if frame.dtype == np.uint16:
            frame = eight_bit_from_sixteen(frame, source=self.path, what="frames")
        if frame.ndim == 2:
            return frame if self.gray else np.repeat(frame[..., None], 3, axis=2)
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY if self.gray else cv2.COLOR_BGR2RGB)

    def _flag(self, grab: _Grab, problem: str) -> MissingFrame:
        return MissingFrame(source=str(self.path),
                            reason=f"{self.path.name} frame {grab.index} at "
                                   f"{self.timestamps[grab.index]:.3f} s: {problem}")

    def _grabs(self, capture: _Capture) -> Iterator[_Grab]:
        """Every frame of ``capture`` in decoding order, with its raw time in seconds.

        A grab that fails with a decoder message is a rejected frame, and
        decoding goes on after it; one that fails silently is the end.
        """
        index, previous, rejected_in_row = 0, None, 0
        while True:
            ok, messages = capture.grab()
            if not ok:
                if not messages or rejected_in_row >= _MAX_REJECTED_IN_ROW:
                    return
                rejected_in_row += 1
                yield _Grab(None, None, messages)
                continue
            rejected_in_row = 0
            milliseconds = capture.get(cv2.CAP_PROP_POS_MSEC)
            seconds = milliseconds / _MS_PER_S
            untimed = not np.isfinite(seconds) or (previous is not None and seconds <= 0)
            # A time not after the previous frame's (a clip joined from two whose times restart):
            # as if missing, so that the trajectory's timestamps increase.
            restamped = not untimed and previous is not None and seconds <= previous
            if untimed or restamped:
                seconds = 0.0 if previous is None else previous + (
                    1.0 / self.fps if self.fps > 0 else _NO_RATE_INTERVAL_S)
            yield _Grab(index, seconds, messages, restamped=restamped)
            previous = seconds
            index += 1

    def __iter__(self) -> Iterator[np.ndarray | MissingFrame]:
        self.timestamps = []
        capture = _Capture(self.path)
        rejected: list[_Grab] = []
        damaged: list[_Grab] = []
        restamped: list[_Grab] = []
        first = 0.0  # raw time of the first frame, the origin of the timestamps
        try:
            for grab in self._grabs(capture):
                if grab.index is None:
                    rejected.append(grab)
                    continue
                if grab.index == 0:
                    first = grab.seconds
                self.timestamps.append(grab.seconds - first)
                damaged += [grab] if grab.messages else []
                restamped += [grab] if grab.restamped else []
                yield self._frame(capture, grab)
            if not self.timestamps:
                messages = capture.open_messages + [m for grab in rejected for m in grab.messages]
                said = f" (FFmpeg: {_quoted(messages)})" if messages else ""
                raise InputError(self.path, f"no frames could be decoded{said}")
            self._warn_if_incomplete(rejected, damaged, capture.open_messages, restamped)
        finally:
            capture.release()

    def _frame(self, capture: _Capture, grab: _Grab) -> np.ndarray | MissingFrame:
        """The grabbed frame, converted, or a flag for a damaged or mis-sized one."""
        if grab.messages:
            return self._flag(grab, f"the decoder reported damage ({_quoted(grab.messages)})")
        frame, messages = capture.retrieve()
        if frame is None or messages:
            said = f" ({_quoted(messages)})" if messages else ""
            return self._flag(grab, f"could not be converted{said}")
        problem = self._size_problem(frame, grab.index)
        if problem and grab.index == 0:
            raise InputError(self.path, problem)
        if problem:
            return MissingFrame(source=str(self.path), reason=f"{self.path.name}: {problem}")
        return self._converted(frame)

    def _warn_if_incomplete(self, rejected: list[_Grab], damaged: list[_Grab], open_messages: list[str],
                            restamped: list[_Grab] = ()) -> None:
        """One InputWarning for rejected frames, a short count, FFmpeg's complaints on opening, or
        frames whose times did not increase."""
        read = len(self.timestamps)
        problems = []
        if restamped:
            first = restamped[0].index
            problems.append(f"{len(restamped)} frame{'s' if len(restamped) > 1 else ''} (the first: frame {first}) "
                            f"had a presentation time not after the previous frame's (times that restart, as in "
                            f"clips joined into one) and {'were' if len(restamped) > 1 else 'was'} stamped one frame "
                            f"interval after it")
        if rejected:
            problems.append(f"skipped {len(rejected)} frame{'s' if len(rejected) > 1 else ''} the decoder "
                            f"rejected ({_quoted([m for grab in rejected for m in grab.messages])})")
        suffix = self.path.suffix.lower()
        found = read + len(rejected)
        if suffix in _COUNTED_SUFFIXES and found < self.frame_count:
            problems.append(f"only {found} of the {self.frame_count} frames the container declares were "
                            f"found (truncated or damaged file)")
            lost_at_end = bool(damaged) and damaged[0].index == read - 1
            if suffix in _UNTIMED_SUFFIXES and not lost_at_end:
                near = (f" (probably those after the damaged frame {damaged[0].index} at "
                        f"{self.timestamps[damaged[0].index]:.3f} s)" if damaged else "")
                problems.append(f"an AVI stores no frame times: if a frame was lost before the end, the "
                                f"frames after it{near} are stamped early")
        if open_messages:
            problems.append(f"FFmpeg on opening it: {_quoted(open_messages)}")
        if problems:
            warnings.warn(f"{self.path}: {'; '.join(problems)}; estimated from the {read} frames decoded",
                          InputWarning, stacklevel=3)

    def spread_frames(self, count: int) -> list[np.ndarray]:
        """Up to ``count`` frames spread evenly over the clip, from its first frame to its end.

        With a declared frame count, each frame is read by seeking to it
        (the first and the last frame included).
        When the container declares none, or a seek yields no frame (a
        count larger than the frames that decode), one decoding pass keeps
        every ``s``-th frame, doubling ``s`` whenever more than ``2 count``
        are kept, so memory stays bounded whatever the clip's length; the
        ``count`` returned are spread over those kept (the last of them
        less than ``s`` frames from the end). Frames the decoder complains
        about, and later frames of another size than ``size``, are left
        out. Does not touch :attr:`timestamps` and warns of nothing (reading
        the clip does).

        Parameters
        ----------
        count : int
            Number of frames wanted, >= 1.

        Returns
        -------
        list of (H, W) or (H, W, 3) uint8 ndarray
            In clip order; fewer than ``count`` when the clip is shorter or
            has damaged frames.

        Raises
        ------
        InputError
            No frame decodes, or the first frame's size differs from ``size``.
        """
        if count < 1:
            raise ValueError(f"expected count >= 1, got {count}")
        if self.frame_count > 0:
            wanted = np.unique(np.linspace(0, self.frame_count - 1, min(count, self.frame_count)).round())
            frames = self._frames_by_seeking([int(k) for k in wanted])
            if frames is not None:
                return frames
        return self._frames_by_one_pass(count)

    def _usable(self, frame: np.ndarray | None, index: int) -> np.ndarray | None:
        """``frame`` converted, or None when it is missing or (after the first) of another size."""
        if frame is None:
            return None
        problem = self._size_problem(frame, index)
        if problem and index == 0:
            raise InputError(self.path, problem)
        return None if problem else self._converted(frame)

    def _frames_by_seeking(self, indices: list[int]) -> list[np.ndarray] | None:
        """The sound frames at ``indices``, each read after a seek; None when a seek yields no frame."""
        capture = _Capture(self.path)
        try:
            frames = []
            for index in indices:
                capture.seek(index)
                ok, messages = capture.grab()
                if not ok:
                    return None
                if messages:
                    continue  # a damaged frame does not decide the band
                frame, converted = capture.retrieve()
                if (usable := self._usable(None if converted else frame, index)) is not None:
                    frames.append(usable)
            return frames
        finally:
            capture.release()

    def _frames_by_one_pass(self, count: int) -> list[np.ndarray]:
        """``count`` sound frames spread over the clip, from one decoding pass with bounded memory."""
        capture = _Capture(self.path)
        kept: list[tuple[int, np.ndarray]] = []
        stride = 1
        try:
            for grab in self._grabs(capture):
                if grab.index is None or grab.index % stride or grab.messages:
                    continue
                frame, messages = capture.retrieve()
                if (usable := self._usable(None if messages else frame, grab.index)) is not None:
                    kept.append((grab.index, usable))
                if len(kept) > 2 * count:
                    stride *= 2
                    kept = [(k, f) for k, f in kept if k % stride == 0]
        finally:
            capture.release()
        if not kept:
            raise InputError(self.path, "no frames could be decoded")
        chosen = np.unique(np.linspace(0, len(kept) - 1, min(count, len(kept))).round().astype(int))
        return [kept[k][1] for k in chosen]
