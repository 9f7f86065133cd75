"""Dual-rotating-retarder polarimetry: condition number and Mueller-element σ against the
number of steps and the retardance, the speed/accuracy trade of a polarimetric scan.

For each step count K (equal steps θ_k = 180°·k/K, ratio 1:5) and retardance δ (both
retarders alike): the condition number of W (:func:`analysis.polarimetry.condition_number`)
and the σ of the 16 Mueller elements for unit intensity noise (√diag((WᵀW)⁻¹), the
reduction's covariance; it does not depend on the sample). ``σ·√K`` is the figure of merit
at equal scan time per step: constant once the scheme is well sampled. The scan time is
K × ``--step-s`` (stage moves and integration per step, an assumption given on the command
line). A Monte Carlo check (``--mc`` seeds) compares the predicted σ with the scatter of
reduced matrices at 36 steps, and the reduction, decomposition and realizability test are
timed.

Run: ``python benchmarks/bench_polarimetry.py [--step-s 1.5] [--mc 200]``
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from analysis.polarimetry import (
    condition_number,
    decompose,
    depolariser,
    drr_angles,
    instrument_matrix,
    linear_retarder,
    realizability,
    reduce,
)

STEPS = (16, 20, 23, 25, 30, 36, 48, 60, 72)
RETARDANCES_DEG = (90.0, 110.0, 127.0, 132.0, 150.0)


def _w(steps: int, delta: float) -> np.ndarray:
    g, a = drr_angles(steps)
    return instrument_matrix(g, a, psg_retardance=delta, psa_retardance=delta)


def table(step_s: float) -> None:
    print(f"{'steps':>5} {'scan s':>7} {'δ °':>6} {'cond':>8} {'σ mean':>8} {'σ max':>8} "
          f"{'σ·√K':>7}")
    for steps in STEPS:
        for deg in RETARDANCES_DEG:
            w = _w(steps, math.radians(deg))
            cond = condition_number(w)
            if math.isfinite(cond):
                sig = np.sqrt(np.diag(np.linalg.inv(w.T @ w)))
                row = f"{cond:8.3f} {sig.mean():8.3f} {sig.max():8.3f} " \
                      f"{sig.mean() * math.sqrt(steps):7.2f}"
            else:
                row = f"{'inf':>8} {'—':>8} {'—':>8} {'—':>7}"
            print(f"{steps:5d} {steps * step_s:7.1f} {deg:6.1f} {row}")


def monte_carlo(seeds: int) -> None:
    w = _w(36, math.radians(127.0))
    truth = depolariser(1.0, 0.6) @ linear_retarder(0.4, 1.0)
    noise = 1e-3
    est0 = reduce(w @ truth.ravel(), noise, w)
    draws = np.array([reduce(w @ truth.ravel()
                             + noise * np.random.default_rng(s).standard_normal(36),
                             noise, w).m for s in range(seeds)])
    ratio = draws.std(axis=0, ddof=1) / est0.sigma
    print(f"\nMonte Carlo, 36 steps, δ = 127°, {seeds} seeds: empirical/predicted σ over the "
          f"16 elements: mean {ratio.mean():.3f}, min {ratio.min():.3f}, max {ratio.max():.3f}")


def timings() -> None:
    w = _w(36, math.radians(127.0))
    truth = depolariser(1.0, 0.6) @ linear_retarder(0.4, 1.0)
    y = w @ truth.ravel() + 1e-3 * np.random.default_rng(0).standard_normal(36)
    n = 200
    t0 = time.perf_counter()
    for _ in range(n):
        est = reduce(y, 1e-3, w)
    t1 = time.perf_counter()
    for _ in range(20):
        decompose(est.m, est.cov)
    # a pure element: its smallest coherency eigenvalue is negative about half the time,
    # which is when the bootstrap runs (seed 1 gives one)
    pure = linear_retarder(0.4, 1.0)
    y_pure = w @ pure.ravel() + 1e-3 * np.random.default_rng(1).standard_normal(36)
    est_pure = reduce(y_pure, 1e-3, w)
    t2 = time.perf_counter()
    for _ in range(20):
        res = realizability(est_pure.m, est_pure.cov)
    t3 = time.perf_counter()
    print(f"\nper matrix: reduce {1e3 * (t1 - t0) / n:.3f} ms, decompose with σ "
          f"{1e3 * (t2 - t1) / 20:.2f} ms, realizability (2000 draws) "
          f"{1e3 * (t3 - t2) / 20:.2f} ms (pure element, p = {res.p_value:.2f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--step-s", type=float, default=1.5,
                    help="seconds per DRR step (moves + integration), for the scan time")
    ap.add_argument("--mc", type=int, default=200, help="Monte Carlo seeds")
    args = ap.parse_args()
    table(args.step_s)
    monte_carlo(args.mc)
    timings()


if __name__ == "__main__":
    main()
