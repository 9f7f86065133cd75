"""Batches and sweeps on a real Dask cluster: a ``LocalCluster`` of 2 worker processes with
one thread (and one BLAS thread) each, as ``scatterlab batch`` starts by default.

* the batch's answers equal the serial analyses', value for value, with a bad run file
  reported and the others finished, and a rerun skipping the finished work;
* a worker process killed mid-batch: its runs are retried on another worker (or, with no
  retries allowed, reported with the cause), and no run or results file is damaged;
* the sweeps (planner options, closed-loop seeds) give the loop's results;
* the SLURM example builds a job script with one single-threaded worker per core.

Timeouts are generous and nothing here depends on timing: a loaded 2-core box only makes
it slower.
"""

from __future__ import annotations

import csv
import functools
import importlib.util
import io
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

from instrument.batch.cluster import (
    BLAS_ENV,
    _worker_deaths,
    cluster_map,
    connect,
    run_on_cluster,
    worker_notes,
)
from instrument.batch.task import Outcome, run_serial
from instrument.cli import main
from instrument.cli.batch import BatchProgress
from instrument.cli.fit import fit_options
from instrument.run.results import read_results_attrs, results_dir
from instrument.run.runfile import read_run
from tests.instrument.batch.runs import fresh_copy, make_brdf_runs, parse_cli

ROOT = Path(__file__).resolve().parents[3]
N_RUNS = 6


@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cluster-runs")
    make_brdf_runs(folder, N_RUNS)
    return folder


@pytest.fixture(scope="module")
def options():
    return fit_options(parse_cli(["fit", "x.h5", "--no-cv"]))


@pytest.fixture(scope="module")
def serial(runs_dir, options, tmp_path_factory):
    """The runs analysed one after another in this process: the reference answers."""
    folder = fresh_copy(runs_dir, tmp_path_factory.mktemp("serial"))
    out = run_serial("fit", sorted(folder.glob("*.h5")), options, report=False)
    assert all(o.status == "analysed" for o in out), out
    return {Path(o.run).name: o for o in out}


@pytest.fixture(scope="module")
def client():
    with connect(workers=2, dashboard=False, timeout_s=120) as c:
        yield c


def _same_answer(o: Outcome, ref: Outcome) -> None:
    assert o.status == "analysed", (o.run, o.cause)
    assert dict(o.values) == dict(ref.values)  # exact float equality
    assert (o.result, o.flags, o.run_id, o.sample) == (ref.result, ref.flags, ref.run_id,
                                                       ref.sample)


@pytest.mark.slow  # run by CI after the default run (ADR 0021)
def test_two_workers_give_the_serial_answers_and_report_a_bad_run(client, runs_dir, options,
                                                                  serial, tmp_path):
    folder = fresh_copy(runs_dir, tmp_path / "runs")
    (folder / "bad.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 200)  # a torn file
    runs = sorted(folder.glob("*.h5"))
    seen: list[Outcome] = []
    out = run_on_cluster(client, "fit", runs, options, report=False, on_outcome=seen.append)
    assert [o.run for o in out] == [str(r) for r in runs] and len(seen) == len(runs)
    by = {Path(o.run).name: o for o in out}
    bad = by.pop("bad.h5")
    assert bad.status == "failed" and "bad.h5" in bad.cause and "cannot be read" in bad.cause
    for name, o in by.items():
        _same_answer(o, serial[name])
        assert int(o.worker.rsplit(":", 1)[1]) != os.getpid()  # done by a worker process
    # one BLAS thread in every worker, and nothing to warn about
    env = client.run(lambda: {k: os.environ.get(k) for k in BLAS_ENV})
    assert len(env) == 2 and all(e == BLAS_ENV for e in env.values())
    assert worker_notes(client) == []
    # the rerun skips every finished run and keeps its answer; the bad one fails again
    again = {Path(o.run).name: o for o in run_on_cluster(client, "fit", runs, options,
                                                         report=False)}
    assert again.pop("bad.h5").status == "failed"
    assert {o.status for o in again.values()} == {"skipped"}
    for name, o in again.items():
        assert dict(o.values) == dict(serial[name].values)


def _kill_a_busy_worker(client, done: list, killed: list, stop: threading.Event) -> None:
    """Once a task has finished (the batch is under way), SIGKILL a worker process that is
    analysing a run; record its address and the tasks it held."""
    while not stop.is_set():
        if done:
            busy = {a: keys for a, keys in client.processing().items() if keys}
            if busy:
                addr, keys = next(iter(busy.items()))
                pid = client.run(os.getpid, workers=[addr])[addr]
                os.kill(pid, signal.SIGKILL)
                killed.append((addr, set(keys)))
                return
        time.sleep(0.02)


@pytest.mark.slow  # a cluster of its own per case, a kill and reports: 80 s on 2 cores
@pytest.mark.timeout(900)  # 80 s on a quiet 2-core box: cluster start, kill, retries
@pytest.mark.parametrize("retries", [3, 0], ids=["retried", "reported"])
def test_a_worker_killed_mid_batch(runs_dir, options, serial, tmp_path, retries):
    folder = fresh_copy(runs_dir, tmp_path / "runs")
    runs = sorted(folder.glob("*.h5"))
    done: list[Outcome] = []
    killed: list = []
    stop = threading.Event()
    with connect(workers=2, retries=retries, dashboard=False, timeout_s=120) as c:
        killer = threading.Thread(target=_kill_a_busy_worker, args=(c, done, killed, stop),
                                  daemon=True)
        killer.start()
        # reports make each task last a second or two, so the kill lands mid-analysis
        out = run_on_cluster(c, "fit", runs, options, report=True, on_outcome=done.append)
        stop.set()
        killer.join(30)
    assert killed, "no worker was busy to be killed"
    held = {k.split("-", 3)[3] for k in killed[0][1]}  # keys: fit-<batch>-<i>-<file name>
    by = {Path(o.run).name: o for o in out}
    assert len(by) == len(runs)  # every run accounted for
    for name, o in by.items():
        if o.status == "failed":
            # only a run the dead worker held, and only when no retry was allowed
            assert not retries and name in held, (name, o.cause)
            assert "worker process analysing it died" in o.cause
        else:
            _same_answer(o, serial[name])  # (retried on another worker:) the same answer
    # a run whose worker died and that another worker finished says it was redone (and
    # only then: without retries the dead worker's runs failed instead)
    redone = [o for o in out if o.redone]
    assert all(o.status != "failed" and o.redone == 1 for o in redone)
    assert bool(redone) == bool(retries)
    # the console says so, in one line per run that was redone
    progress = BatchProgress(len(out), stream=io.StringIO())
    for o in out:
        progress(o)
    lines = [line for line in progress.stream.getvalue().splitlines()
             if line.startswith("  redone: ")]
    assert lines == [f"  redone: {o.run}: the worker process analysing it died (killed, "
                     "crashed or out of memory); another worker analysed it again from the "
                     "start" for o in out if o.redone]
    if not retries:
        assert any(by[n].status == "failed" for n in held)
    # no file damaged: every run reads whole, every results file is complete, no debris
    for run in runs:
        data = read_run(run)
        light, _, dark = data.frames_of(int(data.brdf_rows()[-1]))
        assert light.shape == dark.shape == (1, 96, 96)
        folder_ = results_dir(run, "fit")
        if by[run.name].status == "analysed":
            assert read_results_attrs(run, "fit")["run_id"] == run.stem
            assert (folder_ / "index.html").is_file()
            assert not list(folder_.glob(".*.tmp"))  # a killed write's debris is cleared
    # a rerun here finishes what the dead worker left and skips the rest
    rerun = run_serial("fit", runs, options, report=True)
    for o in rerun:
        name = Path(o.run).name
        assert o.status == ("skipped" if by[name].status == "analysed" else "analysed")
        assert dict(o.values) == dict(serial[name].values)
        assert not list(results_dir(o.run, "fit").glob(".*.tmp"))


@pytest.mark.slow  # a second cluster (the command starts its own): ~55 s of CPU on 2 cores
def test_cli_batch_on_a_local_cluster_prints_the_dashboard_and_writes_the_table(
        runs_dir, serial, tmp_path, capsys):
    folder = fresh_copy(runs_dir, tmp_path / "runs")
    assert main(["batch", "fit", str(folder / "*.h5"), "--no-cv", "--workers", "2",
                 "--no-report", "--summary-dir", str(tmp_path / "table")]) == 0
    out = capsys.readouterr().out
    assert "Dask cluster: 2 worker(s), 2 thread(s)" in out
    assert "Dask dashboard: http" in out
    assert f"{N_RUNS} analysed" in out
    (table,) = (tmp_path / "table").glob("batch-fit-*.csv")
    with open(table, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == N_RUNS
    for row in rows:
        ref = serial[Path(row["run"]).name]
        for k, v in ref.values.items():
            assert row[k] == (repr(v) if isinstance(v, float) else str(v)), k
    assert (tmp_path / "table" / table.with_suffix(".html").name).is_file()


def _dies_the_first_time(marker: str) -> str:
    """A task whose worker process is killed the first time it runs it (as by the OOM
    killer), and that completes on the worker Dask gives it to next."""
    m = Path(marker)
    if not m.exists():
        m.write_text("tried")
        os.kill(os.getpid(), signal.SIGKILL)
    return "done"


def test_a_task_given_to_another_worker_counts_the_death(client, tmp_path):
    """What ``Outcome.redone`` reads (the cheap part of the killed-worker test above)."""
    fut = client.submit(_dies_the_first_time, str(tmp_path / "marker"), pure=False)
    assert fut.result(timeout=120) == "done"
    assert client.run_on_scheduler(_worker_deaths, key=fut.key) == 1
    again = client.submit(_dies_the_first_time, str(tmp_path / "marker"), pure=False)
    assert again.result(timeout=120) == "done"
    assert client.run_on_scheduler(_worker_deaths, key=again.key) == 0


def test_the_planner_sweep_on_the_cluster_equals_the_loop(client):
    from instrument.bench.profile import load_profile
    from instrument.plans import load_plan
    from instrument.plans.tradeoff import ScanOption, setup_from_profile, sweep

    spec = load_plan(ROOT / "examples" / "brdf_inplane.toml")
    profile = load_profile("sim")
    prior, det = setup_from_profile(profile, spec)
    opts = [ScanOption(s, c, f) for s in (10.0, 20.0) for c in (1e3, 1e5) for f in (1, 4)]
    here = sweep(spec, profile, opts, prior=prior, det=det)
    there = sweep(spec, profile, opts, prior=prior, det=det,
                  mapper=functools.partial(cluster_map, client))
    assert there == here  # dataclass equality: every duration and σ, in order


def test_closed_loop_seeds_on_the_cluster_equal_the_loop(client):
    from tests.instrument.pipelines.brdf.test_closed_loop import closed_loop
    from tests.instrument.sim_scan import SAMPLES, ScanSetup

    setup = ScanSetup(theta_r_step=20.0)
    here = closed_loop(SAMPLES[1], range(4), setup)
    there = closed_loop(SAMPLES[1], range(4), setup,
                        mapper=functools.partial(cluster_map, client))
    for name in here.__dataclass_fields__:
        a, b = getattr(here, name), getattr(there, name)
        assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, name


def test_the_slurm_example_asks_for_single_threaded_workers_per_core():
    pytest.importorskip("dask_jobqueue")
    spec = importlib.util.spec_from_file_location("slurm_batch",
                                                  ROOT / "examples" / "slurm_batch.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    cluster = mod.make_cluster(cores=16, memory="32GB", walltime="02:00:00", queue="normal",
                               account="lab", prologue=("source /opt/venv/bin/activate",))
    try:
        script = cluster.job_script()
    finally:
        cluster.close()
    assert "#SBATCH --cpus-per-task=16" in script and "#SBATCH -p normal" in script
    assert "#SBATCH -A lab" in script and "#SBATCH -t 02:00:00" in script
    for line in (*mod.BLAS_ONE_THREAD, "source /opt/venv/bin/activate"):
        assert line in script
    assert "--nworkers 16" in script and "--nthreads 1" in script
    assert mod.main(["--jobs", "1"]) == 2  # no batch command line after --


def test_plan_target_uncertainty_on_two_workers_prints_the_serial_answer(client, capsys):
    """The sweep on the module's running cluster (``--scheduler``): starting one more costs
    more than the sweep; ``scatterlab batch`` starting its own is tested above."""
    argv = ["plan", str(ROOT / "examples" / "brdf_inplane.toml"), "--target-uncertainty",
            "5e-5", "--readout-s", "0.02"]
    assert main(argv) == 0
    here = capsys.readouterr().out
    # A worker the nanny restarted (after a heartbeat missed on a loaded box) takes a moment
    # to join again; the sweep itself would run on one, but the printed count would differ.
    client.wait_for_workers(2, timeout=300)
    assert main([*argv, "--scheduler", client.scheduler.address]) == 0
    there = capsys.readouterr().out
    assert "Dask cluster: 2 worker(s)" in there
    assert there.split("\n", 2)[2] == here  # after the two lines about the cluster
