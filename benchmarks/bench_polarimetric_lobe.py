"""A two-pass polarimetric lobe plan on ``sim-polarimetric``: what the planner promised for
the second pass, what one pass of equal time would have given, and what the joint pBRDF
fit recovered, with the time of each pass.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_polarimetric_lobe.py

The plan and bench are the slow test's
(``tests/instrument/pipelines/polarimetry/test_polarimetric_lobe_run.py``): θi 50°, a
first pass at θr 30–70° every 20° with the search of ±6° every 3° (seven geometries of 23
retarder steps), two geometries placed by Fisher information on the lobe, the hidden
optics as the calibration beside the runs.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

from instrument.cli import main as cli
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from tests.instrument.pipelines.polarimetry.test_polarimetric_lobe_run import drr_lobe_setup


def run_both_passes(folder: Path, bench: Path, text: str) -> Path:
    """Run the lobe plan ``text`` on ``bench`` into ``folder/runs`` as ``scatterlab run``
    does, printing what it says of the second pass and the time of both passes; returns
    the runs' folder. Shared with ``bench_polarimetric_spectral_lobe.py``."""
    runs = folder / "runs"
    plan = folder / "lobe.toml"
    plan.write_text(text, encoding="utf-8")
    out = io.StringIO()
    t0, c0 = time.perf_counter(), time.process_time()
    with contextlib.redirect_stdout(out):
        code = cli(["run", str(plan), "--bench", str(bench), "--out", str(runs),
                    "--no-fsync", "--quiet"])
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    assert code == 0, out.getvalue()
    for line in out.getvalue().splitlines():
        if line.startswith(("second pass", "  predicted", "  a single pass", "  the lobe",
                            "run finished")):
            print(line)
    print(f"both passes with the planning between them: {wall:.0f} s wall, {cpu:.0f} s CPU")
    return runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bench, text = drr_lobe_setup(folder)
        runs = run_both_passes(folder, bench, text)
        second = max(runs.glob("*.h5"))
        done = fit_polarimetric_run(second, report=False, write=False)
        fit = done.summary["pbrdf"]
        print(f"joint fit of {len(done.points)} geometries: {fit['variant']}, {fit['verdict']}")
        for name, v, s in zip(fit["param_names"], fit["params"], fit["stderr"], strict=True):
            print(f"  {name:10s} {v:.4f} ± {s:.4f}")


if __name__ == "__main__":
    main()
