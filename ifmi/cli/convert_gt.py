"""``ifmi convert-gt BAG --topic T --out gt.txt``: a bag's ground-truth topic as a TUM file."""

from __future__ import annotations

import os
from pathlib import Path

from ifmi.errors import OutputError
from ifmi.io.atomic import path_within
from ifmi.io.bag_poses import read_bag_trajectory
from ifmi.io.tum import write_tum

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "convert-gt",
        help="write a ROS bag's pose, odometry or tf topic as a TUM ground-truth file",
        description="Read the poses of a ROS bag's topic (PoseStamped, PoseWithCovarianceStamped, "
                    "TransformStamped, Odometry, or a tf topic with --frames) and write them as a TUM "
                    "file: timestamps in seconds (header.stamp, or the receive time where it is zero), "
                    "poses in the bag's own frame, sorted by time.",
    )
    p.add_argument("bag", metavar="BAG", help=".bag, .mcap or .db3 file, or a ROS 2 bag folder")
    p.add_argument("--topic", metavar="TOPIC", help="the pose topic (default: the bag's only pose topic)")
    p.add_argument("--frames", nargs=2, metavar=("PARENT", "CHILD"),
                   help="with a tf topic (/tf): the pose of CHILD in PARENT, composed along the chain of "
                        "transforms between them")
    p.add_argument("--out", required=True, metavar="TUM", help="TUM file to write")
    p.add_argument("--force", action="store_true", help="replace an existing --out")
    p.set_defaults(func=run)


def run(args) -> int:
    out, bag = Path(args.out), Path(args.bag)
    if path_within(out, bag):
        raise OutputError(out, f"is the bag {bag} or lies in it; choose another output path")
    if os.path.lexists(out) and not args.force:
        raise OutputError(out, "exists already; --force replaces it")
    trajectory = read_bag_trajectory(bag, topic=args.topic,
                                     frames=None if args.frames is None else tuple(args.frames),
                                     options=("--topic", "--frames"))
    write_tum(out, trajectory, header=f"ground truth of {bag.name}"
                                      f"{'' if args.topic is None else ' ' + args.topic}"
                                      f"{'' if args.frames is None else ': ' + ' in '.join(args.frames[::-1])}")
    print(f"{out}: {len(trajectory)} poses from {bag}")
    return 0
