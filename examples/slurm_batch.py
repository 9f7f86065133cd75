"""``scatterlab batch`` on a SLURM cluster, through dask-jobqueue.

Run it on the cluster's login node, in the environment where scatterlab is installed with
its ``hpc`` extra (``pip install -e '.[hpc]'``) on a file system the compute nodes see::

    python examples/slurm_batch.py --jobs 4 --cores 16 --memory 32GB --walltime 02:00:00 \\
        --queue normal --account myproject -- fit 'data/runs/**/*.h5' --no-cv

Everything after ``--`` is the ``scatterlab batch`` command line, as on a laptop. The script
asks SLURM for ``--jobs`` jobs of ``--cores`` cores; each job runs as many Dask worker
processes as it has cores, one thread and one BLAS thread each, so a job's cores are used
by independent runs (the analyses are numpy/scipy code that holds the GIL, and a threaded
BLAS in each process would oversubscribe the node). The batch starts as soon as the first
job has started and uses the others as they arrive; when it ends the jobs are released.

The same can be set up by hand: an ``sbatch`` script that starts ``dask scheduler
--scheduler-file sched.json`` and ``dask worker --scheduler-file sched.json --nthreads 1``
on its nodes, then ``scatterlab batch fit RUNS... --scheduler sched.json``
(docs/guide/batch.md).
"""

from __future__ import annotations

import argparse
import sys

#: Exported in every job before its workers start.
BLAS_ONE_THREAD = ("export OPENBLAS_NUM_THREADS=1", "export OMP_NUM_THREADS=1",
                   "export MKL_NUM_THREADS=1")


def make_cluster(*, cores: int, memory: str, walltime: str, queue: str | None = None,
                 account: str | None = None, prologue: tuple[str, ...] = (),
                 log_directory: str | None = None):
    """A :class:`dask_jobqueue.SLURMCluster` whose jobs run one single-threaded worker
    process per core (no jobs are submitted until it is scaled)."""
    from dask_jobqueue import SLURMCluster

    return SLURMCluster(
        cores=cores, processes=cores, memory=memory, walltime=walltime, queue=queue,
        account=account, job_script_prologue=[*BLAS_ONE_THREAD, *prologue],
        log_directory=log_directory,
    )


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" not in argv:
        print("usage: slurm_batch.py [options] -- ANALYSIS RUN... [batch options]",
              file=sys.stderr)
        return 2
    cut = argv.index("--")
    ap = argparse.ArgumentParser(description="scatterlab batch on SLURM (dask-jobqueue)")
    ap.add_argument("--jobs", type=int, default=2, help="SLURM jobs to ask for (default 2)")
    ap.add_argument("--cores", type=int, default=8, help="cores per job (default 8)")
    ap.add_argument("--memory", default="16GB", help="memory per job (default 16GB)")
    ap.add_argument("--walltime", default="01:00:00", help="per job (default 01:00:00)")
    ap.add_argument("--queue", default=None, help="partition (default: the site's)")
    ap.add_argument("--account", default=None, help="account to charge (if the site needs one)")
    ap.add_argument("--prologue", action="append", default=[],
                    help="a shell line run in each job before its workers (e.g. "
                    "'source /path/to/.venv/bin/activate'); repeatable")
    ap.add_argument("--log-directory", default=None, help="folder for the jobs' logs")
    opts = ap.parse_args(argv[:cut])
    batch = argv[cut + 1:]

    from instrument.cli import main as scatterlab

    cluster = make_cluster(cores=opts.cores, memory=opts.memory, walltime=opts.walltime,
                           queue=opts.queue, account=opts.account,
                           prologue=tuple(opts.prologue), log_directory=opts.log_directory)
    try:
        cluster.scale(jobs=opts.jobs)
        print(f"asked SLURM for {opts.jobs} job(s) of {opts.cores} cores; job script:\n"
              f"{cluster.job_script()}", flush=True)
        return scatterlab(["batch", *batch, "--scheduler", cluster.scheduler_address])
    finally:
        cluster.close()


if __name__ == "__main__":
    sys.exit(main())
