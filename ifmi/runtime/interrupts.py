"""Ctrl-C: SIGINT handlers that record or defer an interrupt, and the exit it leads to.

Both command lines (``ifmi`` and ``omnisim``) install :class:`InterruptFlag`
before they import anything heavy, so an interrupt is known even where
library code catches the KeyboardInterrupt and goes on, or turns it into
another exception (Mitsuba and drjit raise an ImportError or RuntimeError
chained to it); they end with one line on stderr and exit status 130, never
a traceback. :func:`interrupts_deferred` holds an interrupt back while native
code that cannot take a KeyboardInterrupt runs (Mitsuba's import).

Every handler here leaves SIGINT alone outside the main thread (where Python
cannot set handlers), in a process started with SIGINT ignored (``nohup``, a
background job of a script), and where native code handles SIGINT
(``getsignal`` gives None, so it could not be restored).
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = [
    "INTERRUPTED_STATUS",
    "InterruptFlag",
    "interrupts_recorded",
    "interrupts_deferred",
    "caused_by_interrupt",
    "report_interrupt",
]

# Exit status of a process ended by Ctrl-C, as shells report it (128 + SIGINT).
INTERRUPTED_STATUS = 130


class InterruptFlag:
    """SIGINT handler that remembers the interrupt, then raises KeyboardInterrupt as Python does."""

    def __init__(self):
        self.seen = False

    def __call__(self, signum, frame):
        self.seen = True
        raise KeyboardInterrupt


def _sigint_handler_replaceable() -> bool:
    """True in the main thread when SIGINT is neither ignored nor handled by native code."""
    return (threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) not in (signal.SIG_IGN, None))


@contextmanager
def interrupts_recorded() -> Iterator[InterruptFlag]:
    """Install an :class:`InterruptFlag` as the SIGINT handler for the block, then restore the old one.

    Where SIGINT is left alone (see the module text) the flag is yielded but
    never set.
    """
    flag = InterruptFlag()
    previous = signal.signal(signal.SIGINT, flag) if _sigint_handler_replaceable() else None
    try:
        yield flag
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold SIGINT back for the block and raise it again when the block is done.

    Python runs a SIGINT handler in the main thread at its next bytecode, and
    while drjit builds its modules that bytecode can be inside a C++ callback:
    a KeyboardInterrupt there aborts the process, by ``std::terminate`` at once
    or at exit (16 of 151 interrupts between 0.3 and 1.8 s after a render's
    start; 0 of 227 with this deferral around Mitsuba's import). Blocking the
    signal in this thread alone does not help once numpy's worker threads
    exist, as the kernel hands it to one of them. So the handler is replaced
    by one that only records the interrupt. Where SIGINT is left alone (see
    the module text) the block runs as it is.
    """
    if not _sigint_handler_replaceable():
        yield
        return
    received = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received:
            signal.raise_signal(signal.SIGINT)


def caused_by_interrupt(exc: BaseException) -> bool:
    """True when ``exc`` is, or was raised while handling, a KeyboardInterrupt."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def report_interrupt(message: str) -> int:
    """Print ``message`` (one line) on stderr and return :data:`INTERRUPTED_STATUS`."""
    print(message, file=sys.stderr)
    # CPython marks an interrupt that escaped code run by exec() of a string (dataclasses and
    # namedtuple build their methods so, e.g. while numpy imports) as unhandled, and the
    # interpreter then ends the process by SIGINT instead of this status; the next exec() of
    # a string clears that mark.
    exec("pass")
    return INTERRUPTED_STATUS
