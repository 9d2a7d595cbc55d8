"""``ifmi report``: Markdown + HTML report from evaluation and sweep folders."""

from __future__ import annotations

import shlex
import sys

from ifmi.experiments.report import ReportOptions, build_report

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "report",
        help="Markdown/HTML report of evaluations and sweeps",
        description="Reads evaluation folders (ifmi evaluate) and sweep folders (ifmi sweep), "
                    "or folders containing them, and writes README.md, index.html, report.json "
                    "and figures/ into --out (built beside it and swapped in when complete). "
                    "An existing --out must be an earlier report folder (your other files in it "
                    "are kept) or empty. Estimates are never recomputed.",
    )
    p.add_argument("results", nargs="+", metavar="RESULTS", help="evaluation or sweep folders")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="report folder, e.g. reports/NAME (new, empty or an earlier report)")
    p.add_argument("--title", default=None, help="report title")
    # dest is not "command": that name holds the subcommand (used in error messages).
    p.add_argument("--command", dest="regenerate", default=None,
                   help="command line that regenerates the report (printed in it); "
                        "default: this invocation")
    p.add_argument("--no-motion-flow", action="store_true",
                   help="do not compute the iFMI motion-flow sample of scenes that lack one "
                        "(it needs the dataset's images)")
    p.set_defaults(func=run)


def run(args) -> int:
    command = args.regenerate or "ifmi " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    options = ReportOptions(command=command, motion_flow=not args.no_motion_flow,
                            **({"title": args.title} if args.title else {}))
    path = build_report(args.results, out_dir=args.out, options=options)
    print(f"report written to {path} and {path.with_name('index.html')}")
    return 0
