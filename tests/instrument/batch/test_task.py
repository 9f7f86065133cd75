"""Batch tasks in this process (no Dask): what a task does with good, bad, foreign, busy and
already analysed runs, the results file it leaves, the summary table and the command line.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import shutil
import subprocess
import sys
import threading

import h5py
import numpy as np
import pytest

from instrument.batch.analyses import (
    ANALYSES,
    Analysed,
    Analysis,
    AnalysisFailed,
    analyse_fit,
    fit_arguments,
    fit_record,
)
from instrument.batch.summary import summary_columns, write_csv, write_html
from instrument.batch.task import Outcome, run_serial, run_task
from instrument.cli import main
from instrument.cli.fit import fit_options
from instrument.pipelines.brdf.pipeline import fit_options as pipeline_fit_options
from instrument.pipelines.brdf.pipeline import fit_run
from instrument.run.results import (
    already_done,
    options_fingerprint,
    read_record,
    read_results_attrs,
    results_path,
    run_lock,
)
from tests.instrument.batch.runs import fresh_copy, make_brdf_runs, make_flat_run, parse_cli
from tests.shared_files import made_once
from tests.waiting import EVENT_TIMEOUT_S


def _make_runs(folder):
    make_brdf_runs(folder, 3)
    make_flat_run(folder)
    return folder


# Made once per session (≈ 6 s of CPU): the module's tests are spread over the test
# processes, and each one that got a test rendered and wrote the three runs again.
@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory):
    return made_once(tmp_path_factory, "batch-runs", _make_runs)


@pytest.fixture
def runs(runs_dir, tmp_path):
    return fresh_copy(runs_dir, tmp_path / "runs")


def _options(*argv: str) -> dict:
    """The fit options of a command line (the single-run command's own parser)."""
    args = parse_cli(["fit", "x.h5", *argv])
    return fit_options(args)


def test_a_task_analyses_a_run_as_the_single_run_command_does(runs):
    opts = _options("--no-cv")
    o = run_task("fit", runs / "run-00.h5", opts, report=False)
    assert o.status == "analysed" and o.cause == "" and o.run_id == "run-00"
    assert (o.sample, o.kind) == ("glossy", "brdf_in_plane")
    single = fit_run(runs / "run-00.h5", models=opts["models"], run_cv=False, report=False,
                     write=False)
    fit = single.result.chosen_fit
    assert o.values["model"] == single.result.chosen == "lambert+ggx"
    for name, value, err, _ in fit.table():  # value for value
        assert o.values[name] == value and o.values[f"{name}_sigma"] == err
    assert o.values["n_points"] == 39 and o.values["dof"] == fit.dof
    # the results file is the one `scatterlab fit` writes (one writer per file: the
    # pipeline), with the same options recorded; the raw run is untouched
    attrs = read_results_attrs(runs / "run-00.h5", "fit")
    assert attrs["run_id"] == "run-00" and attrs["program"] == "scatterlab fit"
    assert attrs["options_sha256"] == options_fingerprint(
        pipeline_fit_options(**fit_arguments(opts)))
    with h5py.File(results_path(runs / "run-00.h5", "fit"), "r") as f:
        details = json.loads(f["entry/analysis/results_json"][()])
        assert {"reduced", "chosen"} <= set(f["entry/analysis"])
    assert details["selection"]["chosen"] == "lambert+ggx"
    assert fit_record(runs / "run-00.h5", opts) == pipeline_fit_options(**fit_arguments(opts))
    # the summary row kept next to it, tied to that results file
    stored = read_record(runs / "run-00.h5", "fit")
    assert stored["values"] == dict(o.values) and stored["run_id"] == "run-00"
    assert stored["options_sha256"] == attrs["options_sha256"]
    assert (stored["analysis"], stored["status"], stored["report"]) == ("fit", "analysed",
                                                                        False)
    with h5py.File(runs / "run-00.h5", "r") as f:
        assert "analysis" not in f["entry"]


@pytest.mark.slow  # run by CI after the default run (ADR 0021)
def test_a_rerun_skips_what_was_analysed_with_the_same_options(runs):
    opts = _options("--no-cv")
    first = run_serial("fit", sorted(runs.glob("run-*.h5")), opts, report=False)
    assert [o.status for o in first] == ["analysed"] * 3
    stamps = [results_path(p, "fit").stat().st_mtime_ns for p in sorted(runs.glob("run-*.h5"))]
    again = run_serial("fit", sorted(runs.glob("run-*.h5")), opts, report=False)
    assert [o.status for o in again] == ["skipped"] * 3
    assert all("already analysed" in o.cause for o in again)
    # the skipped rows carry the stored answer, so the summary table is still complete
    assert [dict(o.values) for o in again] == [dict(o.values) for o in first]
    assert [o.result for o in again] == [o.result for o in first]
    assert stamps == [results_path(p, "fit").stat().st_mtime_ns
                      for p in sorted(runs.glob("run-*.h5"))]
    # other options, or --force: analysed again
    other = run_task("fit", runs / "run-00.h5", _options("--no-cv", "--criterion", "aic"),
                     report=False)
    assert other.status == "analysed"
    forced = run_task("fit", runs / "run-01.h5", opts, report=False, force=True)
    assert forced.status == "analysed" and dict(forced.values) == dict(first[1].values)
    # a report asked for is part of what was done: the report is made, once
    made = run_task("fit", runs / "run-02.h5", opts, report=True)
    assert made.status == "analysed"
    assert (results_path(runs / "run-02.h5", "fit").parent / "index.html").is_file()
    assert run_task("fit", runs / "run-02.h5", opts, report=True).status == "skipped"


def test_bad_foreign_and_unfinished_runs_are_reported_with_their_cause(runs):
    (runs / "garbage.h5").write_bytes(b"this is not an HDF5 file\n" * 10)
    data = (runs / "run-00.h5").read_bytes()
    (runs / "truncated.h5").write_bytes(data[: len(data) // 3])
    shutil.copy2(runs / "run-01.h5", runs / "live.h5")
    with h5py.File(runs / "live.h5", "r+") as f:
        f["entry"].attrs["status"] = "running"
    names = ["garbage.h5", "run-00.h5", "truncated.h5", "missing.h5", "flat.h5", "live.h5",
             "run-02.h5"]
    out = run_serial("fit", [runs / n for n in names], _options("--no-cv"), report=False)
    by = {o.run.rsplit("/", 1)[-1]: o for o in out}
    assert [o.status for o in out] == ["failed", "analysed", "failed", "failed",
                                       "not applicable", "failed", "analysed"]
    # the words every command uses for a file that is not a run (instrument.run.runfile)
    assert "not a scatterlab run file" in by["garbage.h5"].cause
    assert "garbage.h5" in by["garbage.h5"].cause
    assert "truncated.h5" in by["truncated.h5"].cause
    assert by["missing.h5"].cause.endswith("no such run file")
    assert "flat_field run" in by["flat.h5"].cause
    assert "still being written" in by["live.h5"].cause
    assert by["garbage.h5"].detail  # the traceback, for the HTML table
    # nothing was created next to the files that are not analysable runs
    for n in ("garbage", "truncated", "missing", "flat", "live"):
        assert not (runs / n).exists(), n


def test_a_run_busy_with_another_analysis_is_not_analysed_twice_at_once(runs):
    run = runs / "run-00.h5"
    opts = _options("--no-cv")
    with run_lock(run):
        o = run_task("fit", run, opts, report=False, lock_wait_s=0.3)
    assert o.status == "failed" and "held its lock" in o.cause
    assert not results_path(run, "fit").exists()
    # Two tasks of the same run at once (e.g. a task Dask runs again while the first is
    # still alive): whichever comes second waits for the other's lock, then finds its
    # results.
    first: list[Outcome] = []
    t = threading.Thread(target=lambda: first.append(run_task("fit", run, opts,
                                                              report=False)))
    t.start()
    second = run_task("fit", run, opts, report=False)
    t.join(60)
    assert sorted([first[0].status, second.status]) == ["analysed", "skipped"]
    assert dict(second.values) == dict(first[0].values)


def test_a_fit_that_does_not_converge_fails_with_what_it_found(runs, monkeypatch):
    calls = []

    def not_converged(path, options, *, folder=None, report=True):
        calls.append(path)
        row = analyse_fit(path, options, folder=folder, report=report)
        raise AnalysisFailed("the fit of the chosen model lambert+ggx did not converge "
                             "(maximum evaluations)", row.row())

    monkeypatch.setitem(ANALYSES, "fit", Analysis("fit", "fit", ("brdf_in_plane",),
                                                  "scatterlab fit", not_converged,
                                                  fit_record))
    opts = _options("--no-cv")
    o = run_task("fit", runs / "run-00.h5", opts, report=False)
    assert o.status == "failed" and o.cause.startswith("not usable: the fit of the chosen")
    assert o.values["model"] == "lambert+ggx"  # what it found is kept for the table
    # the pipeline wrote its results file (as `scatterlab fit` does); the row kept beside
    # it says the answer is not usable, so it is not a finished analysis: the rerun tries
    # again
    assert read_record(runs / "run-00.h5", "fit")["status"] == "failed"
    again = run_task("fit", runs / "run-00.h5", opts, report=False)
    assert again.status == "failed" and len(calls) == 2


def test_summary_csv_reads_back_value_for_value_and_html_names_every_run(tmp_path):
    rows = [
        Outcome("a.h5", "fit", "analysed", "a", "s1", "brdf_in_plane", "lambert: ρ = 0.8",
                {"model": "lambert", "lambert.rho": 0.1 + 0.2, "chi2": np.float64(3.5).item()},
                ("a <b> flag",), seconds=1.0, worker="h:1"),
        Outcome("b.h5", "fit", "failed", cause="cannot read b.h5", detail="Traceback …"),
        Outcome("c.h5", "fit", "skipped", "c", "s2", "brdf_in_plane", "oren_nayar",
                {"model": "oren_nayar", "oren_nayar.sigma": 1e-300}),
    ]
    cols = summary_columns(rows)
    assert cols[:7] == ["run", "run_id", "sample", "kind", "analysis", "status", "result"]
    assert cols[7:11] == ["model", "lambert.rho", "chi2", "oren_nayar.sigma"]
    with open(write_csv(rows, tmp_path / "s.csv"), newline="", encoding="utf-8") as fh:
        back = list(csv.DictReader(fh))
    assert float(back[0]["lambert.rho"]) == 0.1 + 0.2
    assert float(back[2]["oren_nayar.sigma"]) == 1e-300
    assert back[1]["status"] == "failed" and back[1]["cause"] == "cannot read b.h5"
    assert back[1]["lambert.rho"] == ""
    page = write_html(rows, tmp_path / "s.html", title="t", about={"options": "{}"})
    text = page.read_text(encoding="utf-8")
    assert all(n in text for n in ("a.h5", "b.h5", "c.h5", "1 failed", "a &lt;b&gt; flag"))


@pytest.mark.slow  # run by CI after the default run (ADR 0021)
def test_cli_batch_fit_here_then_again(runs, tmp_path, capsys):
    argv = ["batch", "fit", str(runs / "run-*.h5"), str(runs / "flat.h5"), "--no-cv",
            "--workers", "0", "--no-report", "--summary-dir", str(tmp_path / "s")]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "3 analysed" in out and "1 not applicable" in out
    (csv_path,) = (tmp_path / "s").glob("batch-fit-*.csv")
    with open(csv_path, newline="", encoding="utf-8") as fh:
        rows = {r["run_id"]: r for r in csv.DictReader(fh)}
    direct = run_task("fit", runs / "run-01.h5", _options("--no-cv"), report=False, force=True)
    assert rows["run-01"]["model"] == direct.values["model"] == "oren_nayar"
    assert rows["run-01"]["ggx.alpha"] == ""  # a column of the other runs' model
    for k, v in direct.values.items():
        assert rows["run-01"][k] == (repr(v) if isinstance(v, float) else str(v)), k
    assert already_done(runs / "run-00.h5", "fit", run_id="run-00",
                        options=fit_record(runs / "run-00.h5", _options("--no-cv")))
    shutil.rmtree(tmp_path / "s")
    assert main(argv) == 0
    assert "3 skipped" in capsys.readouterr().out
    # errors in the command itself: exit 2, a message naming the problem
    assert main(["batch", "fit", str(runs / "nothing-*.h5"), "--workers", "0"]) == 2
    assert "matches no run file" in capsys.readouterr().out
    assert main(["batch", "fit", "--workers", "0"]) == 2
    assert "no runs" in capsys.readouterr().out
    assert main(["batch", "fit", str(runs), "--workers", "0", "--bootstrap", "-1"]) == 2
    assert "--bootstrap" in capsys.readouterr().out
    assert main(["batch", "fit", "--catalog-query", "colour=red", "--workers", "0"]) == 2
    assert "unknown key 'colour'" in capsys.readouterr().out


def test_a_bad_run_makes_the_exit_status_1_and_is_named(runs, tmp_path, capsys):
    (runs / "bad.h5").write_text("nope")
    assert main(["batch", "fit", str(runs), "--workers", "0", "--no-report", "--no-cv",
                 "--summary-dir", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert f"FAILED {runs / 'bad.h5'}: {runs / 'bad.h5'} is not a scatterlab run file" in out
    assert "3 analysed" in out


def test_adapter_rows_are_plain_data(runs):
    a = analyse_fit(runs / "run-00.h5", _options("--no-cv"), folder=runs / "run-00" / "fit",
                    report=False)
    assert isinstance(a, Analysed)
    json.dumps(a.row(), allow_nan=True)  # no numpy scalars: JSON and pickling stay exact
    assert all(type(v) in (str, int, float, bool) for v in a.values.values())


_STATUS = "--- exit status "
_NO_DASK = f"""
import json, sys
for name in ("dask", "distributed", "dask_jobqueue"):
    sys.modules[name] = None  # importing them now raises ImportError, as if not installed
from instrument.cli import build_parser, main
build_parser()
assert not [m for m in sys.modules if m.split(".")[0] in ("dask", "distributed", "bokeh")
            and sys.modules[m] is not None]
for argv in json.loads(sys.argv[1]):  # each command line in turn, its status after it
    print("\\n{_STATUS}" + str(main(argv)), flush=True)
"""


def test_without_dask_the_cli_starts_and_batches_here_and_says_what_to_install(runs):
    # both command lines in one interpreter without Dask (one start, ≈ 1.5 s of CPU less)
    argvs = [["batch", "fit", str(runs / "run-00.h5"), "--workers", "0", "--no-cv",
              "--no-report"],
             ["batch", "fit", str(runs / "run-00.h5"), "--workers", "2"]]
    proc = subprocess.run([sys.executable, "-c", _NO_DASK, json.dumps(argvs)],
                          capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    parts = proc.stdout.split(_STATUS)
    assert len(parts) == len(argvs) + 1, proc.stdout + proc.stderr
    outputs = [parts[0], *(part.split("\n", 1)[1] for part in parts[1:-1])]
    codes = [int(part.split("\n", 1)[0]) for part in parts[1:]]
    here, cluster = zip(codes, outputs, strict=True)
    assert here[0] == 0, proc.stdout + proc.stderr
    assert "1 analysed" in here[1]
    assert cluster[0] == 2
    assert "install the cluster extra" in cluster[1] and "--workers 0" in cluster[1]


def test_an_aborted_run_is_analysed_and_flagged_also_when_skipped(runs):
    shutil.copy2(runs / "run-00.h5", runs / "aborted.h5")
    with h5py.File(runs / "aborted.h5", "r+") as f:
        f["entry"].attrs["status"] = "aborted"
    first, again = (run_task("fit", runs / "aborted.h5", _options("--no-cv"), report=False)
                    for _ in range(2))
    assert (first.status, again.status) == ("analysed", "skipped")
    assert "run status 'aborted'" in first.flags[-1]
    assert again.flags == first.flags


def _layout(path) -> dict[str, tuple]:
    """Every group and dataset of an HDF5 file, with each dataset's shape and dtype kind."""
    out: dict[str, tuple] = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(
            name, (obj.shape, obj.dtype.kind) if isinstance(obj, h5py.Dataset) else ()))
    return out


@pytest.mark.slow  # run by CI after the default run (ADR 0021)
def test_a_run_fitted_alone_is_skipped_by_the_batch_and_both_write_the_same_file(runs,
                                                                                tmp_path,
                                                                                capsys):
    run = runs / "run-00.h5"
    assert main(["fit", str(run), "--no-cv"]) == 0
    single = results_path(run, "fit")
    alone = _layout(single)
    stamp = single.stat().st_mtime_ns
    capsys.readouterr()
    # the same options through the batch: already done, answered from the row kept beside
    argv = ["batch", "fit", str(run), "--no-cv", "--workers", "0", "--summary-dir",
            str(tmp_path / "s")]
    assert main(argv) == 0
    assert "1 skipped" in capsys.readouterr().out
    assert single.stat().st_mtime_ns == stamp  # not written again
    skipped = run_task("fit", run, _options("--no-cv"))
    assert skipped.status == "skipped" and skipped.values["model"] == "lambert+ggx"
    # forced through the batch: the same results file, group for group, dataset for
    # dataset, with the same options recorded (so `scatterlab fit` counts it as done too)
    forced = run_task("fit", run, _options("--no-cv"), force=True)
    assert forced.status == "analysed" and dict(forced.values) == dict(skipped.values)
    assert single.stat().st_mtime_ns != stamp
    assert _layout(single) == alone and "entry/analysis/chosen/params" in alone
    assert already_done(run, "fit", run_id="run-00",
                        options=pipeline_fit_options(models=_options("--no-cv")["models"],
                                                     run_cv=False))
    # other options are other work
    assert run_task("fit", run, _options("--no-cv", "--criterion", "aic")).status == "analysed"


class _Console(io.StringIO):
    """A console that sets ``seen`` once ``text`` has been printed to it."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.text, self.seen = text, threading.Event()

    def write(self, s: str) -> int:
        n = super().write(s)
        if self.text in self.getvalue():
            self.seen.set()
        return n


@pytest.mark.slow  # run by CI after the default run (ADR 0021)
def test_a_single_run_command_waits_for_the_batch_holding_the_run(runs, capsys):
    run = runs / "run-01.h5"
    order: list[str] = []
    held = threading.Event()
    console = _Console("waiting: another analysis of run-01.h5")

    def batch_task_holding_the_run() -> None:
        with run_lock(run):
            held.set()
            # released only once the command has found the lock taken and said so: the
            # command cannot pass the lock before it is free, however the threads run
            assert console.seen.wait(EVENT_TIMEOUT_S), "the command never said it waits"
            order.append("lock released")

    t = threading.Thread(target=batch_task_holding_the_run)
    t.start()
    assert held.wait(EVENT_TIMEOUT_S)
    with contextlib.redirect_stdout(console):
        assert main(["fit", str(run), "--no-cv"]) == 0
    order.append("fit written")
    t.join(EVENT_TIMEOUT_S)
    assert order == ["lock released", "fit written"]
    assert console.seen.is_set()
    assert read_record(run, "fit")["status"] == "analysed"
