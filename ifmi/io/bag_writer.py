"""Writing ROS bags (ROS 1 ``.bag``, ROS 2 folders with MCAP or SQLite3 storage) atomically.

:class:`BagWriter` writes through the ``rosbags`` library into a temporary
folder beside the target and moves the finished bag into place only when it
is complete, so a reader never sees a half-written bag; an existing path is
never replaced. Its methods build the standard messages a data set needs
(headers, images, poses, transforms) for the bag's ROS version.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ifmi.errors import OutputError
from ifmi.geometry.rotations import quat_xyzw_from_matrix

__all__ = ["BagWriter", "BAG_FORMATS", "BAG_STORAGES"]

#: Bag formats: a ROS 1 ``.bag`` file or a ROS 2 bag folder.
BAG_FORMATS = ("ros2", "ros1")
#: Storages of a ROS 2 bag.
BAG_STORAGES = ("mcap", "sqlite3")
# Version of the ROS 2 bag format written (rosbag2 metadata version 8 is read by Humble and later).
_ROS2_BAG_VERSION = 8
# Nanoseconds per second.
_NS_PER_S = 10 ** 9
# The message of /tf, and its definition (the same in ROS 1 and ROS 2).
_TF_TYPE = "tf2_msgs/msg/TFMessage"
_TF_DEFINITION = "geometry_msgs/TransformStamped[] transforms"


class BagWriter:
    """A bag being written; a context manager that puts it in place when its block ends without error.

    Parameters
    ----------
    path : path-like
        The bag to write: a ``.bag`` file (``ros1``) or a folder (``ros2``).
    bag_format : {"ros2", "ros1"}, keyword-only
    storage : {"mcap", "sqlite3"}, keyword-only
        Storage of a ROS 2 bag.

    Raises
    ------
    OutputError
        Something exists at ``path`` already, or the bag cannot be written
        (the message names ``path`` and the reason).
    """

    def __init__(self, path: str | os.PathLike, *, bag_format: str = "ros2", storage: str = "mcap"):
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        if bag_format not in BAG_FORMATS or storage not in BAG_STORAGES:
            raise ValueError(f"expected a format of {BAG_FORMATS} and a storage of {BAG_STORAGES}, "
                             f"got {bag_format!r}, {storage!r}")
        self.path = Path(path)
        self.ros1 = bag_format == "ros1"
        self.storage = storage
        self.typestore = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if _TF_TYPE not in self.typestore.types:  # ROS 1's tf2_msgs are not in the Noetic store
            self.typestore.register(get_types_from_msg(_TF_DEFINITION, _TF_TYPE))
        self._connections: dict[str, object] = {}
        self._staging: Path | None = None
        self._writer = None

    def __enter__(self) -> "BagWriter":
        if os.path.lexists(self.path):
            raise OutputError(self.path, "exists already; a bag is never replaced (choose a new path)")
        try:
            self._staging = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.parent))
            self._writer = self._opened(self._staging / self.path.name)
        except OSError as exc:
            self._discard()
            raise OutputError.from_os_error(self.path, exc) from None
        return self

    def _opened(self, target: Path):
        from rosbags.rosbag1 import Writer as Ros1Writer
        from rosbags.rosbag2 import StoragePlugin, Writer as Ros2Writer

        if self.ros1:
            writer = Ros1Writer(target)
        else:
            plugin = StoragePlugin.MCAP if self.storage == "mcap" else StoragePlugin.SQLITE3
            writer = Ros2Writer(target, version=_ROS2_BAG_VERSION, storage_plugin=plugin)
        writer.open()
        return writer

    def __exit__(self, kind, value, traceback) -> None:
        try:
            if kind is not None:
                return
            try:
                self._writer.close()
                self._writer = None
                if os.path.lexists(self.path):
                    raise OutputError(self.path, "appeared while the bag was written; it is not replaced")
                os.rename(self._staging / self.path.name, self.path)
            except OSError as exc:
                raise OutputError.from_os_error(self.path, exc) from None
        finally:
            self._discard()

    def _discard(self) -> None:
        """Remove the staging folder and whatever is left in it."""
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:  # the staging folder goes anyway; its content does not matter
                pass
            self._writer = None
        if self._staging is not None:
            shutil.rmtree(self._staging, ignore_errors=True)
            self._staging = None

    def write(self, topic: str, message, receive_ns: int) -> None:
        """Write ``message`` (built by this writer's methods) on ``topic`` at ``receive_ns`` nanoseconds."""
        msgtype = message.__msgtype__
        connection = self._connections.get(topic)
        if connection is None:
            connection = self._writer.add_connection(topic, msgtype, typestore=self.typestore)
            self._connections[topic] = connection
        data = (self.typestore.serialize_ros1(message, msgtype) if self.ros1
                else self.typestore.serialize_cdr(message, msgtype))
        try:
            self._writer.write(connection, int(receive_ns), data)
        except OSError as exc:
            raise OutputError.from_os_error(self.path, exc) from None

    def _type(self, name: str):
        return self.typestore.types[name]

    def header(self, stamp_ns: int, frame_id: str):
        """A ``std_msgs/Header`` stamped ``stamp_ns`` nanoseconds in ``frame_id``."""
        stamp = self._type("builtin_interfaces/msg/Time")(sec=int(stamp_ns) // _NS_PER_S,
                                                          nanosec=int(stamp_ns) % _NS_PER_S)
        fields = {"seq": 0} if self.ros1 else {}
        return self._type("std_msgs/msg/Header")(**fields, stamp=stamp, frame_id=frame_id)

    def image(self, pixels: np.ndarray, *, stamp_ns: int, frame_id: str):
        """A ``sensor_msgs/Image``: ``(H, W)`` uint8 as ``mono8``, ``(H, W, 3)`` uint8 RGB as ``rgb8``."""
        pixels = np.ascontiguousarray(pixels, dtype=np.uint8)
        height, width = pixels.shape[:2]
        channels = 1 if pixels.ndim == 2 else pixels.shape[2]
        return self._type("sensor_msgs/msg/Image")(
            header=self.header(stamp_ns, frame_id), height=height, width=width,
            encoding="mono8" if channels == 1 else "rgb8", is_bigendian=0, step=width * channels,
            data=pixels.reshape(-1))

    def compressed_image(self, data: bytes, image_format: str, *, stamp_ns: int, frame_id: str):
        """A ``sensor_msgs/CompressedImage`` holding ``data`` (a PNG or JPEG file), ``format`` ``image_format``."""
        return self._type("sensor_msgs/msg/CompressedImage")(
            header=self.header(stamp_ns, frame_id), format=image_format,
            data=np.frombuffer(data, dtype=np.uint8))

    def _pose(self, rotation: np.ndarray, position: np.ndarray):
        q = quat_xyzw_from_matrix(np.asarray(rotation, dtype=np.float64))
        point = self._type("geometry_msgs/msg/Point")(x=float(position[0]), y=float(position[1]),
                                                      z=float(position[2]))
        quaternion = self._type("geometry_msgs/msg/Quaternion")(x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                                                w=float(q[3]))
        return self._type("geometry_msgs/msg/Pose")(position=point, orientation=quaternion)

    def pose_stamped(self, rotation: np.ndarray, position: np.ndarray, *, stamp_ns: int, frame_id: str):
        """A ``geometry_msgs/PoseStamped``: ``rotation`` (3, 3) and ``position`` (3,) in ``frame_id``."""
        return self._type("geometry_msgs/msg/PoseStamped")(header=self.header(stamp_ns, frame_id),
                                                           pose=self._pose(rotation, position))

    def transform_stamped(self, rotation: np.ndarray, position: np.ndarray, *, stamp_ns: int, parent: str,
                          child: str):
        """A ``geometry_msgs/TransformStamped``: the pose of ``child`` in ``parent``."""
        pose = self._pose(rotation, position)
        translation = self._type("geometry_msgs/msg/Vector3")(x=pose.position.x, y=pose.position.y,
                                                              z=pose.position.z)
        transform = self._type("geometry_msgs/msg/Transform")(translation=translation, rotation=pose.orientation)
        return self._type("geometry_msgs/msg/TransformStamped")(header=self.header(stamp_ns, parent),
                                                                child_frame_id=child, transform=transform)

    def tf_message(self, transforms: list):
        """A ``tf2_msgs/TFMessage`` of ``transforms`` (:meth:`transform_stamped` messages)."""
        return self._type(_TF_TYPE)(transforms=list(transforms))

    def path_message(self, poses: list, *, stamp_ns: int, frame_id: str):
        """A ``nav_msgs/Path`` of ``poses`` (:meth:`pose_stamped` messages)."""
        return self._type("nav_msgs/msg/Path")(header=self.header(stamp_ns, frame_id), poses=list(poses))
