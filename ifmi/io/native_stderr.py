"""The C-level standard error, captured around calls into native decoders.

libjpeg, libpng and FFmpeg print their warnings and errors to file
descriptor 2, out of Python's reach. :func:`call_with_captured_stderr`
points descriptor 2 at a temporary file for one call and hands back what
was written, so that a decoder's complaint becomes a one-line error,
warning or per-frame flag instead of raw lines on the terminal. One
capture runs at a time in the process (one lock for every caller): two
interleaved redirections would leave descriptor 2 pointing at a closed
file.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading
from typing import Callable, TypeVar

__all__ = ["call_with_captured_stderr"]

# File descriptor of the C-level standard error.
_STDERR_FD = 2
# One redirection of the standard error at a time in this process.
_LOCK = threading.Lock()

_T = TypeVar("_T")


def call_with_captured_stderr(call: Callable[[], _T]) -> tuple[_T, bytes]:
    """``call()``, and the bytes written to the C-level standard error meanwhile (kept, not shown).

    What Python wrote to ``sys.stderr`` before is flushed first, so it goes
    where it was headed. Without a standard error or a temporary file the
    call runs uncaptured and nothing is returned for it.

    Returns
    -------
    result
        What ``call`` returned.
    written : bytes
        Everything written to descriptor 2 during the call, by any thread.
    """
    with _LOCK, contextlib.ExitStack() as stack:
        try:
            capture = stack.enter_context(tempfile.TemporaryFile())
            saved = os.dup(_STDERR_FD)
        except OSError:  # no temporary file or no standard error: run uncaptured
            return call(), b""
        try:
            with contextlib.suppress(AttributeError, ValueError, OSError):  # no or a closed sys.stderr
                sys.stderr.flush()
            os.dup2(capture.fileno(), _STDERR_FD)
            try:
                result = call()
            finally:
                os.dup2(saved, _STDERR_FD)
        finally:
            os.close(saved)
        capture.seek(0)
        return result, capture.read()
