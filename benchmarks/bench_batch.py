"""``scatterlab batch fit`` on 32 simulated BRDF runs: serial against 1 and 2 local workers.

The runs are in-plane scans of the simulated bench (57 points each, 96² px frames; the
glossy and the Oren–Nayar sample in turn, one sensor seed per run), rendered by the
simulated camera and written by the engine's writer (tests/instrument/sim_scan.py). Each
mode analyses all of them with the same options (``--force``: nothing is skipped):

* serial — :func:`instrument.batch.task.run_serial`, in this process, no Dask;
* 1 and 2 workers — :func:`instrument.batch.cluster.run_on_cluster` on a ``LocalCluster``
  of that many worker processes (one thread, one BLAS thread each), the cluster already
  started (its start-up is reported apart).

For each it prints the wall time (the best of ``--repeat`` passes: the machine is shared,
and the best pass is the one least disturbed), the speed-up over serial against the ideal
(the number of workers), the sum of the tasks' own wall times and of their CPU times, the
share of a core a task got while it ran (CPU over wall), and how busy the workers were
(Σ task wall time over workers × batch wall time; 1 = never idle, no overhead). The rows
must equal the serial rows value for value; the benchmark says so.

Run: ``python benchmarks/bench_batch.py [--runs 32] [--no-report] [--workers 1 2]
[--repeat 2]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from instrument.batch.task import Outcome, run_serial
from instrument.cli import build_parser
from instrument.cli.fit import fit_options
from tests.instrument.sim_scan import SAMPLES, ScanSetup, render, write_run_file


def make_runs(folder: Path, n: int) -> list[Path]:
    rendered = [render(ScanSetup(), SAMPLES[1]), render(ScanSetup(), SAMPLES[2])]
    return [write_run_file(rendered[k % 2], 100 + k, folder / f"run-{k:02d}.h5",
                           run_id=f"run-{k:02d}") for k in range(n)]


def _row(label: str, wall: float, serial_wall: float, workers: int, out: list[Outcome],
         start_s: float | None) -> str:
    busy = sum(o.seconds for o in out)
    cpu = sum(o.cpu_seconds for o in out)
    speed = serial_wall / wall
    start = "–" if start_s is None else f"{start_s:.1f}"
    return (f"| {label} | {wall:.1f} | {speed:.2f} | {workers} | {speed / workers:.0%} | "
            f"{busy:.1f} | {cpu:.1f} | {cpu / busy:.0%} | {busy / (workers * wall):.0%} | "
            f"{start} |")


def _best(passes: list[tuple[float, list[Outcome]]]) -> tuple[float, list[Outcome]]:
    return min(passes, key=lambda p: p[0])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=32, help="simulated runs (default 32)")
    ap.add_argument("--no-report", action="store_true",
                    help="no report/figures per run (the fits only)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2],
                    help="local cluster sizes to time (default: 1 2)")
    ap.add_argument("--repeat", type=int, default=2, help="passes per mode, best kept "
                    "(default 2)")
    ap.add_argument("--keep", default=None, help="write the runs here and keep them")
    args = ap.parse_args()
    from instrument.batch.cluster import connect, run_on_cluster

    report = not args.no_report
    options = fit_options(build_parser().parse_args(["fit", "x.h5"]))
    tmp = Path(args.keep or tempfile.mkdtemp(prefix="bench-batch-"))
    try:
        t = time.perf_counter()
        runs = make_runs(tmp, args.runs)
        print(f"{len(runs)} runs written in {time.perf_counter() - t:.1f} s to {tmp}; "
              f"fit options: defaults (BIC, CV on), report {'on' if report else 'off'}; "
              f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start")
        passes = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            out = run_serial("fit", runs, options, report=report, force=True)
            passes.append((time.perf_counter() - t, out))
        serial_wall, ref = _best(passes)
        assert all(o.status == "analysed" for o in ref), [o.cause for o in ref if o.cause]
        print("| mode | wall (s) | speed-up | ideal | of ideal | Σ task wall (s) "
              "| Σ task CPU (s) | core share | workers busy | cluster start (s) |")
        print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        print(_row("serial, this process", serial_wall, serial_wall, 1, ref, None))
        for n in args.workers:
            t = time.perf_counter()
            with connect(workers=n, dashboard=False) as client:
                start_s = time.perf_counter() - t
                passes = []
                for _ in range(args.repeat):
                    t = time.perf_counter()
                    out = run_on_cluster(client, "fit", runs, options, report=report,
                                         force=True)
                    passes.append((time.perf_counter() - t, out))
            wall, out = _best(passes)
            same = all(a.status == "analysed" and dict(a.values) == dict(b.values)
                       for p in passes for a, b in zip(p[1], ref, strict=True))
            print(_row(f"{n} worker{'s' if n > 1 else ''}", wall, serial_wall, n, out,
                       start_s) + ("" if same else " **rows differ from serial**"))
            if not same:
                return 1
        print(f"rows of every mode equal the serial rows value for value; load average "
              f"{os.getloadavg()[0]:.1f} at the end")
    finally:
        if args.keep is None:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
