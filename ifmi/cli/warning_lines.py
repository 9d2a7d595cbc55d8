"""One-line display of input warnings, shared by the ``ifmi`` and ``omnisim`` command lines.

Python's default display prints the source file and line that raised a
warning; for a user's input problem (a skipped file, a fallback) only the
message matters, so :class:`~ifmi.errors.InputWarning` is printed as
``PROGRAM COMMAND: warning: MESSAGE`` on standard error, once per call.
Other warnings keep Python's default display.
"""

from __future__ import annotations

import sys
import warnings
from contextlib import contextmanager
from typing import Callable, Iterator

from ..errors import InputWarning

__all__ = ["input_warnings_as_lines"]


@contextmanager
def input_warnings_as_lines(prefix: Callable[[], str]) -> Iterator[None]:
    """Print every :class:`~ifmi.errors.InputWarning` raised inside as one line.

    Parameters
    ----------
    prefix : callable () -> str
        Returns the line's prefix, e.g. ``"omnisim degrade"``; called when a
        warning is shown, so it may name a command parsed after entry.
    """
    with warnings.catch_warnings():
        default_show = warnings.showwarning

        def show_warning(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, InputWarning):
                print(f"{prefix()}: warning: {message}", file=sys.stderr)
            else:
                default_show(message, category, filename, lineno, file, line)

        warnings.showwarning = show_warning
        warnings.simplefilter("always", InputWarning)
        yield
