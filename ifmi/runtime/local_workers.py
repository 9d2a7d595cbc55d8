"""Dask clusters of ``ifmi sweep`` and ``omnisim render``: how many local processes, and connecting to a scheduler."""

from __future__ import annotations

import logging
import os

from ifmi.errors import InputError, OutputError, first_line

__all__ = ["DEFAULT_CONNECT_TIMEOUT_S", "DEFAULT_LOCAL_WORKERS", "cluster_loss", "connect_timeout_argument",
           "max_local_workers", "quiet_dask_logs", "scheduler_client"]

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


# Seconds a Dask scheduler has to accept a connection and answer (``--connect-timeout``).
DEFAULT_CONNECT_TIMEOUT_S = 10.0


def connect_timeout_argument(text: str) -> float:
    """``--connect-timeout SECONDS``: a finite number of seconds > 0.

    Raises
    ------
    argparse.ArgumentTypeError
        The text is not such a number.
    """
    import argparse
    import math

    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected seconds > 0, got {text!r}")
    return value


def scheduler_client(address: str, *, option: str = "--scheduler",
                     connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S):
    """A ``distributed.Client`` of the Dask scheduler at ``address``, once it has answered in Dask's protocol.

    Dask's own client waits for the first message of a server without a
    time limit, so a port that accepts and never answers would hang it, and
    a port of another protocol (a dashboard's HTTP) makes it read a frame
    size from foreign bytes. The scheduler is asked for its identity first,
    within ``connect_timeout_s`` in all.

    Parameters
    ----------
    address : str
        Scheduler address, e.g. ``tcp://HOST:8786``.
    option : str, keyword-only
        The option that gave ``address``, to name in errors.
    connect_timeout_s : float, keyword-only
        Seconds for connecting and the scheduler's answer, > 0.

    Returns
    -------
    distributed.Client

    Raises
    ------
    InputError
        Named ``option``: an address Dask cannot parse, nothing listening, no
        answer within ``connect_timeout_s``, or an answer that is not a Dask
        scheduler's.
    """
    from distributed import Client

    problem = _scheduler_problem(address, connect_timeout_s)
    if problem is None:
        try:
            return Client(address, timeout=f"{connect_timeout_s}s")
        except Exception as exc:  # noqa: BLE001  (the scheduler went away between the two connections)
            problem = first_line(exc)
    raise InputError(option, f"cannot connect to a Dask scheduler at {address!r}: {problem}")


def _scheduler_problem(address: str, timeout_s: float) -> str | None:
    """Why ``address`` is not a Dask scheduler that answers within ``timeout_s`` s, or None when it is."""
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=1) as pool:  # a thread of its own: the caller may run an event loop
        try:
            identity = pool.submit(asyncio.run, _scheduler_identity(address, timeout_s)).result()
        except asyncio.TimeoutError:
            return (f"no Dask answer within {timeout_s:g} s (nothing listening, a server of another protocol "
                    f"such as the dashboard's HTTP, or a stuck scheduler; --connect-timeout SECONDS changes the "
                    f"wait)")
        except (ValueError, OSError) as exc:
            return first_line(exc)
        except Exception as exc:  # noqa: BLE001  (bytes of another protocol fail in many ways)
            return f"the server there does not speak Dask's protocol ({first_line(exc)[:80]})"
    if not (isinstance(identity, dict) and identity.get("type") == "Scheduler"):
        return "the server there answers in Dask's protocol but is not a scheduler"
    return None


async def _scheduler_identity(address: str, timeout_s: float):
    """The identity message of the Dask server at ``address``, within ``timeout_s`` s in all."""
    import asyncio

    from distributed.comm import connect

    async def ask():
        comm = await connect(address, timeout=timeout_s)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    return await asyncio.wait_for(ask(), timeout_s)


def quiet_dask_logs() -> None:
    """Drop Dask's log records below CRITICAL in this process from now on (for command lines).

    A lost scheduler or worker is reported by the command in one line
    (:func:`cluster_loss`), and a scheduler that cannot be reached by
    :func:`scheduler_client`; Dask would log the same faults as tracebacks,
    some of them from its event-loop thread after the client is closed.
    """
    import distributed  # noqa: F401  (its logging configuration first, then the levels)
    import distributed.client  # noqa: F401

    # Dask gives some of its loggers (distributed.client) a level and handler of their own.
    names = ["distributed"] + [name for name in logging.root.manager.loggerDict if name.startswith("distributed.")]
    for name in names:
        logging.getLogger(name).setLevel(logging.CRITICAL)


def cluster_loss(exc: BaseException) -> str | None:
    """What a Dask cluster lost, when ``exc`` (raised by a future's result) says it lost something; else None.

    Parameters
    ----------
    exc : BaseException
        Raised by ``future.result()``.

    Returns
    -------
    str or None
        ``"the scheduler went away"`` for cancelled futures (Dask cancels
        them all when the client loses its scheduler) and a closed
        connection, the killed-worker
        reason when a job killed ``distributed.scheduler.allowed-failures``
        workers in turn, the first line of a connection error; None for
        anything else (e.g. an error of the job itself).
    """
    from concurrent.futures import CancelledError

    from distributed.comm.core import CommClosedError
    from distributed.scheduler import KilledWorker

    if isinstance(exc, (CancelledError, CommClosedError)):
        return "the scheduler went away"
    if isinstance(exc, KilledWorker):
        return "a job killed every worker that ran it"
    if isinstance(exc, OSError) and not isinstance(exc, OutputError):
        return first_line(exc)[:120]
    return None
