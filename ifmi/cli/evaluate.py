"""``ifmi evaluate``: errors of an estimate against ground truth, saved as files; a CI gate."""

from __future__ import annotations

import argparse
import json

from ifmi.api import evaluate
from ifmi.errors import InputError
from ifmi.evaluation.trajectory_files import EvaluateOptions, format_summary_table, gate_verdict, summary_of
from ifmi.io.bags import is_bag_path
from ifmi.io.results import side_file_paths

__all__ = ["add_parser", "run"]


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1], got {text!r}") from None
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1], got {text}")
    return value


def _non_negative(kind):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
        if not value >= 0:
            raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text}")
        return value
    return parse


def _time_difference(text: str) -> float:
    """A finite timestamp difference >= 0 (with ``inf`` every pose would be "within" it, yet each
    ground-truth pose still pairs with one estimate pose: the shortfall messages would read wrong)."""
    expected = "expected a finite time difference >= 0 in the timestamps' unit"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{expected}, got {text!r}") from None
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"{expected}, got {text}")
    return value


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "evaluate",
        help="orientation errors of an estimate against ground truth (and a pass/fail gate)",
        description="Per-axis roll/pitch/yaw RMSE and mean ± std, geodesic, relative and "
                    "translation-direction errors, failures and time per frame. Results are "
                    "written to --out (default: ESTIMATE.eval/ beside the estimate) as one set; "
                    "an existing --out must be an earlier evaluation folder or empty. With "
                    "--max-rmse it is a CI gate: one PASS/FAIL line, exit 0 on PASS, 1 on FAIL.",
    )
    p.add_argument("--gt", required=True, metavar="GROUNDTRUTH",
                   help="ground-truth TUM file, or a ROS bag (.bag, .mcap, .db3 or a ROS 2 bag folder)")
    p.add_argument("--gt-topic", metavar="TOPIC",
                   help="the bag's ground-truth topic: PoseStamped, PoseWithCovarianceStamped, "
                        "TransformStamped, Odometry, or a tf topic with --gt-frames (default: the bag's "
                        "only pose topic)")
    p.add_argument("--gt-frames", nargs=2, metavar=("PARENT", "CHILD"),
                   help="with a tf topic (/tf): the pose of CHILD in PARENT, composed along the chain of "
                        "transforms between them")
    p.add_argument("--est", required=True, metavar="ESTIMATE", help="estimated TUM file")
    p.add_argument("--out", metavar="DIR",
                   help="evaluation folder to write (new, empty or an earlier evaluation)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--max-time-difference", type=_time_difference, default=1e-3, metavar="T",
                   help="largest timestamp difference for associating poses (default 1e-3)")
    p.add_argument("--min-matched", type=_fraction, default=0.5, metavar="FRACTION",
                   help="smallest fraction of the ground-truth poses, and of the estimate "
                        "poses, that must be associated (default 0.5); at least 2 poses always")
    g = p.add_argument_group("pass/fail gate")
    g.add_argument("--max-rmse", type=_non_negative(float), metavar="RAD",
                   help="fail (exit 1) when the geodesic RMSE exceeds RAD radians")
    g.add_argument("--max-failed", type=_non_negative(int), metavar="N",
                   help="also fail when more than N frames failed (from the estimate's frames.csv)")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.max_failed is not None and args.max_rmse is None:
        raise InputError("command line", "--max-failed needs --max-rmse")
    if args.max_failed is not None:
        frames_path = side_file_paths(args.est)[0]
        if not frames_path.is_file():
            # Refused before anything is written: no evaluation folder for a gate that cannot run.
            raise InputError(frames_path, "not found: the failed-frame count is unknown; "
                                          "expected the estimate's frames.csv for --max-failed")
    if (args.gt_topic or args.gt_frames) and not is_bag_path(args.gt):
        raise InputError(args.gt, "--gt-topic and --gt-frames are for a ROS bag; this is not one")
    options = EvaluateOptions(max_time_difference=args.max_time_difference, min_matched=args.min_matched)
    # Written to --out, or to ESTIMATE.eval/ beside the estimate when that can be written.
    meta = evaluate(args.gt, args.est, out=args.out or True, options=options, gt_topic=args.gt_topic,
                    gt_frames=None if args.gt_frames is None else tuple(args.gt_frames)).meta
    if args.max_rmse is not None:
        try:
            verdict = gate_verdict(summary_of(meta), max_rmse_rad=args.max_rmse,
                                   max_failed=args.max_failed)
        except ValueError as exc:
            raise InputError(args.est, str(exc)) from None
        if args.json:
            print(json.dumps({**meta, "verdict": verdict.line, "passed": verdict.passed},
                             indent=2, sort_keys=True, default=lambda v: None))
        else:
            print(verdict.line)
        return 0 if verdict.passed else 1
    if args.json:
        print(json.dumps(meta, indent=2, sort_keys=True, default=lambda v: None))
    else:
        print(format_summary_table(meta))
        if meta["path"] is not None:
            print(f"results written to {meta['path']}")
    return 0
