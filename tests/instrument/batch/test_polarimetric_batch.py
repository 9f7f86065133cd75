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
        "calibration": {"drr": "lab-a", "pem": "lab-a"}, "start": start, "fixed": ["k"],
        "distribution": "beckmann"}
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


# --- both polarimeter modes in one batch (ADR 0114, amendment) -----------------------------
#: The hidden PEM train of sim-polarimetric-pem in its calibration's frame (as
#: tests/instrument/pipelines/polarimetry/test_pem_calibration.py has it).
PEM_HIDDEN = np.array([1266.9 / 1230.0, 0.1, -0.7, math.pi / 2, -0.6])


def _pem_calibration(folder: Path, name: str) -> Path:
    from analysis.polarimetry.pem_calibration import PemCalibration

    cal = PolarimeterCalibration(
        drr=PemCalibration(params=PEM_HIDDEN, cov=np.diag([1e-8] * 5), chi2=100.0, dof=100,
                           psg_extinction=1e-5, psa_extinction=1e-5),
        bench="sim-polarimetric-pem", source_scale_w=1e-3, date="2026-11-27T00:00:00Z",
        quality="hidden train")
    return save_calibration(cal, folder, name=name)


@pytest.fixture(scope="module")
def pem_glass(tmp_path_factory) -> Path:
    """A PEM run of the glass at θi 50°, θr 40° and 50° (2 × 8 settings through the engine,
    on sim-polarimetric-pem with its misaligned train) with ``lab-p.json`` (its hidden
    train, mode "pem") and ``lab-a.json`` (a DRR's) beside it; made once per session."""
    from tests.instrument.run.test_pem_run import fast_pem_bench
    from tests.instrument.run.test_pem_run import plan_text as pem_plan

    def make(folder: Path) -> Path:
        (folder / "make").mkdir()
        plan = folder / "make" / "plan.toml"
        plan.write_text(pem_plan("glass pem", ti="50.0", tr="40.0, 50.0"), encoding="utf-8")
        bench = fast_pem_bench(folder / "make", None, ideal=False)
        assert main(["run", str(plan), "--bench", str(bench), "--out",
                     str(folder / "make" / "runs"), "--no-fsync", "--quiet"]) == 0
        (run,) = (folder / "make" / "runs").glob("*.h5")
        (folder / "runs").mkdir()
        shutil.copy2(run, folder / "runs" / "pem.h5")
        cals = calibration_folder(folder / "runs")
        _pem_calibration(cals, "lab-p.json")
        _calibration("sim-polarimetric", cals, "lab-a.json")
        return folder / "runs"
    return made_once(tmp_path_factory, "polbatch-pem", make)


def test_a_calibration_of_the_other_mode_stops_batch_fit_and_fit_by_run(pem_glass, tmp_path,
                                                                       capsys):
    runs = _copy(pem_glass, tmp_path / "runs")
    pem = runs / "pem.h5"
    before = _written(runs)
    # a DRR's calibration named for a PEM run: refused, the run named, nothing written
    # (before this, batch fit dropped the name for PEM runs and fitted them uncalibrated)
    assert main(["batch", "fit", str(pem), "--workers", "0", "--calibration", "lab-a",
                 "--summary-dir", str(tmp_path / "summary")]) == 2
    out = capsys.readouterr().out
    assert out.startswith("error: --calibration lab-a: ") and "calibrates a dual-rotating-" \
        "retarder polarimeter, run pem.h5 is a PEM run; give one calibration per mode " \
        "(--calibration drr=lab-a --calibration pem=NAME, or pem=none" in out, out
    assert _written(runs) == before and not (tmp_path / "summary").exists()
    # fit refuses it too, in the pipeline's words
    assert main(["fit", str(pem), "--calibration", "lab-a", "--no-write"]) == 2
    assert "(mode 'drr'); the run" in capsys.readouterr().out
    # the other mode's file named for its own mode only: the PEM run is not refused (its
    # calibration is the default, none beside it under polarimeter-*.json)
    from instrument.batch.polarimetric_options import check_runs, polarimetric_fit_options
    by_kind = check_runs([pem], polarimetric_fit_options(["drr=lab-a"]))
    assert by_kind.pem == [pem]
    assert check_runs([pem], polarimetric_fit_options(["drr=lab-a", "pem=lab-p"])).pem == [pem]


@pytest.mark.slow  # the DRR and PEM runs made once (see above) and both fits: 30-60 s
def test_a_batch_of_both_modes_takes_one_calibration_per_mode(glass_and_scalar, pem_glass,
                                                             tmp_path, capsys):
    runs = _copy(glass_and_scalar, tmp_path / "runs")
    shutil.copy2(pem_glass / "pem.h5", runs / "pem.h5")
    shutil.copy2(calibration_folder(pem_glass) / "lab-p.json",
                 calibration_folder(runs) / "lab-p.json")
    glass, pem = runs / "glass.h5", runs / "pem.h5"
    before = _written(runs)
    # one name over both modes: every run of the mode it does not calibrate is refused
    for name, refused, mode in (("lab-a", "pem.h5", "PEM"),
                                ("lab-p", "glass.h5", "dual-rotating-retarder")):
        assert main(["batch", "fit", str(glass), str(pem), "--workers", "0",
                     "--calibration", name, "--summary-dir", str(tmp_path / "s")]) == 2
        out = capsys.readouterr().out
        assert f"run {refused} is a {mode} run; give one calibration per mode" in out, out
        assert out.count(" is a ") == 1, out  # the run of the file's own mode is not named
    assert _written(runs) == before and not (tmp_path / "s").exists()
    # one per mode: each run reduced with its own
    assert main(["batch", "fit", str(glass), str(pem), "--workers", "0", "--calibration",
                 "drr=lab-a", "--calibration", "pem=lab-p", "--summary-dir",
                 str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "PEM" not in out  # no note: the PEM run took its calibration
    (table,) = tmp_path.glob("batch-fit-*.csv")
    with open(table, newline="", encoding="utf-8") as fh:
        rows = {Path(r["run"]).name: r for r in csv.DictReader(fh)}
    for name in ("glass.h5", "pem.h5"):
        assert rows[name]["status"] == "analysed", rows[name]
        assert rows[name]["calibrated"] == "True"
        assert "uncalibrated" not in rows[name]["flags"]
    cals = calibration_folder(runs)
    alone = fit_polarimetric_run(pem, calibration=cals / "lab-p.json", report=False,
                                 write=False).summary
    assert alone["calibration"] == str(cals / "lab-p.json")
    assert float(rows["pem.h5"]["chi2"]) == pytest.approx(alone["pbrdf"]["chi2"], rel=1e-9)
    with h5py.File(results_dir(pem, "fit") / "results.h5") as f:
        assert f["entry/analysis"].attrs["calibrated"]
    assert _options(tmp_path)["polarimetric"]["calibration"] == {"drr": "lab-a",
                                                                  "pem": "lab-p"}
    # the same batch again finds both done (the record of a PEM run names its calibration)
    again = tmp_path / "again"
    assert main(["batch", "fit", str(glass), str(pem), "--workers", "0", "--calibration",
                 "drr=lab-a", "--calibration", "pem=lab-p", "--summary-dir",
                 str(again)]) == 0
    (table,) = again.glob("batch-fit-*.csv")
    with open(table, newline="", encoding="utf-8") as fh:
        assert [r["status"] for r in csv.DictReader(fh)] == ["skipped", "skipped"]
