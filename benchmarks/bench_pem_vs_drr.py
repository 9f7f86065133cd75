"""PEM against dual rotating retarder on the same glass and geometries: σ of the normalised
Mueller elements and the scan time.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_pem_vs_drr.py --seeds 2

Each seed is one engine run per polarimeter of the glass (n = 1.5, rms slope 0.15, albedo
0.3) at θi 50°, θr 40° and 50°: the DRR with 25 steps per geometry on ``sim-polarimetric``
(mounts 100× faster, the meter's noise seed varied), the PEM with its 2 × 4 settings on
``sim-polarimetric-pem`` (mounts 10× faster; the lock-in's seed varied, its waits advancing
its emulated clock without sleeping). Both are reduced with their nominal train
(``--calibration none``: the DRR bench's hidden misalignment biases its elements, which
the pulls show; σ does not depend on it). The scan time is the planner's estimate on each
built-in profile: the motion on real stages plus the bench's acquisition (the lock-in's
settles are real waits on either bench).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from instrument.bench.profile import load_profile
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from instrument.plans import build_plan
from instrument.plans.planfile import parse_plan
from tests.instrument.pipelines.polarimetry.closed_loop import (
    fast_bench,
    plan_text,
    pulls,
    run_with_truth,
)
from tests.instrument.run.test_pem_run import fast_pem_bench
from tests.instrument.run.test_pem_run import plan_text as pem_plan_text

GEOMETRY = ("50.0", "40.0, 50.0")


def _fit(path: Path, truths: dict[tuple[int, int], np.ndarray]
         ) -> tuple[np.ndarray, np.ndarray]:
    done = fit_polarimetric_run(path, calibration="none", report=False, write=False)
    sig = np.concatenate([p.brdf.sigma_normalised.ravel()[1:] for p in done.points])
    pull = np.concatenate([pulls(p, truths[(round(p.group.theta_i), round(p.group.theta_r))])
                           for p in done.points])
    return sig, pull


def one(seed: int, folder: Path) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
    out = {}
    sub = folder / f"drr{seed}"
    sub.mkdir()
    t0 = time.perf_counter()
    path, truths = run_with_truth(sub, fast_bench(sub, seed=seed),
                                  plan_text("glass", *GEOMETRY))
    out["drr"] = (*_fit(path, truths), time.perf_counter() - t0)
    sub = folder / f"pem{seed}"
    sub.mkdir()
    t0 = time.perf_counter()
    path, truths = run_with_truth(sub, fast_pem_bench(sub, seed=seed),
                                  pem_plan_text("glass", *GEOMETRY), steps=8,
                                  world_name="sim-polarimetric-pem", frame_deg=0.0)
    out["pem"] = (*_fit(path, truths), time.perf_counter() - t0)
    return out


def estimates() -> dict[str, tuple[float, float, int]]:
    """(motion on real stages, the bench's acquisition, points) of each plan on its
    built-in profile."""
    found = {}
    for mode, text, bench in (("drr", plan_text("glass", *GEOMETRY), "sim-polarimetric"),
                              ("pem", pem_plan_text("glass", *GEOMETRY),
                               "sim-polarimetric-pem")):
        est = build_plan(parse_plan(text), load_profile(bench)).estimate()
        found[mode] = (est.motion_s, est.bench_acquisition_s or 0.0, est.n_points)
    return found


def main_() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=2)
    args = ap.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, args.seeds + 1):
            runs.append(one(seed, Path(tmp)))
    est = estimates()
    print("| | points | median σ(m_ij/m00) | max σ | pull spread | within 2σ | "
          "motion (real stages) | acquisition | emulated run + fit wall |")
    print("|---|---|---|---|---|---|---|---|---|")
    for mode in ("drr", "pem"):
        sig = np.concatenate([r[mode][0] for r in runs])
        pull = np.concatenate([r[mode][1] for r in runs])
        wall = float(np.median([r[mode][2] for r in runs]))
        motion, acq, n = est[mode]
        print(f"| {mode} | {n} | {np.median(sig):.2e} | {sig.max():.2e} | "
              f"{np.std(pull):.2f} | {np.mean(np.abs(pull) < 2):.0%} | {motion:.0f} s | "
              f"{acq:.0f} s | {wall:.0f} s |")


if __name__ == "__main__":
    main_()
