"""SIGINT handlers of :mod:`ifmi.runtime.interrupts` (the command lines' own Ctrl-C tests are with each CLI)."""

import signal

import pytest

from ifmi.runtime.interrupts import caused_by_interrupt, interrupts_deferred, interrupts_recorded


def test_interrupt_in_a_deferred_block_is_raised_when_it_is_done(default_sigint):
    before, reached_end = signal.getsignal(signal.SIGINT), False
    with pytest.raises(KeyboardInterrupt):
        with interrupts_deferred():
            signal.raise_signal(signal.SIGINT)
            reached_end = True  # the handler only recorded the signal
    assert reached_end and signal.getsignal(signal.SIGINT) is before


def test_a_process_started_with_sigint_ignored_keeps_ignoring_it():
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with interrupts_recorded() as flag, interrupts_deferred():
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            signal.raise_signal(signal.SIGINT)
        assert not flag.seen and signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


def test_interrupt_is_recognised_through_exception_chains():
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as inner:
            raise RuntimeError("drjit.custom(): error while performing a custom operation") from inner
    except RuntimeError as exc:
        assert caused_by_interrupt(exc)
    assert not caused_by_interrupt(RuntimeError("plain failure"))
