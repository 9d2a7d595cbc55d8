"""How many local Dask workers a command line may start, shared by ``ifmi sweep`` and ``omnisim render``."""

from __future__ import annotations

import argparse
import os

__all__ = ["DEFAULT_LOCAL_WORKERS", "local_worker_count"]

# The default number of local workers, allowed on any machine.
DEFAULT_LOCAL_WORKERS = 2


def _usable_cpus() -> int:
    """CPUs this process may run on (its affinity where the system tells it), at least 1."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def local_worker_count(text: str) -> int:
    """A local cluster's worker count from ``--workers``: 1 to the usable CPUs (at least the default).

    Each worker runs one single-threaded job (an estimate, a frame's render),
    so more workers than CPUs only compete for them, and a count such as
    100000 would start that many processes (each with its own Mitsuba or
    estimator in memory).

    Parameters
    ----------
    text : str
        The option's value.

    Returns
    -------
    int

    Raises
    ------
    argparse.ArgumentTypeError
        Not an integer, below 1, or above the limit.
    """
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    limit = max(DEFAULT_LOCAL_WORKERS, _usable_cpus())
    if value > limit:
        raise argparse.ArgumentTypeError(f"expected at most {limit} workers (the CPUs this process may "
                                         f"use), got {value}")
    return value
