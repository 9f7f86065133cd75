"""``scatterlab batch fit`` on polarimetric runs (here, ``--workers 0``): each run goes
through the polarimetric pipeline, as ``scatterlab fit`` sends it, and its row holds the
chosen pBRDF variant with the parameters the single-run pipeline finds; the calibration
(a name beside the run, or a file) and the pBRDF start values and held parameters reach
each polarimetric fit, scalar runs in the same batch are fitted without them, and a
calibration that cannot be used stops the batch with nothing written."""

from __future__ import annotations

import csv
import html
import json
import math
import re
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from analysis.polarimetry.calibration import DrrCalibration
from instrument.cli import main
from instrument.pipelines.polarimetry.calibration import (
    PolarimeterCalibration,
    calibration_folder,
    save_calibration,
)
from instrument.pipelines.polarimetry.pipeline import DEFAULT_START, fit_polarimetric_run
from instrument.run.results import results_dir
from tests.instrument.batch.runs import make_brdf_runs
from tests.instrument.pipelines.polarimetry.closed_loop import (
    FRAME_DEG,
    fast_bench,
    plan_text,
)
from tests.shared_files import made_once

#: a glass without a diffuse layer: the variant without it is what the data need
GLASS = '[simulation.scene.pbrdf]\nn = 1.5\nslope_rms = 0.15\n\n'


def _run(folder: Path, seed: int) -> Path:
    folder.mkdir()
    plan = folder / "plan.toml"
    plan.write_text(plan_text(f"glass {seed}", "50.0", "45.0, 50.0"), encoding="utf-8")
    bench = fast_bench(folder, GLASS, seed=seed)
    assert main(["run", str(plan), "--bench", str(bench), "--out", str(folder / "runs"),
                 "--no-fsync", "--quiet"]) == 0
    (path,) = (folder / "runs").glob("*.h5")
    return path


@pytest.mark.slow  # two engine runs of 2 geometries × 25 steps and their fits: 60-120 s
def test_batch_fit_takes_polarimetric_runs_through_their_pipeline(tmp_path):
    runs = [_run(tmp_path / f"r{seed}", seed) for seed in (3, 4)]
    assert main(["batch", "fit", *map(str, runs), "--workers", "0", "--summary-dir",
                 str(tmp_path)]) == 0
    (table,) = tmp_path.glob("batch-fit-*.csv")
    with open(table, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2
    for run in runs:
        (row,) = [r for r in rows if Path(r["run"]).name == run.name or r["run"] == str(run)]
        assert row["status"] == "analysed", row
        assert row["model"] == "fresnel_dielectric"
        assert int(row["n_geometries"]) == 2
        # uncalibrated (no calibration beside the runs): flagged in the row
        assert "uncalibrated" in row["flags"]
        # the row holds what the single-run pipeline computes
        alone = fit_polarimetric_run(run, report=False, write=False).summary["pbrdf"]
        assert float(row["n"]) == pytest.approx(alone["params"][0], rel=1e-9)
        assert float(row["chi2"]) == pytest.approx(alone["chi2"], rel=1e-9)
        with h5py.File(results_dir(run, "fit") / "results.h5") as f:
            assert f["entry/analysis"].attrs["kind"] == "polarimetric"
            assert f["entry/analysis/pbrdf"].attrs["variant"] == "fresnel_dielectric"
    # a second batch finds both done with the same options and fits nothing again
    again = tmp_path / "again"
    assert main(["batch", "fit", *map(str, runs), "--workers", "0", "--summary-dir",
                 str(again)]) == 0
    (table,) = again.glob("batch-fit-*.csv")
    with open(table, newline="", encoding="utf-8") as fh:
        assert [r["status"] for r in csv.DictReader(fh)] == ["skipped", "skipped"]


#: The hidden optics of sim-polarimetric in the calibration's frame (as in
#: tests/instrument/pipelines/polarimetry/test_polarimetric_fit.py): a calibration that
#: holds them, written as `scatterlab calibrate polarimeter` stores one.
HIDDEN = np.array([2.0 - FRAME_DEG, -2.0 - FRAME_DEG, math.radians(94.5),
                   math.radians(85.5), -0.3 - FRAME_DEG])


def _calibration(bench: str, folder: Path, name: str) -> Path:
    cal = PolarimeterCalibration(
        drr=DrrCalibration(params=HIDDEN, cov=np.diag([1e-6] * 5), chi2=100.0, dof=100),
        bench=bench, source_scale_w=1e-3, date="2026-11-27T00:00:00Z",
        quality="hidden optics")
    return save_calibration(cal, folder, name=name)


@pytest.fixture(scope="module")
def glass_and_scalar(tmp_path_factory) -> Path:
    """A folder with one polarimetric glass run (2 geometries × 25 steps through the
    engine), a calibration named ``lab-a.json`` beside it and one scalar BRDF run; made
    once per session."""
    def make(folder: Path) -> Path:
        run = _run(folder / "make", 5)
        (folder / "runs").mkdir()
        shutil.copy2(run, folder / "runs" / "glass.h5")
        _calibration("sim-polarimetric", calibration_folder(folder / "runs"), "lab-a.json")
        make_brdf_runs(folder / "scalar", 1)[0].rename(folder / "runs" / "scalar.h5")
        return folder / "runs"
    return made_once(tmp_path_factory, "polbatch", make)


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _written(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.mark.slow  # one engine run of 2 geometries × 25 steps, made once, and its fits
def test_batch_fit_passes_the_calibration_and_pbrdf_options_to_polarimetric_runs(
        glass_and_scalar, tmp_path, capsys):
    runs = _copy(glass_and_scalar, tmp_path / "runs")
    glass, scalar = runs / "glass.h5", runs / "scalar.h5"
    assert main(["batch", "fit", str(glass), str(scalar), "--workers", "0",
                 "--calibration", "lab-a", "--pbrdf-start", "alpha=0.2,albedo=0.2",
                 "--pbrdf-fixed", "k", "--summary-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    # said once, for the scalar run
    assert out.count("apply to polarimetric runs only") == 1
    assert ("note: --calibration, --pbrdf-start, --pbrdf-fixed apply to polarimetric runs "
            "only; the 1 scalar run of this batch is fitted without them") in out
    (table,) = tmp_path.glob("batch-fit-*.csv")
    with open(table, newline="", encoding="utf-8") as fh:
        rows = {Path(r["run"]).name: r for r in csv.DictReader(fh)}
    assert rows["glass.h5"]["status"] == "analysed", rows["glass.h5"]
    assert rows["glass.h5"]["calibrated"] == "True"
    assert "uncalibrated" not in rows["glass.h5"]["flags"]
    assert rows["scalar.h5"]["status"] == "analysed", rows["scalar.h5"]
    # the polarimetric fit is the single-run pipeline's with the same options
    cal = calibration_folder(runs) / "lab-a.json"
    start = list(DEFAULT_START)
    start[2:4] = [0.2, 0.2]
    alone = fit_polarimetric_run(glass, calibration=cal, start=start, fixed=("k",),
                                 report=False, write=False).summary["pbrdf"]
    assert alone["variant"] == "fixed by the user" and alone["fixed"] == ["k"]
    for name, value in zip(alone["param_names"], alone["params"], strict=True):
        if name != "k":
            assert float(rows["glass.h5"][name]) == pytest.approx(value, rel=1e-9)
    assert "k" not in rows["glass.h5"] or rows["glass.h5"]["k"] == ""  # held, not fitted
    with h5py.File(results_dir(glass, "fit") / "results.h5") as f:
        g = f["entry/analysis"]
        assert g.attrs["calibrated"]
        assert g["pbrdf"].attrs["variant"] == "fixed by the user"
    # the batch recorded the options, and the same batch again finds the run done
    assert _options(tmp_path)["polarimetric"] == {
        "calibration": "lab-a", "start": start, "fixed": ["k"], "distribution": "beckmann"}
    assert _statuses(glass, tmp_path / "again", "alpha=0.2,albedo=0.2") == ["skipped"]
    # other start values are other options: fitted again
    assert _statuses(glass, tmp_path / "other", "alpha=0.25,albedo=0.2") == ["analysed"]


def _statuses(run: Path, summary: Path, start: str) -> list[str]:
    """The statuses of a batch fit of ``run`` with calibration lab-a, k held and ``start``."""
    assert main(["batch", "fit", str(run), "--workers", "0", "--calibration", "lab-a",
                 "--pbrdf-start", start, "--pbrdf-fixed", "k", "--summary-dir",
                 str(summary)]) == 0
    (table,) = summary.glob("batch-fit-*.csv")
    with open(table, newline="", encoding="utf-8") as fh:
        return [r["status"] for r in csv.DictReader(fh)]


def _options(folder: Path) -> dict:
    """The options the batch's HTML summary records (its 'options' line)."""
    (page,) = folder.glob("batch-fit-*.html")
    found = re.search(r"<li><b>options</b>: (.*?)</li>", page.read_text(encoding="utf-8"))
    assert found is not None
    return json.loads(html.unescape(found.group(1)))


@pytest.mark.slow  # the run made once (see above); nothing is fitted here
@pytest.mark.parametrize(("argv", "words"), [
    (["--calibration", "lab-b"], "no polarimeter calibration of that name in"),
    (["--calibration", "other-bench"], "calibrates bench 'elsewhere', run glass.h5 was "
                                       "taken on 'sim-polarimetric'"),
    (["--pbrdf-start", "alfa=0.3"], "--pbrdf-start: no pBRDF parameter 'alfa'"),
    (["--pbrdf-fixed", "kappa"], "--pbrdf-fixed: no pBRDF parameter 'kappa'"),
])
def test_a_bad_calibration_or_pbrdf_option_stops_the_batch_with_nothing_written(
        glass_and_scalar, tmp_path, capsys, argv, words):
    runs = _copy(glass_and_scalar, tmp_path / "runs")
    _calibration("elsewhere", calibration_folder(runs), "other-bench.json")
    before = _written(runs)
    summary = tmp_path / "summary"
    assert main(["batch", "fit", str(runs / "scalar.h5"), str(runs / "glass.h5"),
                 "--workers", "0", "--summary-dir", str(summary), *argv]) == 2
    out = capsys.readouterr().out
    assert out.startswith("error: ") and words in out, out
    assert _written(runs) == before  # no results folder, no record beside either run
    assert not summary.exists()


@pytest.mark.slow  # the run made once (see above) and one fit
def test_fit_takes_the_same_calibration_name_and_start_values(glass_and_scalar, tmp_path,
                                                              capsys):
    runs = _copy(glass_and_scalar, tmp_path / "runs")
    glass = runs / "glass.h5"
    assert main(["fit", str(glass), "--calibration", "lab-a", "--pbrdf-start",
                 "1.5,0,0.2,0.2", "--pbrdf-fixed", "k,frame_deg", "--no-write"]) == 0
    out = capsys.readouterr().out
    cal = calibration_folder(runs) / "lab-a.json"
    assert f"calibrated with {cal}" in out
    lines = {ln.split()[0]: ln for ln in out.splitlines() if ln.startswith("  ") and
             ln.split() and ln.split()[0] in ("n", "k", "alpha", "albedo", "frame_deg")}
    for name in ("k", "frame_deg"):  # held at the start values given
        assert lines[name].endswith("(fixed)") and float(lines[name].split()[1]) == 0.0
    assert not lines["alpha"].endswith("(fixed)")
    assert main(["fit", str(glass), "--calibration", "lab-b", "--no-write"]) == 2
    assert "no polarimeter calibration of that name" in capsys.readouterr().out
