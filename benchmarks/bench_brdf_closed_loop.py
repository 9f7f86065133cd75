"""Closed-loop BRDF validation figures (issue 5 §5): coverage, model selection, σ vs scatter.

Three ground-truth samples scanned on the simulated bench (camera/scene/sensor code without
the motion emulators), reduced by the absolute method and fitted with BIC selection among
lambert, oren_nayar and lambert+ggx; see tests/instrument/test_closed_loop.py, which
asserts the same numbers.

Run: ``python benchmarks/bench_brdf_closed_loop.py [--quick] [--seeds N]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.brdf import get_model
from tests.instrument.sim_scan import SAMPLES
from tests.instrument.test_closed_loop import closed_loop


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="10 seeds per sample")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per sample (default 50)")
    args = ap.parse_args()
    n = args.seeds or (10 if args.quick else 50)
    print("| sample | truth | seeds | inside 2σ (per parameter) | all inside 2σ | right model "
          "| std of z | estimate spread / reported σ | time (s) |")
    print("|---|---|---:|---|---:|---:|---|---|---:|")
    for s in SAMPLES:
        t0 = time.perf_counter()
        st = closed_loop(s, range(n))
        dt = time.perf_counter() - t0
        names = get_model(s.model).param_names
        truth = ", ".join(f"{k}={v:g}" for k, v in zip(names, s.params, strict=True))

        def fmt(a: np.ndarray, pct: bool = False) -> str:
            return ", ".join(f"{x:.0%}" if pct else f"{x:.2f}" for x in a)

        print(f"| {s.name} | {s.model}: {truth} | {n} | {fmt(st.coverage_2sigma, True)} | "
              f"{st.joint_coverage:.0%} | {st.right_model:.0%} | {fmt(st.z_std)} | "
              f"{fmt(st.spread_over_sigma)} | {dt:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
