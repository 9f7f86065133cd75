"""The Dask side of batches and sweeps (ADR 0070): the cluster, the batch on it, ordered maps.

* :func:`connect` gives a :class:`distributed.Client`: on a new local cluster of worker
  *processes* with one thread and one BLAS thread each (numpy/scipy code holds the GIL
  for much of a fit, and a threaded BLAS per process would oversubscribe the cores), or on
  an existing scheduler by address (``tcp://host:8786``) or scheduler file (what
  ``dask scheduler --scheduler-file`` and dask-jobqueue set-ups write).
* :func:`run_on_cluster` submits one :func:`instrument.batch.task.run_task` per run and
  collects the outcomes as they finish. A task catches its run's own problems; what is left
  is a worker process that died under it (killed, crashed, out of memory): Dask gives the
  task to another worker up to ``retries`` times, then it is reported as failed. A task
  that was given to another worker says so (``Outcome.redone``: the scheduler's count of
  the workers that died holding it), and ``scatterlab batch`` prints one line for it.
* :func:`cluster_map` is an ordered map for sweeps: the same function on many inputs, the
  results in input order, equal to a loop here because every input carries its own seed.

This module is the only one that imports Dask; it is imported when a batch or a sweep
starts, never at start-up.
"""

from __future__ import annotations

import contextlib
import logging
import os
import uuid
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import dask
from distributed import Client, LocalCluster, as_completed
from distributed.scheduler import KilledWorker

from instrument.batch.task import Outcome, run_task

__all__ = ["BLAS_ENV", "DEFAULT_RETRIES", "cluster_map", "connect", "describe",
           "run_on_cluster", "worker_notes"]

#: One BLAS/OpenMP thread per worker process.
BLAS_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
#: How many times a task whose worker died is given to another worker.
DEFAULT_RETRIES = 3


@contextlib.contextmanager
def connect(scheduler: str | None = None, workers: int | None = None, *,
            retries: int = DEFAULT_RETRIES, dashboard: bool = True,
            timeout_s: float = 60.0) -> Iterator[Client]:
    """A client on an existing scheduler, or on a new local cluster of ``workers``
    processes (default: one per core), closed with the block.

    ``scheduler`` is an address (``tcp://host:8786``) or the path of a scheduler file.
    ``retries`` only applies to the local cluster (an existing scheduler has its own
    ``distributed.scheduler.allowed-failures``).

    Raises
    ------
    OSError
        The scheduler cannot be reached within ``timeout_s`` (the message names it).
    """
    if scheduler is not None:
        try:
            if Path(scheduler).is_file():
                client = Client(scheduler_file=scheduler, timeout=timeout_s)
            else:
                client = Client(scheduler, timeout=timeout_s)
        except (OSError, TimeoutError) as err:
            raise OSError(f"cannot reach the Dask scheduler {scheduler} within "
                          f"{timeout_s:g} s: {err}") from err
        try:
            yield client
        finally:
            client.close()
        return
    n = max(1, workers if workers is not None else (os.cpu_count() or 1))
    # In the environment before the worker processes are spawned, so numpy reads them when
    # it first loads its BLAS there; the nanny restarts a killed worker the same way.
    os.environ.update(BLAS_ENV)
    config = {"distributed.scheduler.allowed-failures": int(retries),
              "distributed.nanny.pre-spawn-environ": {
                  **dask.config.get("distributed.nanny.pre-spawn-environ", {}), **BLAS_ENV},
              # The statistical profiler samples the task thread's stack every 10 ms and
              # takes the GIL to do it: measurable on analyses that are mostly Python-level
              # loops (BENCHMARKS.md batch). The dashboard loses its profile page only.
              "distributed.worker.profile.enabled": False}
    with dask.config.set(config):
        # Without the dashboard the scheduler still serves a small HTTP endpoint (health,
        # metrics): on a free port, so that it never competes for 8787.
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=":8787" if dashboard else ":0",
                               scheduler_kwargs={"dashboard": bool(dashboard)},
                               silence_logs=logging.ERROR, env=dict(BLAS_ENV))
    try:
        client = Client(cluster, timeout=timeout_s)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def describe(client: Client) -> str:
    """"N workers, M threads at ADDRESS" for the console."""
    info = client.scheduler_info()
    workers = info.get("workers", {})
    threads = sum(int(w.get("nthreads", 0)) for w in workers.values())
    return f"{len(workers)} worker(s), {threads} thread(s), scheduler {info.get('address')}"


def _blas_env() -> dict[str, str | None]:
    return {k: os.environ.get(k) for k in BLAS_ENV}


def worker_notes(client: Client) -> list[str]:
    """Warnings about the workers: BLAS threads other than one (an existing cluster set up
    without them oversubscribes its cores)."""
    notes = []
    for addr, env in client.run(_blas_env).items():
        bad = {k: v for k, v in env.items() if v != "1"}
        if bad:
            notes.append(f"worker {addr}: {', '.join(f'{k}={v}' for k, v in bad.items())} "
                         "(set them to 1 in the workers' environment: one BLAS thread per "
                         "worker process)")
    return notes


def run_on_cluster(client: Client, analysis: str, runs: Sequence[str | Path],
                   options: Mapping[str, Any], *, report: bool = True, force: bool = False,
                   on_outcome: Callable[[Outcome], None] | None = None) -> list[Outcome]:
    """Every run analysed by one task on the cluster; outcomes in the order of ``runs``.

    ``on_outcome`` is called here (the client's thread) as each task ends, in the order
    they end.
    """
    futures = []
    batch = uuid.uuid4().hex[:8]
    for i, run in enumerate(runs):
        # a key of this batch's own (a rerun is new work even with equal arguments: the
        # file may have changed) that names the run on the dashboard
        futures.append(client.submit(run_task, analysis, str(run), dict(options),
                                     report=report, force=force, pure=False,
                                     key=f"{analysis}-{batch}-{i:05d}-{Path(run).name}"))
    where = {f.key: i for i, f in enumerate(futures)}
    out: list[Outcome | None] = [None] * len(futures)
    for fut in as_completed(futures):
        i = where[fut.key]
        run = str(runs[i])
        try:
            o = fut.result()
            deaths = client.run_on_scheduler(_worker_deaths, key=fut.key)
            if deaths:
                o = replace(o, redone=int(deaths))
        except KilledWorker as err:
            o = Outcome(run, analysis, "failed",
                        cause=f"the worker process analysing it died each time it was tried "
                        f"(killed, crashed or out of memory; {err})")
        except Exception as err:  # e.g. cancelled when the scheduler went away
            o = Outcome(run, analysis, "failed", cause=f"{type(err).__name__}: {err}")
        out[i] = o
        fut.release()
        if on_outcome is not None:
            on_outcome(o)
    return [o for o in out if o is not None]


def _worker_deaths(key: str, dask_scheduler: Any = None) -> int:
    """On the scheduler: how many worker processes died while they held task ``key``
    (Dask's count of them, which it gives the task to another worker after each)."""
    ts = dask_scheduler.tasks.get(key) if dask_scheduler is not None else None
    return int(getattr(ts, "suspicious", 0) or 0)


def cluster_map(client: Client, fn: Callable[..., Any], items: Iterable[Any],
                **shared: Any) -> list[Any]:
    """``[fn(item, **shared) for item in items]`` on the cluster, in input order.

    Each ``shared`` value is sent to every worker once (not once per item). An exception
    in any call is raised here, as in the loop.
    """
    sent = {k: client.scatter([v], broadcast=True, hash=False)[0] for k, v in shared.items()}
    futures = client.map(fn, list(items), pure=False, **sent)
    try:
        return cast(list[Any], client.gather(futures))
    finally:
        client.cancel(futures)
        client.cancel(list(sent.values()))
