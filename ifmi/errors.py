"""Exceptions whose message is a complete one-line report for the user."""

from __future__ import annotations

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad user input: a file that cannot be read or does not fit its contract.

    The message names the file and the problem in one line; command-line
    entry points print it and exit non-zero without a traceback.
    """

    def __init__(self, path, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")
