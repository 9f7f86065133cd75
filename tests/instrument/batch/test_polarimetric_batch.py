"""``scatterlab batch fit`` on polarimetric runs (here, ``--workers 0``): each run goes
through the polarimetric pipeline, as ``scatterlab fit`` sends it, and its row holds the
chosen pBRDF variant with the parameters the single-run pipeline finds."""

from __future__ import annotations

import csv
from pathlib import Path

import h5py
import pytest

from instrument.cli import main
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from instrument.run.results import results_dir
from tests.instrument.pipelines.polarimetry.closed_loop import fast_bench, plan_text

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
