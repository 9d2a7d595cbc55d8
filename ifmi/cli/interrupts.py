"""Ctrl-C on the command lines: one line on stderr and exit status 130, never a traceback.

Both command lines (``ifmi`` and ``omnisim``) install :class:`InterruptFlag`
before they import anything heavy, so an interrupt is known even where
library code catches the KeyboardInterrupt and goes on, or turns it into
another exception (Mitsuba and drjit raise an ImportError or RuntimeError
chained to it).
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["InterruptFlag", "interrupts_recorded", "caused_by_interrupt", "report_interrupt"]

# Exit status of a process ended by Ctrl-C, as shells report it (128 + SIGINT).
INTERRUPTED_STATUS = 130


class InterruptFlag:
    """SIGINT handler that remembers the interrupt, then raises KeyboardInterrupt as Python does."""

    def __init__(self):
        self.seen = False

    def __call__(self, signum, frame):
        self.seen = True
        raise KeyboardInterrupt


@contextmanager
def interrupts_recorded() -> Iterator[InterruptFlag]:
    """Install an :class:`InterruptFlag` as the SIGINT handler for the block, then restore the old one.

    Outside the main thread (where Python cannot set handlers), in a process
    started with SIGINT ignored (``nohup``, a background job of a script), or
    where native code handles SIGINT (``getsignal`` gives None), the flag is
    yielded but never set and SIGINT stays as it was.
    """
    flag = InterruptFlag()
    takes_interrupts = (threading.current_thread() is threading.main_thread()
                        and signal.getsignal(signal.SIGINT) not in (signal.SIG_IGN, None))
    previous = signal.signal(signal.SIGINT, flag) if takes_interrupts else None
    try:
        yield flag
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


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
