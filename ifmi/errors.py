"""Exceptions whose message is a complete one-line report for the user."""

from __future__ import annotations

import json

__all__ = ["InputError", "InputWarning", "CalibrationFitError", "ClusterError", "OutputError", "OptionError",
           "first_line", "one_line",
           "json_excerpt"]


class InputError(ValueError):
    """Bad user input: a file that cannot be read or does not fit its contract.

    The message names the file and the problem in one line; command-line
    entry points print it and exit non-zero without a traceback.
    """

    def __init__(self, path, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class CalibrationFitError(InputError):
    """A camera model that does not suit the method's configuration (e.g. too few pixels).

    Raised where only the model is at hand, naming it generically; entry
    points that read the model from a calibration file re-raise it with that
    file's path (:meth:`for_file`).
    """

    def __init__(self, problem: str, path="camera model") -> None:
        super().__init__(path, problem)

    def for_file(self, path) -> "CalibrationFitError":
        """The same problem, reported against the calibration file ``path``."""
        return CalibrationFitError(self.problem, path)


class OutputError(OSError):
    """A result could not be written: the user's path and the OS reason, in one line.

    Raised by the atomic writers of :mod:`ifmi.io.atomic` in place of the raw
    ``OSError`` (whose message would name a temporary file). Command-line entry
    points print it and exit with status 1; nothing half-written is left.
    """

    def __init__(self, path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"cannot write {path}: {reason}")

    def __str__(self) -> str:
        return f"cannot write {self.path}: {self.reason}"

    @classmethod
    def from_os_error(cls, path, exc: OSError) -> "OutputError":
        """Wrap ``exc`` (raised while writing ``path``) with the user's path."""
        if isinstance(exc, cls):
            return exc
        return cls(path, exc.strerror or str(exc))


class ClusterError(RuntimeError):
    """A Dask cluster lost during a run (its scheduler gone, or a task that kept killing workers).

    The message is one line saying what was lost and how much of the run
    was kept for a rerun of the same command; command-line entry points
    print it and exit with status 1.
    """


class InputWarning(UserWarning):
    """Input that was used in part, with something left out (e.g. files skipped).

    The message is one line naming the file or folder; command-line entry
    points print it as ``ifmi COMMAND: warning: MESSAGE``.
    """


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message, or its class name when the message is empty."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def one_line(exc: BaseException) -> str:
    """``Type: first line of the message``, with `` ...`` when lines are left out."""
    text = str(exc).strip()
    if not text:
        return type(exc).__name__
    first = text.splitlines()[0]
    return f"{type(exc).__name__}: {first}{' ...' if first != text else ''}"


def json_excerpt(value, *, max_chars: int = 40) -> str:
    """``value`` as JSON text for a one-line message, cut to ``max_chars`` characters ending in ``...``.

    Values JSON cannot write are shown by ``str``.
    """
    text = json.dumps(value, default=str)
    return text if len(text) <= max_chars else text[:max_chars - 3] + "..."


class OptionError(ValueError):
    """A configuration value of the wrong type or range, or an unknown key.

    Attributes
    ----------
    key : str
        Dotted key path of the value (``""`` for the whole mapping).
    problem : str
        What is wrong, e.g. ``expected an integer, got float 1.5``.
    """

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        self.problem = problem
        super().__init__(f"{key}: {problem}" if key else problem)
