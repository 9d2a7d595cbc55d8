"""``ifmi evaluate``: errors of an estimate against ground truth, saved as files."""

from __future__ import annotations

import json

from ..evaluation import EvaluateOptions, evaluate_files, format_summary_table

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "evaluate",
        help="orientation errors of an estimate against ground truth",
        description="Per-axis roll/pitch/yaw RMSE and mean ± std, geodesic, relative and "
                    "translation-direction errors, failures and time per frame. Results are "
                    "written to --out (default: ESTIMATE.eval/ beside the estimate).",
    )
    p.add_argument("--gt", required=True, metavar="GROUNDTRUTH", help="ground-truth TUM file")
    p.add_argument("--est", required=True, metavar="ESTIMATE", help="estimated TUM file")
    p.add_argument("--out", metavar="DIR", help="evaluation folder to write")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--max-time-difference", type=float, default=1e-3, metavar="T",
                   help="largest timestamp difference for associating poses (default 1e-3)")
    p.set_defaults(func=run)


def run(args) -> int:
    meta = evaluate_files(args.gt, args.est, out_dir=args.out,
                          options=EvaluateOptions(max_time_difference=args.max_time_difference))
    if args.json:
        print(json.dumps(meta, indent=2, sort_keys=True, default=lambda v: None))
    else:
        print(format_summary_table(meta))
        print(f"results written to {meta['path']}")
    return 0
