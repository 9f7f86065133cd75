"""``--scheduler`` / ``--workers``: where a batch or a sweep runs (ADR 0070).

Shared by ``scatterlab batch``, ``scatterlab plan --target-uncertainty`` and the sweep
benchmarks. Dask is imported only when a cluster is asked for, so these options cost
nothing at start-up and the commands work without the ``cluster`` extra when they run
here, one task after another.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import sys
from collections.abc import Callable, Iterator
from typing import Any, TextIO, cast

__all__ = ["ClusterUnavailable", "add_cluster_options", "mapper", "open_cluster"]

INSTALL_HINT = ("install the cluster extra: pip install -e '.[cluster]' (or "
                "pip install 'scatterlab[cluster]')")


class ClusterUnavailable(RuntimeError):
    """Dask is not installed, or the scheduler cannot be reached."""


def _workers(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of workers") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"{n} workers: give 0 (here, one at a time) or more")
    return n


def add_cluster_options(p: argparse.ArgumentParser, *, local_by_default: bool) -> None:
    """``--scheduler ADDRESS`` or ``--workers N`` (not both), and ``--retries``.

    ``local_by_default``: with neither option, a local cluster of one worker per core
    (``scatterlab batch``); otherwise the work runs here, one item after another.
    """
    g = p.add_mutually_exclusive_group()
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on an existing Dask cluster: its scheduler's address "
                   "(tcp://host:8786) or scheduler file (JSON)")
    default = ("a local cluster with one worker process per core" if local_by_default
               else "here, one after another")
    g.add_argument("--workers", type=_workers, default=None, metavar="N",
                   help=f"N local worker processes (one thread, one BLAS thread each); 0: "
                   f"here, one after another without Dask (default: {default})")
    p.add_argument("--retries", type=int, default=3, metavar="K",
                   help="times a task whose worker process died is given to another worker "
                   "on a local cluster (default 3)")


def _local_default(args: argparse.Namespace, local_by_default: bool) -> bool:
    if args.scheduler is not None:
        return True
    if args.workers is None:
        return local_by_default
    return cast(bool, args.workers > 0)


@contextlib.contextmanager
def open_cluster(args: argparse.Namespace, *, local_by_default: bool, dashboard: bool = True,
                 out: TextIO | None = None) -> Iterator[Any | None]:
    """A Dask client as the options ask (None: run here, without Dask), closed with the
    block; prints the cluster, its dashboard address and warnings about its workers.

    Raises
    ------
    ClusterUnavailable
        Dask is not installed, or the scheduler cannot be reached.
    """
    out = out or sys.stdout
    if not _local_default(args, local_by_default):
        yield None
        return
    try:
        from instrument.batch import cluster
    except ImportError as err:
        raise ClusterUnavailable(f"running on a Dask cluster needs dask.distributed "
                                 f"({err}); {INSTALL_HINT}, or give --workers 0") from None
    with contextlib.ExitStack() as stack:
        try:
            client = stack.enter_context(cluster.connect(
                args.scheduler, args.workers, retries=args.retries, dashboard=dashboard))
        except OSError as err:
            raise ClusterUnavailable(str(err)) from err
        print(f"Dask cluster: {cluster.describe(client)}", file=out)
        if not client.scheduler_info().get("workers"):
            print("  no workers yet: the tasks wait for them (batch-system jobs may still "
                  "be queued)", file=out)
        link = client.dashboard_link
        if link:
            print(f"Dask dashboard: {link}", file=out)
        for note in cluster.worker_notes(client):
            print(f"  warning: {note}", file=out)
        out.flush()
        yield client


def mapper(client: Any | None) -> Callable[..., list[Any]] | None:
    """The ordered map of the sweeps on ``client`` (None: the sweep's own loop)."""
    if client is None:
        return None
    from instrument.batch.cluster import cluster_map

    return functools.partial(cluster_map, client)
