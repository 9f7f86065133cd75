"""Engine overhead per point: scatterlab's RunEngine against Bluesky's, same grid.

A two-axis grid (sample_theta × detector_theta) of N points on zero-latency devices:
scatterlab runs it on hw_mocks.sim.ideal devices (moves, a power-meter reading per point,
storage of every scalar reading in the HDF5 run file and its journal); Bluesky runs
``grid_scan([det], motor1, ..., motor2, ...)`` with ophyd.sim's SynAxis/SynGauss and its
documents collected in memory by a subscriber. Both in the same benchmark run; Bluesky
runs in its own environment (``--bluesky-python``, default benchvenv/bin/python, a
virtual environment in the repository root that holds bluesky and ophyd),
so it is never a dependency of scatterlab.

    python benchmarks/bench_engine.py            # 1,000 and 10,000 points
    python benchmarks/bench_engine.py --quick    # 1,000 points
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from instrument.plans import build_plan, parse_plan  # noqa: E402
from instrument.run.runner import start_run  # noqa: E402
from tests.instrument.helpers import ideal_bench  # noqa: E402

BLUESKY = r"""
import json, sys, time
from bluesky import RunEngine
from bluesky.plans import grid_scan
from ophyd.sim import det, motor1, motor2
n_side = int(sys.argv[1])
RE = RunEngine({})
docs = []
RE.subscribe(lambda name, doc: docs.append((name, doc)))
best = None
for _ in range(int(sys.argv[2])):
    docs.clear()
    t = time.perf_counter()
    RE(grid_scan([det], motor1, 0, 1, n_side, motor2, 0, 1, n_side, snake_axes=False))
    dt = time.perf_counter() - t
    best = dt if best is None else min(best, dt)
print(json.dumps({"seconds": best, "events": sum(1 for n, _ in docs if n == "event")}))
"""


def grid_plan(n_side: int) -> str:
    """n_side × n_side points: θi in 0.01° steps from 10°, θr in equal steps 40°..80°."""
    theta_i = [round(10.0 + 0.01 * k, 6) for k in range(n_side)]
    theta_r = [round(40.0 + 40.0 * k / (n_side - 1), 9) for k in range(n_side)]
    return f"""
[plan]
kind = "brdf_in_plane"
name = "overhead grid"
order = "raster"
[sample]
name = "bench"
[scan]
theta_i = {theta_i}
theta_r = {theta_r}
[acquisition]
detectors = ["power_meter"]
"""


def run_scatterlab(n_side: int, repeats: int) -> dict:
    best = None
    n = 0
    for _ in range(repeats):
        bench = ideal_bench()
        plan = build_plan(parse_plan(grid_plan(n_side)), bench.profile)
        n = len(plan.points)
        with tempfile.TemporaryDirectory() as tmp:
            engine = start_run(plan, bench, runs_dir=tmp, fsync=False, catalog=False)
            t = time.perf_counter()
            engine.run()
            dt = time.perf_counter() - t
            assert engine.n_done == n, "not every point was stored"
        best = dt if best is None else min(best, dt)
    return {"seconds": best, "points": n}


def run_bluesky(python: str, n_side: int, repeats: int) -> dict | None:
    if not Path(python).exists():
        return None
    out = subprocess.run([python, "-c", BLUESKY, str(n_side), str(repeats)],
                         capture_output=True, text=True, timeout=1800)
    if out.returncode != 0:
        print(out.stderr, file=sys.stderr)
        return None
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1,000 points only, one repeat")
    ap.add_argument("--bluesky-python", default="benchvenv/bin/python")
    args = ap.parse_args()
    # 32 × 32 = 1,024 and 100 × 100 = 10,000 points; Bluesky runs the same grids.
    sides = [32] if args.quick else [32, 100]
    repeats = 1 if args.quick else 3
    print(f"{'points':>7} {'scatterlab us/pt':>17} {'bluesky us/pt':>14} {'ratio':>7}")
    for n_side in sides:
        ours = run_scatterlab(n_side, repeats)
        theirs = run_bluesky(args.bluesky_python, n_side, repeats)
        us = 1e6 * ours["seconds"] / ours["points"]
        if theirs is None:
            print(f"{ours['points']:>7} {us:>17.1f} {'(no bluesky)':>14}")
            continue
        them = 1e6 * theirs["seconds"] / theirs["events"]
        print(f"{ours['points']:>7} {us:>17.1f} {them:>14.1f} {them / us:>6.1f}x")


if __name__ == "__main__":
    main()
