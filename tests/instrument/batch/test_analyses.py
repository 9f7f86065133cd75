"""The light-field and sphere analyses through ``scatterlab batch`` (here, ``--workers 0``):
the rows hold what the single-run commands compute, and the outputs go next to the run.

The runs come from the example plans on the emulated benches (firmware emulators, real
drivers, the engine), as in the pipelines' own end-to-end tests.
"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from instrument.batch.task import run_task
from instrument.cli import main
from instrument.cli.locate import locate_options
from instrument.cli.reconstruct import reconstruction_options
from instrument.cli.spheres import sphere_options
from instrument.pipelines.lightfield.locate import locate_run
from instrument.pipelines.lightfield.reconstruct import reconstruct_run
from instrument.pipelines.spheres.pipeline import analyse_run
from instrument.run.results import read_results_attrs, results_dir
from tests.instrument.batch.runs import parse_cli

ROOT = Path(__file__).resolve().parents[3]


def _scan(out: Path, plan: str, bench: str) -> Path:
    assert main(["run", str(ROOT / "examples" / plan), "--bench", bench, "--out", str(out),
                 "--no-fsync", "--quiet"]) == 0
    (run,) = out.glob("*.h5")
    return run


@pytest.fixture(scope="module")
def lightfield_run(tmp_path_factory) -> Path:
    return _scan(tmp_path_factory.mktemp("lf"), "lightfield_scan.toml", "sim-lightfield")


def _rows(folder: Path, analysis: str) -> list[dict]:
    (table,) = folder.glob(f"batch-{analysis}-*.csv")
    with open(table, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow  # five localisations and reconstructions with figures: about 50 s of CPU
def test_batch_reconstruct_and_locate_give_the_single_run_answers(lightfield_run, tmp_path,
                                                                  capsys):
    run = lightfield_run
    assert main(["batch", "reconstruct", str(run), "--n-theta", "96", "--workers", "0",
                 "--summary-dir", str(tmp_path)]) == 0
    (row,) = _rows(tmp_path, "reconstruct")
    args = parse_cli(["reconstruct", str(run), "--n-theta", "96"])
    from instrument.batch.analyses import reconstruct_arguments

    ref = reconstruct_run(run, write=False, **reconstruct_arguments(reconstruction_options(args)))
    assert row["status"] == "analysed" and row["recoverable"] == "True"
    assert float(row["highest_order"]) == ref.p_hat
    assert int(row["angles"]) == 96
    assert float(row["noise_per_sample"]) == ref.reconstruction.diagnostics.noise.sigma_per_sample
    figures = results_dir(run, "lightfield")
    assert (figures / "results.h5").is_file() and list(figures.glob("*.png"))
    # locate, from the reconstruction the results file holds (the one just made)
    assert main(["batch", "locate", str(run), "--workers", "0", "--no-report",
                 "--summary-dir", str(tmp_path)]) == 0
    (row,) = _rows(tmp_path, "locate")
    largs = parse_cli(["locate", str(run)])
    from instrument.batch.analyses import locate_arguments

    loc = locate_run(run, write=False, **locate_arguments(locate_options(largs)))
    det = loc.detection
    assert int(row["objects"]) == det.count >= 1
    assert float(row["object0_y_mm"]) == float(det.positions_mm[0][0])
    assert float(row["object0_z_mm"]) == float(det.positions_mm[0][1])
    assert row["object0_quality"] == det.quality[0]
    # the pipeline writes the results file, as the single-run command does
    assert read_results_attrs(run, "lightfield")["program"] == "scatterlab locate"
    # reconstruct's record was replaced by locate's (one results file per pipeline)
    assert main(["batch", "reconstruct", str(run), "--n-theta", "96", "--workers", "0",
                 "--summary-dir", str(tmp_path / "again")]) == 0
    assert "1 analysed" in capsys.readouterr().out
    # a localisation by the single-run command counts as done for the batch, and the
    # batch answers from the row the command kept
    assert main(["locate", str(run), "--no-figures"]) == 0
    capsys.readouterr()
    assert main(["batch", "locate", str(run), "--workers", "0", "--no-report",
                 "--summary-dir", str(tmp_path / "third")]) == 0
    assert "1 skipped" in capsys.readouterr().out
    (again,) = _rows(tmp_path / "third", "locate")
    assert again["status"] == "skipped" and again["object0_y_mm"] == row["object0_y_mm"]


@pytest.mark.slow  # a sphere capture through the engine: about 10 s
def test_batch_spheres_gives_the_single_run_answer(tmp_path):
    run = _scan(tmp_path / "sp", "sphere_capture.toml",
                str(ROOT / "instrument" / "bench" / "profiles" / "sim-spheres.toml"))
    args = parse_cli(["spheres", str(run), "--lmax", "12", "--lmax-check", "8"])
    opts = sphere_options(args)
    o = run_task("spheres", run, opts, report=True)
    _, res = analyse_run(run, write=False, **opts)
    assert o.status == "analysed", o.cause
    assert o.values["relighting_error"] == res.relight_l1 < 0.065
    assert o.values["consistency_statistic"] == res.consistency.statistic
    assert o.values["inconsistent"] is bool(res.consistency.inconsistent)
    assert (o.values["objects"], o.values["lightings"], o.values["lmax"]) == (2, 2, 12)
    assert (results_dir(run, "spheres") / "relighting.png").is_file()
    # a BRDF fit of a sphere capture does not apply
    assert run_task("fit", run, {}, report=False).status == "not applicable"
