"""How many processes a local Dask cluster may start (``ifmi sweep``, ``omnisim render``)."""

from __future__ import annotations

import os

__all__ = ["DEFAULT_LOCAL_WORKERS", "max_local_workers"]

# The default number of local workers, allowed on any machine.
DEFAULT_LOCAL_WORKERS = 2


def max_local_workers() -> int:
    """Most workers a local cluster may have: the CPUs this process may run on, at least the default.

    Each worker runs one single-threaded job (an estimate, a frame's render),
    so more workers than CPUs only compete for them, and a count such as
    100000 would start that many processes, each with its own estimator or
    Mitsuba in memory.

    Returns
    -------
    int
        ``max(DEFAULT_LOCAL_WORKERS, usable CPUs)``; the CPUs are the
        process's affinity where the system tells it, else the CPU count.
    """
    try:
        usable = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        usable = os.cpu_count() or 1
    return max(DEFAULT_LOCAL_WORKERS, usable)
