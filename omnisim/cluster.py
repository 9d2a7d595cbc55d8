"""Render frames in parallel processes on a Dask cluster (a local one, or one at a scheduler address).

Workers only compute: each returns a frame's file bytes to the calling
process, which writes them with the same atomic, resumable writer as a
single-process render, so the folder and ``meta.json`` have one writer and
the bytes do not depend on where a frame was rendered.

Mitsuba's Python plugins are registered per process, so a worker plugin
(:class:`OmnisimWorkerPlugin`) imports Mitsuba with the right LLVM and
registers the omni sensor in every worker when it starts (and in workers
that join later). The plugin also keeps the worker's loaded scene, so a
scene is loaded once per worker, not once per frame.
"""

from __future__ import annotations

from contextlib import contextmanager

from distributed import WorkerPlugin

from ifmi.errors import ClusterError
from ifmi.runtime.local_workers import DEFAULT_CONNECT_TIMEOUT_S, cluster_loss, scheduler_client

__all__ = ["OmnisimWorkerPlugin", "cluster_client", "map_on_client", "map_on_cluster"]

PLUGIN_NAME = "omnisim"


class OmnisimWorkerPlugin(WorkerPlugin):
    """Registers the omni sensor in a worker and keeps that worker's per-plan state.

    Parameters
    ----------
    variant : str
        Mitsuba variant the workers use (the calling process's).
    threads : int, optional
        Render threads per worker (default: Dr.Jit's, all cores).
    """

    name = PLUGIN_NAME

    def __init__(self, variant: str, threads: int | None = None):
        self.variant = variant
        self.threads = threads
        self.states = {}

    def setup(self, worker) -> None:
        from omnisim.llvm import import_mitsuba
        from omnisim.sensor import register_omni_sensor

        register_omni_sensor(import_mitsuba(self.variant))
        if self.threads:
            import drjit as dr

            dr.set_thread_count(int(self.threads))

    def state(self, key: str, factory, plan):
        """The state (e.g. a loaded scene) of ``plan``, built once per worker by ``factory(plan)``."""
        if key not in self.states:
            self.states.clear()  # one dataset at a time: free the previous scene
            self.states[key] = factory(plan)
        return self.states[key]


def _run_on_worker(factory, run, plan, key: str, job):
    from distributed import get_worker

    plugin = get_worker().plugins[PLUGIN_NAME]
    return run(plugin.state(key, factory, plan), job)


@contextmanager
def cluster_client(*, variant: str, workers: int | None = None, scheduler: str | None = None,
                   connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S):
    """A Dask client whose workers have the omnisim plugin; closed (with its local cluster) on exit.

    Parameters
    ----------
    variant : str, keyword-only
        Mitsuba variant for the workers.
    workers : int, optional, keyword-only
        Start a local cluster of this many worker processes, which share the
        machine's cores (each renders with ``cores // workers`` threads, at least 1).
    scheduler : str, optional, keyword-only
        Address of an existing scheduler (used instead of ``workers``).
    connect_timeout_s : float, keyword-only
        Seconds ``scheduler`` has to accept the connection and answer, > 0.

    Yields
    ------
    distributed.Client

    Raises
    ------
    InputError
        Named ``--scheduler``: see :func:`ifmi.runtime.local_workers.scheduler_client`.
    """
    import os

    from distributed import Client, LocalCluster

    threads = None
    if scheduler:
        cluster, client = None, scheduler_client(scheduler, connect_timeout_s=connect_timeout_s)
    else:
        threads = max(1, (os.cpu_count() or 1) // int(workers))
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    try:
        client.register_plugin(OmnisimWorkerPlugin(variant, threads))
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def map_on_client(client, factory, run, plan, jobs: list, *, key: str):
    """Run ``run(factory(plan), job)`` for every job on the workers of ``client``; yield results as they finish.

    Parameters
    ----------
    client : distributed.Client
        From :func:`cluster_client` (its workers have the omnisim plugin).
    factory : callable
        ``factory(plan)`` builds a worker's state once (picklable by reference).
    run : callable
        ``run(state, job)`` computes one job's result (picklable by reference).
    plan : object
        Shared input, sent to each worker once.
    jobs : list
        Job descriptions.
    key : str, keyword-only
        Identifies ``plan``; a worker rebuilds its state when the key changes.

    Yields
    ------
    object
        The results, in completion order.

    Raises
    ------
    ClusterError
        The scheduler was lost (its futures cancelled) or a job kept killing
        its workers (Dask retries a job whose worker died, up to its
        ``distributed.scheduler.allowed-failures``).
    """
    from distributed import as_completed

    [shared] = client.scatter([plan], broadcast=True)
    futures = [client.submit(_run_on_worker, factory, run, shared, key, job, pure=False) for job in jobs]
    done = 0
    try:
        for future in as_completed(futures):
            result = future.result()
            done += 1
            yield result
    except Exception as exc:
        lost = cluster_loss(exc)
        if lost is None:
            raise
        raise ClusterError(f"lost the Dask cluster at {client.scheduler.address} after {done} of {len(futures)} "
                           f"jobs ({lost}); the frames written are kept: rerun the same command to render "
                           f"the rest") from None


def map_on_cluster(factory, run, plan, jobs: list, *, key: str, variant: str,
                   workers: int | None = None, scheduler: str | None = None,
                   connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S):
    """:func:`map_on_client` on a client of :func:`cluster_client`, opened for these jobs alone.

    Parameters
    ----------
    factory, run, plan, jobs, key
        See :func:`map_on_client`.
    variant, workers, scheduler, connect_timeout_s
        See :func:`cluster_client`.

    Yields
    ------
    object
        The results, in completion order.
    """
    with cluster_client(variant=variant, workers=workers, scheduler=scheduler,
                        connect_timeout_s=connect_timeout_s) as client:
        yield from map_on_client(client, factory, run, plan, jobs, key=key)
