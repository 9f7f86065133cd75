"""Does the lobe planner keep its promise? Predicted against delivered σ over seeds.

A two-pass lobe plan (:mod:`instrument.plans.lobe`) promises, before its second pass runs,
the σ of every parameter the fit of both passes will have. This script checks the promise
as ``scatterlab run`` makes it: per seed, the first pass (θi = 20°, 40°, 60°; θr every 20°
from −70° to 70° and ±4° around the mirror direction in 1° steps) is acquired with its own
sensor noise, read through the sim bench's neutral-density filters where the peak clips at
the shortest exposure (the engine's rule, ADR 0018; calibrated transmissions, their error
shared by the points of a filter, and each seed's calibrated values drawn about the
truth with their stated σ, so that the seed spread holds that shared error), fitted; the
second pass (24 points on a 0.25° grid) is placed by
:func:`~instrument.plans.lobe.place_points` with the fit's error budget
(:mod:`instrument.plans.lobe_budget`), acquired with another seed, and both passes are
fitted together as ``scatterlab fit`` does (forward model, shared filter errors
propagated).

Per parameter: the mean *predicted* σ, the mean σ the fits *report*, and the *delivered* σ
— the standard deviation of the fitted values over the seeds (its own relative standard
error is 1/√(2(N−1)), 16 % at 20 seeds). The promise holds when predicted/delivered is
within 0.7–1.3. The first line per α is the single-pass plan of equal time the planner
weighs the second pass against (:func:`~instrument.plans.lobe.single_pass_alternative`).

Scans are rendered without the motion emulators (tests/instrument/sim_scan.py): 96-px
camera integrating its pupil, beam 2 µW (the peak of a GGX α = 0.05 lobe clips at 10 µs
without a filter), auto-exposure to 50 % of full well capped at 10 ms, 20 ms readout.

Run: ``python benchmarks/bench_lobe_planner.py [--seeds 20] [--alphas 0.05,0.2]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.instrument.lobe_closed_loop import run_alpha


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--alphas", default="0.05,0.2")
    ap.add_argument("--power-w", type=float, default=2e-6)
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args()
    print("| α | parameter | σ predicted | σ reported (RMS) | σ delivered (seed spread) | "
          "predicted / delivered | mean − truth |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for alpha in (float(x) for x in args.alphas.split(",")):
        t0 = time.perf_counter()
        r = run_alpha(alpha, args.seeds, args.power_w, args.verbose)
        for k, name in enumerate(r["names"]):
            print(f"| {alpha:g} | {name} | {r['pred'][k]:.3g} | {r['reported'][k]:.3g} | "
                  f"{r['delivered'][k]:.3g} | {r['pred'][k] / r['delivered'][k]:.2f} | "
                  f"{r['bias'][k]:+.2g} |", flush=True)
        one, both_s = r["alt"][0]
        target = r["names"][-1]
        print(f"<!-- α = {alpha:g}: {r['seeds']} seeds, {time.perf_counter() - t0:.0f} s; "
              f"clipped readings {r['clipped'][0]} (first passes) + {r['clipped'][1]} "
              f"(second passes); {r['filtered']:.1f} second-pass points per seed through a "
              f"filter; seed-to-seed spread of the prediction {r['pred_spread'][-1]:.1%}; "
              f"single pass of equal time ({both_s:.0f} s): θr every "
              f"{one.theta_r_step_deg:g}°, {one.n_points} points, predicted σ({target}) "
              f"{one.sigma[target]:.3g} -->", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
