"""``scatterlab fit`` on polarimetric runs over several seeds: pulls of the Mueller elements
against the world's truth, uncalibrated and with the calibration that ``scatterlab calibrate
polarimeter`` measures on the references, and of the pBRDF parameters (calibrated) against
the hidden sample.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_polarimetric_fit.py --seeds 3

Each seed is one engine run on ``sim-polarimetric`` (mounts 100× faster than the built-in
profile's; the power meter's noise seed changes) of the glass at θi 50°, θr 40° and 50°,
25 steps per geometry, then the reference scans of the calibration. Prints the pull spread
and the fraction within 2σ.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from instrument.cli import main
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from tests.instrument.pipelines.polarimetry.closed_loop import (
    fast_bench,
    plan_text,
    pulls,
    run_with_truth,
)

TRUTH = (1.5, 0.0, 0.15, 0.3)


def one(seed: int, folder: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """One seed: the glass run, the calibration measured on the references, both fits.
    Returns the uncalibrated and calibrated pulls, the pBRDF pulls and the calibration's
    wall time."""
    sub = folder / f"seed{seed}"
    sub.mkdir()
    bench = fast_bench(sub, seed=seed)
    path, truths = run_with_truth(sub, bench, plan_text("glass", "50.0", "40.0, 50.0"))
    out = path.parent
    t0 = time.perf_counter()
    assert main(["calibrate", "polarimeter", "--bench", str(bench), "--out", str(out),
                 "--steps", "25", "--no-fsync"]) == 0
    t_cal = time.perf_counter() - t0
    found = []
    for which in ("none", None):
        done = fit_polarimetric_run(path, calibration=which, report=False, write=False)
        found.append(np.concatenate([
            pulls(p, truths[(round(p.group.theta_i), round(p.group.theta_r))])
            for p in done.points]))
    fit = done.summary["pbrdf"]
    par = np.array([(fit["params"][k] - TRUTH[k]) / fit["stderr"][k] for k in (0, 2, 3)])
    return found[0], found[1], par, t_cal


def main_() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    t0 = time.perf_counter()
    unc, cal, par, t_cal = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            u, c, p, t = one(seed, Path(tmp))
            unc.append(u)
            cal.append(c)
            par.append(p)
            t_cal.append(t)
    u, c, p = np.concatenate(unc), np.concatenate(cal), np.array(par)
    print(f"{args.seeds} seeds × 2 geometries × 15 normalised elements "
          f"({time.perf_counter() - t0:.0f} s wall)")
    print(f"  calibrate polarimeter (4 reference scans × 25 steps): "
          f"{np.median(t_cal):.0f} s wall per seed (median)")
    for name, x in (("uncalibrated", u), ("calibrated (measured)", c)):
        print(f"  {name:<30} pull spread {np.std(x):6.2f}  max |pull| {np.max(np.abs(x)):6.1f}"
              f"  within 2σ {np.mean(np.abs(x) < 2):.0%}")
    print("  pBRDF (calibrated) pulls n, alpha, albedo per seed:")
    for row in p:
        print("    " + "  ".join(f"{v:+.2f}" for v in row))
    print(f"  within 2σ {np.mean(np.abs(p) < 2):.0%}")


if __name__ == "__main__":
    main_()
