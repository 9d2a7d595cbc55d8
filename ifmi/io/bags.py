"""ROS bags as frame sequences: the images of one topic, decoded in the bag's order, stamped in seconds.

A robot's omni camera is recorded as a ROS bag. :class:`BagFrames` yields
the frames of one image topic the way :class:`~ifmi.io.video.VideoFrames`
yields a video's, read with the ``rosbags`` library (no ROS install):

* a ROS 1 ``.bag`` file, a ROS 2 bag folder (``metadata.yaml`` with
  SQLite3 ``.db3`` or MCAP storage), or a bare ``.mcap`` or ``.db3`` file;
* ``sensor_msgs/Image`` in the encodings of :data:`RAW_ENCODINGS`, and
  ``sensor_msgs/CompressedImage`` holding a PNG or JPEG (decoded exactly as
  an image file of a dataset folder, :func:`~ifmi.io.images.image_from_bytes`).

Frame k is the k-th message of the topic in the bag's recording order. Its
time is the message's ``header.stamp`` in seconds, or the bag's receive time
where the stamp is zero (a driver that leaves it unset). A stamp not after
the previous frame's (a duplicate, or one that goes back) is put one frame
interval after it, as a video's times are, so the timestamps of the
estimate increase; one :class:`~ifmi.errors.InputWarning` tells of it.

Colour frames read in gray equal the same pixels read in gray from an RGB
PNG file (the weights and rounding of the PNG decoder,
:func:`gray_from_rgb`), so a bag of raw images and a folder of PNG files of
the same pixels give the same estimate.

A frame that cannot be used (an encoding not listed, data shorter than its
size, damaged compressed data, another size than the calibration's after
the first) is yielded as a :class:`~ifmi.frames.MissingFrame` whose reason
names the bag, the frame and its time. A bag that cannot be opened, a topic
it does not have, a topic of another message type, or no frame at all
raise :class:`~ifmi.errors.InputError` in one line naming the bag; a bag
that breaks off while it is read ends the sequence there with one warning.
"""

from __future__ import annotations

import os
import sqlite3
import struct
import warnings
from concurrent.futures import ThreadPoolExecutor
from contextlib import closing, contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ifmi.errors import InputError, InputWarning
from ifmi.frames import MissingFrame
from ifmi.io.images import eight_bit_from_sixteen, image_from_bytes, size_problem

__all__ = ["BagFrames", "BAG_SUFFIXES", "IMAGE_TYPES", "RAW_ENCODINGS", "is_bag_path", "open_bag",
           "topics_of_types", "gray_from_rgb", "bag_read_errors", "chosen_topic",
           "stamp_seconds"]

#: Files read as bags (lower case): ROS 1, and ROS 2 storage files without their folder.
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
#: Message types of image topics.
RAW_IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE_TYPE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (RAW_IMAGE_TYPE, COMPRESSED_IMAGE_TYPE)
#: Encodings of ``sensor_msgs/Image`` read: channels, sample type, and the order of the colours.
RAW_ENCODINGS = {
    "mono8": (1, np.uint8, None),
    "mono16": (1, np.uint16, None),
    "bgr8": (3, np.uint8, "bgr"),
    "rgb8": (3, np.uint8, "rgb"),
    "bgra8": (4, np.uint8, "bgr"),
    "rgba8": (4, np.uint8, "rgb"),
}
# Weights of red, green and blue in a gray level, in units of 2**-15, and the shift that applies
# them (truncating): those of libpng's RGB-to-gray conversion, which OpenCV's PNG decoder uses
# when it reads a colour PNG in gray.
_GRAY_WEIGHTS_RGB = (9797, 19234, 3737)
_GRAY_SHIFT = 15
# Nanoseconds per second (ROS times are integer seconds and nanoseconds).
_NS_PER_S = 10 ** 9
# Spacing given to a restamped frame while fewer than two stamps are known.
_NO_RATE_INTERVAL_S = 1.0
# Topics listed by name in an error; the rest are counted.
_LISTED_TOPICS = 8

# What the libraries under the bag readers (files, SQLite, MCAP's decompressors, struct unpacking)
# raise for a damaged or truncated bag.
# (lz4 raises RuntimeError; a damaged length field in MCAP an OverflowError.)
_STORAGE_ERRORS = (OSError, EOFError, ValueError, KeyError, IndexError, struct.error, sqlite3.Error,
                   RuntimeError, AssertionError, ArithmeticError, UnicodeDecodeError)


def bag_read_errors() -> tuple:
    """The exception types raised for a bag's content: ``rosbags``' own and those of the storage under it."""
    import apsw  # the SQLite binding of ROS 2 .db3 storage (a dependency of rosbags)
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error
    from rosbags.serde import SerdeError
    from ruamel.yaml.error import YAMLError  # metadata.yaml of a ROS 2 bag folder

    return (AnyReaderError, Reader1Error, Reader2Error, SerdeError, apsw.Error, YAMLError) + _STORAGE_ERRORS


def is_bag_path(path: str | os.PathLike) -> bool:
    """True for a file with a bag suffix (:data:`BAG_SUFFIXES`) or a folder holding ``metadata.yaml``."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.suffix.lower() in BAG_SUFFIXES


def _reason(exc: BaseException) -> str:
    """The first line of an exception's message, or its type's name."""
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


@contextmanager
def open_bag(path: str | os.PathLike):
    """The bag at ``path``, open for reading, as a ``rosbags.highlevel.AnyReader``.

    A bag without message definitions (a bare ``.db3``) is read with the
    standard types of ROS 1 Noetic (``.bag``) or ROS 2 Humble (otherwise).

    Raises
    ------
    InputError
        Missing path, or not a bag ``rosbags`` can open (damaged, truncated,
        unindexed, another format), with the library's reason.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not path.exists():
        raise InputError(path, "bag not found")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise InputError(path, "not a ROS 2 bag folder (no metadata.yaml)")
    store = get_typestore(Stores.ROS1_NOETIC if path.suffix.lower() == ".bag" else Stores.ROS2_HUMBLE)
    try:
        reader = AnyReader([path], default_typestore=store)
        reader.open()
    except bag_read_errors() as exc:
        raise InputError(path, f"not a ROS bag that can be read ({_reason(exc)})") from None
    try:
        yield reader
    finally:
        try:
            reader.close()
        except bag_read_errors():
            pass


def _listed(names: list[str]) -> str:
    more = f" and {len(names) - _LISTED_TOPICS} more" if len(names) > _LISTED_TOPICS else ""
    return ", ".join(names[:_LISTED_TOPICS]) + more


def topics_of_types(reader, types) -> dict[str, str]:
    """``{topic: message type}`` of the reader's topics whose type is one of ``types``, by name."""
    return {topic: info.msgtype for topic, info in sorted(reader.topics.items()) if info.msgtype in types}


def chosen_topic(path: Path, reader, topic: str | None, types, *, what: str, option: str) -> str:
    """``topic``, checked against the bag; or, when None, the bag's only topic of ``types``.

    Raises
    ------
    InputError
        The topic is not in the bag (the message lists the bag's topics of
        ``types``), it has another type, or none was given and the bag has
        no or several topics of ``types``.
    """
    fitting = topics_of_types(reader, types)
    found = f"its {what} topics: {_listed([f'{t} ({m})' for t, m in fitting.items()])}" if fitting else \
        f"it has no {what} topic ({' or '.join(types)}); its topics: " + \
        (_listed([f"{t} ({i.msgtype})" for t, i in sorted(reader.topics.items())]) or "none")
    if topic is None:
        if len(fitting) == 1:
            return next(iter(fitting))
        if fitting:
            raise InputError(path, f"has {len(fitting)} {what} topics; choose one with {option} ({found})")
        raise InputError(path, found)
    if topic not in reader.topics:
        raise InputError(path, f"has no topic {topic} ({found})")
    msgtype = reader.topics[topic].msgtype
    if msgtype not in types:
        raise InputError(path, f"topic {topic} holds {msgtype}, expected {' or '.join(types)} ({found})")
    return topic


def stamp_seconds(message, receive_ns: int) -> float:
    """A message's ``header.stamp`` in seconds, or the receive time ``receive_ns`` when the stamp is zero."""
    stamp = message.header.stamp
    ns = int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)
    return (ns if ns else int(receive_ns)) / _NS_PER_S


def gray_from_rgb(image: np.ndarray) -> np.ndarray:
    """Gray levels of an RGB image, as a PNG decoder reads a colour PNG in gray.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        Red, green, blue, indexed ``[row, col]``.

    Returns
    -------
    (H, W) uint8 ndarray
        ``(9797 R + 19234 G + 3737 B) >> 15``: libpng's weights (0.299,
        0.587, 0.114 in units of 2**-15) and truncation, so that the frame
        equals the same pixels stored as an RGB PNG and read in gray.
    """
    red, green, blue = (np.arange(256, dtype=np.uint32) * w for w in _GRAY_WEIGHTS_RGB)
    total = red[image[..., 0]]
    total += green[image[..., 1]]
    total += blue[image[..., 2]]
    total >>= _GRAY_SHIFT
    return total.astype(np.uint8)


def _raw_pixels(message) -> np.ndarray:
    """The pixels of a ``sensor_msgs/Image`` as stored: ``(H, W)`` or ``(H, W, C)``, 8 or 16 bits.

    Raises
    ------
    ValueError
        An encoding not in :data:`RAW_ENCODINGS`, or a row step or data
        length that do not hold the frame; the message says which.
    """
    encoding = str(message.encoding)
    if encoding.lower() not in RAW_ENCODINGS:
        raise ValueError(f"encoding {encoding!r} is not read (expected one of {', '.join(RAW_ENCODINGS)})")
    channels, dtype, _ = RAW_ENCODINGS[encoding.lower()]
    height, width, step = int(message.height), int(message.width), int(message.step)
    row_bytes = width * channels * np.dtype(dtype).itemsize
    if height < 1 or width < 1 or step < row_bytes:
        raise ValueError(f"{height}x{width} {encoding} with a row step of {step} bytes (expected at least "
                         f"{row_bytes})")
    data = np.asarray(message.data, dtype=np.uint8)
    if data.size < step * height:
        raise ValueError(f"{data.size} bytes of data for {height} rows of {step} bytes (a cut frame)")
    rows = data[:step * height].reshape(height, step)[:, :row_bytes]
    order = ">" if message.is_bigendian else "<"
    pixels = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order))
    pixels = pixels.astype(dtype, copy=False).reshape((height, width, channels))
    return pixels[..., 0] if channels == 1 else pixels


def _raw_frame(message, *, source: str, gray: bool) -> np.ndarray:
    """A ``sensor_msgs/Image`` as an 8-bit ``(H, W)`` gray or ``(H, W, 3)`` RGB frame (gray stays gray)."""
    pixels = _raw_pixels(message)
    if pixels.dtype == np.uint16:
        pixels = eight_bit_from_sixteen(pixels, source=source, what="frames")
    order = RAW_ENCODINGS[str(message.encoding).lower()][2]
    if order is None:
        return pixels
    rgb = pixels[..., :3] if order == "rgb" else pixels[..., 2::-1]
    return gray_from_rgb(rgb) if gray else np.ascontiguousarray(rgb)


@dataclass(frozen=True)
class _Message:
    """One message of the topic: its position, raw bytes and receive time (ns)."""

    index: int
    receive_ns: int
    data: bytes


class BagFrames:
    """Frames of one image topic of a ROS bag, decoded lazily in the bag's order.

    Iterating yields each frame as an ``(H, W)`` or ``(H, W, 3)`` uint8
    array, or a :class:`~ifmi.frames.MissingFrame` naming the bag, the
    frame and the problem. Once the topic is read, one
    :class:`~ifmi.errors.InputWarning` tells of restamped frames and of a
    bag that broke off.

    Parameters
    ----------
    path : path-like
        A ``.bag``, ``.mcap`` or ``.db3`` file, or a ROS 2 bag folder.
    topic : str, optional, keyword-only
        The image topic; default the bag's only one.
    size : (int, int), optional, keyword-only
        Expected ``(height, width)`` of every frame (the calibration's).
    gray : bool, keyword-only
        Yield ``(H, W)`` gray frames (default); otherwise ``(H, W, 3)`` RGB
        (gray frames stay ``(H, W)``).
    prefetch : bool, keyword-only
        Decode the next frame in a background thread while the caller works
        on the current one (decoding releases the GIL), as a dataset folder's
        frames are read for an estimate.

    Attributes
    ----------
    topic : str
    msgtype : str
        ``sensor_msgs/msg/Image`` or ``sensor_msgs/msg/CompressedImage``.
    frame_count : int
        Messages of the topic the bag declares.
    timestamps : list of float
        Time of each frame yielded so far (flagged ones too), seconds
        (``header.stamp``, or the receive time where it is zero), made
        increasing as the module docstring says.

    Raises
    ------
    InputError
        The bag cannot be opened, the topic is missing, of another type or
        not given while the bag has several image topics (the message lists
        them), the topic has no message, or the first frame cannot be used
        or has another size than ``size``.
    """

    def __init__(self, path: str | os.PathLike, *, topic: str | None = None,
                 size: tuple[int, int] | None = None, gray: bool = True, prefetch: bool = False):
        self.path = Path(path)
        self.prefetch = prefetch
        self.size = None if size is None else tuple(int(v) for v in size)
        self.gray = gray
        self.timestamps: list[float] = []
        with open_bag(self.path) as reader:
            self.topic = chosen_topic(self.path, reader, topic, IMAGE_TYPES, what="image", option="--topic")
            self.msgtype = reader.topics[self.topic].msgtype
            self.frame_count = int(reader.topics[self.topic].msgcount)
        if self.frame_count == 0:
            raise InputError(self.path, f"topic {self.topic} has no messages")

    def __len__(self) -> int:
        """Messages of the topic the bag declares."""
        return self.frame_count

    def _messages(self, reader, broke: list) -> Iterator[_Message]:
        """The topic's messages in the bag's order; a read error ends them and is put in ``broke``."""
        connections = [c for c in reader.connections if c.topic == self.topic]
        index = 0
        try:
            for _, receive_ns, data in reader.messages(connections=connections):
                yield _Message(index, receive_ns, data)
                index += 1
        except bag_read_errors() as exc:
            broke.append(f"the bag breaks off after {index} of the {self.frame_count} frames of "
                         f"{self.topic} ({_reason(exc)})")

    def _decoded(self, reader, message: _Message, *, gray: bool) -> tuple[object, np.ndarray | str]:
        """``(deserialised message or None, frame or the reason it cannot be used)``."""
        try:
            ros = reader.deserialize(message.data, self.msgtype)
        except bag_read_errors() as exc:
            return None, f"the message cannot be decoded ({_reason(exc)})"
        source = f"{self.path} {self.topic} frame {message.index}"
        try:
            if self.msgtype == COMPRESSED_IMAGE_TYPE:
                frame = image_from_bytes(bytes(ros.data), source=source, size=self.size, gray=gray,
                                         depth_source=self.path)
            else:
                frame = _raw_frame(ros, source=str(self.path), gray=gray)
        except InputError as exc:
            return ros, exc.problem
        except ValueError as exc:
            return ros, str(exc)
        problem = size_problem(*frame.shape[:2], self.size)
        return ros, (problem if problem else frame)

    def _decoded_messages(self, reader, broke: list, pool: ThreadPoolExecutor | None):
        """``(message, _decoded(message))`` in order; with ``pool`` the next message is decoded there
        while the current one is with the caller."""
        messages = self._messages(reader, broke)
        if pool is None:
            for message in messages:
                yield message, self._decoded(reader, message, gray=self.gray)
            return
        pending = None
        for message in messages:
            future = pool.submit(self._decoded, reader, message, gray=self.gray)
            if pending is not None:
                yield pending[0], pending[1].result()
            pending = (message, future)
        if pending is not None:
            yield pending[0], pending[1].result()

    def _time(self, ros, message: _Message, previous: float | None, spacing: float) -> tuple[float, bool]:
        """The frame's time in seconds and whether it was restamped (not after ``previous``)."""
        seconds = message.receive_ns / _NS_PER_S if ros is None else stamp_seconds(ros, message.receive_ns)
        if previous is not None and not seconds > previous:
            return previous + spacing, True
        return seconds, False

    def __iter__(self) -> Iterator[np.ndarray | MissingFrame]:
        self.timestamps = []
        broke: list[str] = []
        restamped: list[int] = []
        with open_bag(self.path) as reader, \
                (ThreadPoolExecutor(max_workers=1) if self.prefetch else nullcontext()) as pool:
            for message, (ros, frame) in self._decoded_messages(reader, broke, pool):
                seconds, moved = self._time(ros, message, self.timestamps[-1] if self.timestamps else None,
                                            self._spacing())
                self.timestamps.append(seconds)
                restamped += [message.index] if moved else []
                if isinstance(frame, str) and message.index == 0:
                    raise InputError(self.path, f"{self.topic} frame 0: {frame}")
                if isinstance(frame, str):
                    yield MissingFrame(source=str(self.path),
                                       reason=f"{self.path.name} {self.topic} frame {message.index} at "
                                              f"{seconds:.6f} s: {frame}")
                else:
                    yield frame
        if not self.timestamps:
            raise InputError(self.path, f"no frame of {self.topic} could be read ({'; '.join(broke)})")
        self._warn(restamped, broke)

    def _spacing(self) -> float:
        """One frame interval: the mean spacing of the times so far (1 s before two are known)."""
        if len(self.timestamps) < 2 or self.timestamps[-1] <= self.timestamps[0]:
            return _NO_RATE_INTERVAL_S
        return (self.timestamps[-1] - self.timestamps[0]) / (len(self.timestamps) - 1)

    def _warn(self, restamped: list[int], broke: list[str]) -> None:
        problems = list(broke)
        if restamped:
            many = len(restamped) > 1
            problems.append(f"{len(restamped)} frame{'s' if many else ''} of {self.topic} (the first: frame "
                            f"{restamped[0]}) had a stamp not after the previous frame's (a duplicate or a "
                            f"stamp that goes back) and {'were' if many else 'was'} stamped one frame "
                            f"interval after it")
        if problems:
            warnings.warn(f"{self.path}: {'; '.join(problems)}; estimated from the {len(self.timestamps)} "
                          f"frames read", InputWarning, stacklevel=3)

    def spread_frames(self, count: int) -> list[np.ndarray]:
        """Up to ``count`` usable frames spread evenly over the topic, the first and the last included.

        The frames are those at ``linspace(0, frame_count - 1, count)``
        rounded, as for a dataset folder; later frames that cannot be used
        are left out. Does not touch :attr:`timestamps`.

        Parameters
        ----------
        count : int
            Number of frames wanted, >= 1.

        Returns
        -------
        list of (H, W) or (H, W, 3) uint8 ndarray

        Raises
        ------
        InputError
            The first frame cannot be used or has another size than ``size``.
        """
        if count < 1:
            raise ValueError(f"expected count >= 1, got {count}")
        wanted = set(np.unique(np.linspace(0, self.frame_count - 1, min(count, self.frame_count))
                               .round().astype(int)).tolist())
        frames = []
        with open_bag(self.path) as reader, closing(self._messages(reader, [])) as messages:
            for message in messages:
                if message.index in wanted:
                    _, frame = self._decoded(reader, message, gray=self.gray)
                    if isinstance(frame, str) and message.index == 0:
                        raise InputError(self.path, f"{self.topic} frame 0: {frame}")
                    frames += [] if isinstance(frame, str) else [frame]
                if message.index >= max(wanted):
                    break
        return frames
