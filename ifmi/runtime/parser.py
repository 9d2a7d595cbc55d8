"""The argument parser of the ``ifmi`` and ``omnisim`` command lines."""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn

__all__ = ["OneLineValueErrors"]

# Exit status of a command-line usage error (argparse's own).
USAGE_STATUS = 2
# How argparse starts the message of an error about one argument's value.
_ARGUMENT_ERROR_START = "argument "


class OneLineValueErrors(argparse.ArgumentParser):
    """An argument parser whose errors about one option's value are one line, without the usage block.

    ``--max-rmse -0.01`` is a value the user typed wrong: the line naming the
    option and what it expects is the whole report, as for every other input
    error. Errors of the command line's shape (a missing required option, an
    unknown argument) keep argparse's usage block, which shows the shape.
    Subcommand parsers made by ``add_subparsers`` inherit the class.
    """

    def error(self, message: str) -> NoReturn:
        if message.startswith(_ARGUMENT_ERROR_START):
            print(f"{self.prog}: error: {message}", file=sys.stderr)
            sys.exit(USAGE_STATUS)
        super().error(message)
