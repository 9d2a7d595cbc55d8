"""A dataset folder written as a ROS bag, to be played into a ROS visual-odometry node.

The bag (ROS 2 folder with MCAP storage by default, or SQLite3; or a ROS 1
``.bag`` file) holds, with frame k stamped ``start_time + t_k *
frame_interval`` seconds, ``t_k`` being the frame's time in the dataset
(its index; ground-truth lines carry their own time in frames):

``/camera/image_raw``
    The images: ``sensor_msgs/Image`` (``mono8`` or ``rgb8``), or
    ``sensor_msgs/CompressedImage`` with ``compressed`` (``png``:
    lossless; a source file already in that format is stored as it is),
    ``frame_id`` ``camera``.
``/groundtruth/pose``
    ``groundtruth.txt``: ``geometry_msgs/PoseStamped`` of camera k in the
    first camera's frame (``frame_id`` ``camera_0``).
``/tf``
    ``poses_world.txt`` when the dataset has it (a render):
    ``world -> camera`` transforms, camera-to-world, metres.
``/groundtruth/row_poses``
    With a rolling shutter (``rolling_shutter/NNNNNN.txt``): one
    ``nav_msgs/Path`` per frame, stamped as the frame, whose pose r is image
    row r's pose in ``camera_0`` stamped at the row's own time.

The calibration stays in the dataset's file (no ROS message holds an
omnidirectional model). The bag is written beside its path and moved there
when complete (:class:`ifmi.io.bag_writer.BagWriter`); an existing path, the
dataset itself or a path inside it is refused.
"""

from __future__ import annotations

import heapq
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ifmi.errors import InputError
from ifmi.io.bag_writer import BAG_FORMATS, BAG_STORAGES, BagWriter
from ifmi.io.dataset import read_dataset, read_image
from ifmi.io.tum import read_tum

__all__ = ["ExportSettings", "ExportResult", "export_dataset", "IMAGE_TOPIC", "GROUNDTRUTH_TOPIC", "TF_TOPIC",
           "ROW_POSES_TOPIC"]

IMAGE_TOPIC = "/camera/image_raw"
GROUNDTRUTH_TOPIC = "/groundtruth/pose"
TF_TOPIC = "/tf"
ROW_POSES_TOPIC = "/groundtruth/row_poses"
# Frame names: the moving camera, the first camera (ground truth's frame), the scene's world.
_CAMERA_FRAME = "camera"
_FIRST_CAMERA_FRAME = "camera_0"
_WORLD_FRAME = "world"
#: Compressed image formats: file suffixes of a source image stored as it is, and OpenCV's encoder.
COMPRESSED_FORMATS = {"png": ((".png",), ".png"), "jpeg": ((".jpg", ".jpeg"), ".jpg")}
# JPEG quality of frames encoded for the bag (OpenCV's scale, 0..100).
_JPEG_QUALITY = 95
# Nanoseconds per second.
_NS_PER_S = 10 ** 9


@dataclass(frozen=True)
class ExportSettings:
    """How a dataset is written as a bag.

    Attributes
    ----------
    bag_format : {"ros2", "ros1"}
    storage : {"mcap", "sqlite3"}
        Storage of a ROS 2 bag.
    compressed : {"png", "jpeg"} or None
        Images as ``CompressedImage`` of that format; None: raw ``Image``.
    start_time : float
        Stamp of time 0 (frame 0), seconds.
    frame_interval : float
        Seconds between frames (> 0).
    """

    bag_format: str = "ros2"
    storage: str = "mcap"
    compressed: str | None = None
    start_time: float = 0.0
    frame_interval: float = 1.0

    def __post_init__(self) -> None:
        checks = (("--format", self.bag_format in BAG_FORMATS, f"one of {', '.join(BAG_FORMATS)}"),
                  ("--storage", self.storage in BAG_STORAGES, f"one of {', '.join(BAG_STORAGES)}"),
                  ("--compressed", self.compressed is None or self.compressed in COMPRESSED_FORMATS,
                   f"one of {', '.join(COMPRESSED_FORMATS)}"),
                  ("--start-time", np.isfinite(self.start_time) and self.start_time >= 0,
                   "a finite time >= 0 in seconds"),
                  ("--frame-interval", np.isfinite(self.frame_interval) and self.frame_interval > 0,
                   "a finite interval > 0 in seconds"))
        for option, ok, expected in checks:
            if not ok:
                raise InputError(option, f"expected {expected}")

    def stamp_ns(self, frames: float) -> int:
        """The stamp, in nanoseconds, of a time ``frames`` frame intervals after time 0."""
        return int(round((self.start_time + float(frames) * self.frame_interval) * _NS_PER_S))


@dataclass(frozen=True)
class ExportResult:
    """Outcome of :func:`export_dataset`: the bag written, its frame count, and its topics."""

    out: str
    frames: int
    topics: tuple


def _check_out(dataset_root: Path, out: Path, settings: ExportSettings) -> None:
    """Refuse an output that is or lies in the dataset, or whose name does not fit the format."""
    source = dataset_root.resolve()
    if out.resolve() == source or out.resolve().is_relative_to(source):
        raise InputError(out, f"is the source dataset or lies inside it ({dataset_root}); choose a path "
                              f"outside it")
    if settings.bag_format == "ros1" and out.suffix != ".bag":
        raise InputError(out, "a ROS 1 bag is a file ending in .bag")
    if settings.bag_format == "ros2" and out.suffix.lower() in (".bag", ".mcap", ".db3"):
        raise InputError(out, f"a ROS 2 bag is a folder: name it without {out.suffix} (or --format ros1 for "
                              f"a .bag file)")


def _row_pose_files(root: Path, indices) -> list[Path]:
    """``rolling_shutter/NNNNNN.txt`` of each frame index, or [] for a global shutter."""
    folder = root / "rolling_shutter"
    if not folder.is_dir():
        return []
    paths = [folder / f"{k:06d}.txt" for k in indices]
    missing = [p.name for p in paths if not p.is_file()]
    if missing:
        raise InputError(folder, f"per-row poses missing for {len(missing)} frames (the first: {missing[0]})")
    return paths


def _events(dataset, settings: ExportSettings, truth, world, rows: list[Path]):
    """``(stamp_ns, order, kind, index)`` of every message, in time order."""
    streams = [
        [(settings.stamp_ns(t), 0, "image", k) for k, t in enumerate(dataset.frame_indices)],
        [] if truth is None else [(settings.stamp_ns(t), 1, "pose", k) for k, t in enumerate(truth.timestamps)],
        [] if world is None else [(settings.stamp_ns(t), 2, "tf", k) for k, t in enumerate(world.timestamps)],
        [(settings.stamp_ns(t), 3, "rows", k) for k, t in enumerate(dataset.frame_indices) if rows],
    ]
    return heapq.merge(*(sorted(s) for s in streams))


def _image_message(writer: BagWriter, dataset, k: int, settings: ExportSettings, stamp_ns: int):
    """Frame k as an ``Image``, or a ``CompressedImage`` (the file's own bytes when of that format)."""
    import cv2

    path = dataset.image_paths[k]
    if settings.compressed is None:
        pixels = read_image(path, size=dataset.model.size, gray=False)
        return writer.image(pixels, stamp_ns=stamp_ns, frame_id=_CAMERA_FRAME)
    suffixes, encoder = COMPRESSED_FORMATS[settings.compressed]
    if path.suffix.lower() in suffixes:
        read_image(path, size=dataset.model.size)  # a damaged file is refused, not copied
        data = path.read_bytes()
    else:
        pixels = read_image(path, size=dataset.model.size, gray=False)
        bgr = pixels[..., ::-1] if pixels.ndim == 3 else pixels
        quality = [cv2.IMWRITE_JPEG_QUALITY, _JPEG_QUALITY] if settings.compressed == "jpeg" else []
        ok, buffer = cv2.imencode(encoder, np.ascontiguousarray(bgr), quality)
        if not ok:
            raise InputError(path, f"could not be encoded as {settings.compressed}")
        data = buffer.tobytes()
    return writer.compressed_image(data, settings.compressed, stamp_ns=stamp_ns, frame_id=_CAMERA_FRAME)


def _row_path(writer: BagWriter, path: Path, settings: ExportSettings, stamp_ns: int):
    """A frame's per-row poses (a TUM file, times in frames) as a ``nav_msgs/Path``."""
    rows = read_tum(path)
    poses = [writer.pose_stamped(r, p, stamp_ns=settings.stamp_ns(t), frame_id=_FIRST_CAMERA_FRAME)
             for t, p, r in zip(rows.timestamps, rows.positions, rows.rotations)]
    return writer.path_message(poses, stamp_ns=stamp_ns, frame_id=_FIRST_CAMERA_FRAME)


def export_dataset(dataset_dir: str | os.PathLike, out: str | os.PathLike, *,
                   settings: ExportSettings = ExportSettings(), progress: bool = False) -> ExportResult:
    """Write a dataset folder as a ROS bag (see the module docstring for its topics).

    Parameters
    ----------
    dataset_dir : path-like
        A DATASET folder (calibration, ``images/``, optional ``groundtruth.txt``,
        ``poses_world.txt`` and ``rolling_shutter/``).
    out : path-like
        The bag: a folder (``ros2``) or a ``.bag`` file (``ros1``); must not exist.
    settings : ExportSettings, keyword-only
    progress : bool, keyword-only
        Show a progress bar on stderr.

    Returns
    -------
    ExportResult

    Raises
    ------
    InputError
        An unreadable dataset, image or trajectory file, an output that is
        the dataset or lies in it, or a name that does not fit the format.
    OutputError
        ``out`` exists, or the bag cannot be written; nothing is left at ``out``.
    """
    from tqdm import tqdm

    dataset = read_dataset(dataset_dir)
    out = Path(out)
    _check_out(dataset.root, out, settings)
    truth = None if dataset.groundtruth_path is None else read_tum(dataset.groundtruth_path)
    world_path = dataset.root / "poses_world.txt"
    world = read_tum(world_path) if world_path.is_file() else None
    rows = _row_pose_files(dataset.root, dataset.frame_indices)
    topics = (IMAGE_TOPIC,) + ((GROUNDTRUTH_TOPIC,) if truth is not None else ()) + \
        ((TF_TOPIC,) if world is not None else ()) + ((ROW_POSES_TOPIC,) if rows else ())
    with BagWriter(out, bag_format=settings.bag_format, storage=settings.storage) as writer, \
            tqdm(total=len(dataset), disable=not progress, unit="frame", desc="export") as bar:
        for stamp_ns, _, kind, k in _events(dataset, settings, truth, world, rows):
            if kind == "image":
                writer.write(IMAGE_TOPIC, _image_message(writer, dataset, k, settings, stamp_ns), stamp_ns)
                bar.update(1)
            elif kind == "pose":
                writer.write(GROUNDTRUTH_TOPIC, writer.pose_stamped(truth.rotations[k], truth.positions[k],
                                                                    stamp_ns=stamp_ns, frame_id=_FIRST_CAMERA_FRAME),
                             stamp_ns)
            elif kind == "tf":
                transform = writer.transform_stamped(world.rotations[k], world.positions[k], stamp_ns=stamp_ns,
                                                     parent=_WORLD_FRAME, child=_CAMERA_FRAME)
                writer.write(TF_TOPIC, writer.tf_message([transform]), stamp_ns)
            else:
                writer.write(ROW_POSES_TOPIC, _row_path(writer, rows[k], settings, stamp_ns), stamp_ns)
    return ExportResult(out=str(out), frames=len(dataset), topics=topics)
