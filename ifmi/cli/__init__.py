"""Command line of ``ifmi``: parsing only; every subcommand calls library code.

Each subcommand lives in its own module of this package and exposes
``add_parser(subparsers)`` (which sets ``func`` on its parser) so that the
entry point stays a thin dispatcher.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from ifmi.errors import ClusterError, InputError, OutputError
from ifmi.runtime.interrupts import caused_by_interrupt, interrupts_recorded, report_interrupt
from ifmi.runtime.parser import OneLineValueErrors
from ifmi.runtime.warning_lines import input_warnings_as_lines

__all__ = ["main"]

# Subcommand modules, in the order ``ifmi --help`` lists them.
_SUBCOMMANDS = ("estimate", "evaluate", "sweep", "report", "convert_calib", "convert_gt", "methods")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineValueErrors(
        prog="ifmi",
        description="Rotation estimation between omni images with the extended iFMI, "
                    "feature baselines, evaluation, sweeps and reports.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _SUBCOMMANDS:
        try:
            module = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"{__name__}.{name}":
                continue
            raise
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``ifmi`` with ``argv``; returns the exit status.

    Exit status: 0 done; 1 an output could not be written
    (:class:`~ifmi.errors.OutputError`) or a Dask cluster was lost
    (:class:`~ifmi.errors.ClusterError`); 2 bad input
    (:class:`~ifmi.errors.InputError`, or a command-line usage error);
    130 interrupted; a subcommand may document more (``estimate``: 3 when
    more than half of the frames failed). Each error is one line on stderr;
    :class:`~ifmi.errors.InputWarning` warnings are printed as one line each.
    """
    with interrupts_recorded() as flag:
        command = "ifmi"  # the subcommand is known once the arguments are parsed
        try:
            args = build_parser().parse_args(argv)  # imports the library
            command = f"ifmi {args.command}"
            status = _run(args, command)
            if flag.seen:  # library code caught the KeyboardInterrupt, or turned it into an error
                raise KeyboardInterrupt
            return status
        except BaseException as exc:
            if flag.seen or caused_by_interrupt(exc):
                return report_interrupt(f"{command}: interrupted")
            raise


def _run(args, command: str) -> int:
    """Run the parsed subcommand; errors of the input or the output become one line and a status."""
    with input_warnings_as_lines(lambda: command):
        try:
            status = int(args.func(args) or 0)
        except InputError as exc:
            print(f"{command}: error: {exc}", file=sys.stderr)
            return 2
        except (OutputError, ClusterError) as exc:
            print(f"{command}: error: {exc}", file=sys.stderr)
            return 1
        except BrokenPipeError:
            # The reader of stdout left (``ifmi evaluate | head``): nothing more to print, and
            # Python's flush at exit must not fail on the closed pipe either.
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 1
    return status


if __name__ == "__main__":
    sys.exit(main())
