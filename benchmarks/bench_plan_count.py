"""Refusing an oversized plan: counted from its axes, against generating its points.

A plan of 10 × 10⁶ in-plane angles (10⁷ points, ten times the limit) is refused by
:func:`instrument.plans.build_plan` before any point is made
(:mod:`instrument.plans.count`). Reported: the wall time of the refusal (best of
``--repeat``) and its peak of traced Python memory (``tracemalloc``); and, for scale, what
generating points costs (``_raw_points``, what ``build_plan`` did before counting, for a
plan of ``--generate`` points: its time untraced and its peak traced, and both extrapolated
linearly to 10⁷ points).

    python benchmarks/bench_plan_count.py
    python benchmarks/bench_plan_count.py --generate 100000 --repeat 5
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from instrument.bench.profile import load_profile  # noqa: E402
from instrument.plans import PlanError, build_plan, parse_plan  # noqa: E402
from instrument.plans.build import _raw_points  # noqa: E402

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "bench"
[sample]
name = "grey"
[scan]
theta_i = {theta_i}
theta_r = {{start = -80, stop = {stop!r}, step = {step!r}}}
"""


def in_plane(n_i: int, n_r: int) -> str:
    step = 160.0 / n_r
    theta_i = [5.0 * k for k in range(n_i)]
    return PLAN.format(theta_i=theta_i, stop=-80 + step * (n_r - 1), step=step)


def traced(fn):
    """(seconds, peak traced bytes) of ``fn``: timed in one call, traced in another
    (tracing slows every allocation)."""
    t0 = time.perf_counter()
    fn()
    dt = time.perf_counter() - t0
    tracemalloc.start()
    try:
        fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return dt, peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--generate", type=int, default=50_000,
                    help="points of the plan generated for scale (default 50000)")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    profile = load_profile("sim")
    huge = parse_plan(in_plane(10, 1_000_000))

    def refuse() -> None:
        try:
            build_plan(huge, profile)
        except PlanError:
            return
        raise AssertionError("the 10^7-point plan was not refused")

    refusals = [traced(refuse) for _ in range(args.repeat)]
    t_refuse = min(t for t, _ in refusals)
    peak_refuse = max(p for _, p in refusals)
    spec = parse_plan(in_plane(2, args.generate // 2))
    t_gen, peak_gen = traced(lambda: _raw_points(spec, profile))
    n = 2 * (args.generate // 2)
    load = os.getloadavg()[0]
    print(f"load average {load:.1f}")
    print("| what | points | wall s | peak traced MiB |")
    print("|---|---:|---:|---:|")
    print(f"| refuse (count) | 10000000 | {t_refuse:.6f} | {peak_refuse / 2**20:.3f} |")
    print(f"| generate | {n} | {t_gen:.2f} | {peak_gen / 2**20:.1f} |")
    print(f"| generate, extrapolated | 10000000 | {t_gen * 1e7 / n:.0f} | "
          f"{peak_gen * 1e7 / n / 2**20:.0f} |")


if __name__ == "__main__":
    main()
