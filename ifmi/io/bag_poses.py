"""Ground truth from a ROS bag: the poses of one topic, or a frame's pose from ``/tf``, as a trajectory.

Motion capture and INS ground truth arrive in bags as pose, odometry or tf
topics. :func:`read_bag_trajectory` reads them with the ``rosbags`` library
(bags as :func:`ifmi.io.bags.open_bag` opens them):

* ``geometry_msgs/PoseStamped``, ``PoseWithCovarianceStamped``,
  ``TransformStamped`` and ``nav_msgs/Odometry``: one pose per message;
* ``tf2_msgs/TFMessage`` (``/tf``; also ROS 1's older ``tf/tfMessage``): the pose of a ``child`` frame in a
  ``parent`` frame, composed along the tree's chain of transforms when they
  are several (``world -> base -> camera``). The chain is evaluated at the
  stamps of its moving transform nearest the child (the tracked body's own
  measurements); every other moving transform is interpolated there (positions linearly, rotations along the
  shortest arc), and a time outside one's span is left out. Transforms of
  ``/tf_static`` are constant.

A pose's time is its ``header.stamp`` in seconds, or the bag's receive time
where the stamp is zero. Poses are returned as the bag holds them (in their
own world frame); the evaluation re-bases both trajectories to their first
associated frame (:func:`ifmi.evaluation.metrics.trajectory_errors`).
"""

from __future__ import annotations

import os
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ifmi.errors import InputError
from ifmi.geometry.rotations import matrix_from_quat_xyzw
from ifmi.geometry.trajectory import Trajectory
from ifmi.io.bags import bag_read_errors, chosen_topic, open_bag, stamp_seconds

__all__ = ["read_bag_trajectory", "POSE_TYPES", "TF_TYPES"]

#: Messages of a tf topic: tf2's, and the older tf's of early ROS 1 recordings (the same fields).
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
#: Message types of a pose topic, and where each keeps its pose.
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped",
              "geometry_msgs/msg/TransformStamped", "nav_msgs/msg/Odometry") + TF_TYPES
# The topic of transforms that do not change.
_STATIC_TF_TOPIC = "/tf_static"
# Nanoseconds per second.
_NS_PER_S = 10 ** 9


def _pose_of(message, msgtype: str) -> tuple[np.ndarray, np.ndarray]:
    """``(position (3,), quaternion x y z w (4,))`` of a pose message."""
    if msgtype == "geometry_msgs/msg/TransformStamped":
        t, q = message.transform.translation, message.transform.rotation
    else:
        pose = message.pose if msgtype == "geometry_msgs/msg/PoseStamped" else message.pose.pose
        t, q = pose.position, pose.orientation
    return np.array([t.x, t.y, t.z], dtype=np.float64), np.array([q.x, q.y, q.z, q.w], dtype=np.float64)


def _messages(path: Path, reader, topics: list[str]):
    """``(topic, receive_ns, message)`` of ``topics`` in the bag's order.

    Raises
    ------
    InputError
        The bag breaks off or a message cannot be decoded.
    """
    connections = [c for c in reader.connections if c.topic in topics]
    try:
        for connection, receive_ns, data in reader.messages(connections=connections):
            yield connection.topic, receive_ns, reader.deserialize(data, connection.msgtype)
    except bag_read_errors() as exc:
        raise InputError(path, f"cannot read {', '.join(topics)} ({str(exc).strip() or type(exc).__name__})") from None


def _trajectory(path: Path, topic: str, stamps: list, positions: list, quaternions: list) -> Trajectory:
    """The poses sorted by time; refuses no poses, zero quaternions and repeated stamps."""
    if not stamps:
        raise InputError(path, f"topic {topic} has no poses")
    quaternions = np.asarray(quaternions)
    norms = np.linalg.norm(quaternions, axis=1)
    if np.any(~np.isfinite(norms)) or np.any(norms < 1e-9) or not np.all(np.isfinite(positions)):
        k = int(np.flatnonzero(~(np.isfinite(norms) & (norms >= 1e-9)) | ~np.isfinite(positions).all(1))[0])
        raise InputError(path, f"{topic}: pose {k} at {stamps[k]:.6f} s has a zero or non-finite quaternion "
                               f"or position")
    order = np.argsort(stamps, kind="stable")
    times = np.asarray(stamps, dtype=np.float64)[order]
    return Trajectory(timestamps=times, positions=np.asarray(positions, dtype=np.float64)[order],
                      rotations=matrix_from_quat_xyzw(quaternions[order] / norms[order, None]))


def read_bag_trajectory(path: str | os.PathLike, *, topic: str | None = None,
                        frames: tuple[str, str] | None = None,
                        options: tuple[str, str] = ("--gt-topic", "--gt-frames")) -> Trajectory:
    """The ground-truth poses of a bag's topic, sorted by time.

    Parameters
    ----------
    path : path-like
        A ``.bag``, ``.mcap`` or ``.db3`` file or a ROS 2 bag folder.
    topic : str, optional, keyword-only
        A topic of :data:`POSE_TYPES`; default the bag's only one. For a
        ``tf2_msgs/TFMessage`` topic ``frames`` is needed.
    frames : (str, str), optional, keyword-only
        ``(parent, child)``: read the pose of ``child`` in ``parent`` from
        the transforms of ``topic`` (and of ``/tf_static``).
    options : (str, str), keyword-only
        The command-line options that give ``topic`` and ``frames``, named in errors.

    Returns
    -------
    Trajectory
        Timestamps in seconds; positions in the bag's unit (metres in ROS);
        rotations map the pose's frame into its parent.

    Raises
    ------
    InputError
        The bag cannot be read, the topic is missing or of another type
        (the message lists the bag's pose topics), ``frames`` is missing for
        a tf topic or given for another one, the frames are not connected
        by the bag's transforms, or there are no poses.
    """
    path = Path(path)
    with open_bag(path) as reader:
        topic = chosen_topic(path, reader, topic, POSE_TYPES, what="pose", option=options[0])
        msgtype = reader.topics[topic].msgtype
        if msgtype in TF_TYPES:
            if frames is None:
                raise InputError(path, f"topic {topic} holds transforms between frames; name the pose wanted "
                                       f"with {options[1]} PARENT CHILD")
            return _tf_trajectory(path, reader, topic, frames)
        if frames is not None:
            raise InputError(path, f"{options[1]} is for a tf topic ({TF_TYPES[0]}); {topic} holds {msgtype}")
        stamps, positions, quaternions = [], [], []
        for _, receive_ns, message in _messages(path, reader, [topic]):
            position, quaternion = _pose_of(message, msgtype)
            stamps.append(stamp_seconds(message, receive_ns))
            positions.append(position)
            quaternions.append(quaternion)
    return _trajectory(path, topic, stamps, positions, quaternions)


def _tf_edges(path: Path, reader, topic: str) -> tuple[dict, dict]:
    """``(moving, static)``: ``{(parent, child): [(seconds, position, quaternion), ...]}`` of the transforms."""
    moving, static = defaultdict(list), {}
    topics = [topic] + ([_STATIC_TF_TOPIC] if _STATIC_TF_TOPIC in reader.topics and topic != _STATIC_TF_TOPIC
                        else [])
    for name, receive_ns, message in _messages(path, reader, topics):
        for transform in message.transforms:
            edge = (transform.header.frame_id.lstrip("/"), transform.child_frame_id.lstrip("/"))
            sample = (stamp_seconds(transform, receive_ns),) + _pose_of(transform, "geometry_msgs/msg/TransformStamped")
            if name == _STATIC_TF_TOPIC:
                static[edge] = [sample]
            else:
                moving[edge].append(sample)
    return dict(moving), static


def _chain(path: Path, parents: dict, parent: str, child: str) -> list[tuple[tuple[str, str], bool]]:
    """The edges from ``parent`` down to ``child``: ``[((p, c), inverted), ...]`` in composition order.

    Raises
    ------
    InputError
        A frame is not in the tree, or the two are not connected.
    """
    def up(frame: str) -> list[str]:
        seen = [frame]
        while seen[-1] in parents and parents[seen[-1]] not in seen:
            seen.append(parents[seen[-1]])
        return seen

    known = set(parents) | set(parents.values())
    for frame in (parent, child):
        if frame not in known:
            raise InputError(path, f"frame {frame} is not in the transforms (frames: {', '.join(sorted(known))})")
    from_parent, from_child = up(parent), up(child)
    common = next((f for f in from_child if f in from_parent), None)
    if common is None:
        raise InputError(path, f"frames {parent} and {child} are not connected by the transforms")
    rising = [((parents[f], f), True) for f in from_parent[:from_parent.index(common)]]
    falling = [((parents[f], f), False) for f in reversed(from_child[:from_child.index(common)])]
    return rising + falling


def _edge_at(samples: list, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(inside (N,) bool, rotations (N, 3, 3), positions (N, 3))`` of an edge at ``times``."""
    samples = sorted(samples, key=lambda s: s[0])
    stamps = np.array([s[0] for s in samples])
    positions = np.array([s[1] for s in samples])
    rotations = Rotation.from_quat(np.array([s[2] for s in samples]))
    if len(samples) == 1:
        n = len(times)
        return np.ones(n, bool), np.repeat(rotations.as_matrix(), n, 0), np.repeat(positions, n, 0)
    inside = (times >= stamps[0]) & (times <= stamps[-1])
    clipped = np.clip(times, stamps[0], stamps[-1])
    turned = Slerp(stamps, rotations)(clipped).as_matrix()
    moved = np.stack([np.interp(clipped, stamps, positions[:, i]) for i in range(3)], axis=1)
    return inside, turned, moved


def _tf_trajectory(path: Path, reader, topic: str, frames: tuple[str, str]) -> Trajectory:
    """The pose of ``frames[1]`` in ``frames[0]`` composed from the transforms of ``topic``."""
    parent, child = (f.lstrip("/") for f in frames)
    moving, static = _tf_edges(path, reader, topic)
    edges = {**{e: s for e, s in moving.items()}, **static}
    chain = _chain(path, {c: p for p, c in edges}, parent, child)
    timed = [edge for edge, _ in chain if edge in moving and edge not in static]
    if not timed:
        raise InputError(path, f"the transforms from {parent} to {child} never change (all in {_STATIC_TF_TOPIC})")
    clock = timed[-1]  # the moving transform nearest the child: its own measurement times
    times = np.unique([s[0] for s in moving[clock]])
    keep = np.ones(len(times), bool)
    rotations, positions = np.repeat(np.eye(3)[None], len(times), 0), np.zeros((len(times), 3))
    for edge, inverted in chain:
        inside, turned, moved = _edge_at(edges[edge], times)
        keep &= inside
        if inverted:  # the pose of the edge's parent in its child
            turned = np.transpose(turned, (0, 2, 1))
            moved = -np.einsum("nij,nj->ni", turned, moved)
        positions = positions + np.einsum("nij,nj->ni", rotations, moved)
        rotations = rotations @ turned
    if not keep.any():
        raise InputError(path, f"the transforms from {parent} to {child} never overlap in time")
    return Trajectory(timestamps=times[keep], positions=positions[keep], rotations=rotations[keep])
