"""Soak: 100,000 points on zero-latency devices; memory and per-point time must stay flat.

The run stores every point (positions, angles, a power reading) in its HDF5 file and
journal, exactly like a real run. Every 10,000 points the resident memory (VmRSS) and
the mean time per point of the last window are recorded.

    python benchmarks/bench_soak.py            # 100,000 points
    python benchmarks/bench_soak.py --quick    # 20,000 points
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from instrument.plans import build_plan, parse_plan  # noqa: E402
from instrument.run.events import Progress  # noqa: E402
from instrument.run.runner import start_run  # noqa: E402
from tests.instrument.helpers import ideal_bench  # noqa: E402


def rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def plan_text(n: int) -> str:
    rows = n // 500
    theta_i = [round(5.0 + 0.001 * k, 6) for k in range(rows)]
    theta_r = [round(20.0 + 60.0 * k / 499, 9) for k in range(500)]
    return f"""
[plan]
kind = "brdf_in_plane"
name = "soak"
order = "raster"
[sample]
name = "soak"
[scan]
theta_i = {theta_i}
theta_r = {theta_r}
[acquisition]
detectors = ["power_meter"]
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20,000 points")
    ap.add_argument("--window", type=int, default=10000)
    args = ap.parse_args()
    n = 20000 if args.quick else 100000
    bench = ideal_bench()
    plan = build_plan(parse_plan(plan_text(n)), bench.profile)
    rows = []
    last = {"t": 0.0, "n": 0}

    def on(ev) -> None:
        if isinstance(ev, Progress) and ev.n_done % args.window == 0:
            now = time.perf_counter()
            dt = (now - last["t"]) / (ev.n_done - last["n"])
            rows.append((ev.n_done, 1e6 * dt, rss_mib()))
            last.update(t=now, n=ev.n_done)

    with tempfile.TemporaryDirectory() as tmp:
        engine = start_run(plan, bench, runs_dir=tmp, fsync=False, catalog=False)
        engine.subscribe(on)
        start_rss = rss_mib()
        last["t"] = time.perf_counter()
        t0 = last["t"]
        engine.run()
        total = time.perf_counter() - t0
        size = engine.store.path.stat().st_size
    print(f"{len(plan.points)} points in {total:.1f} s ({1e6 * total / len(plan.points):.1f} "
          f"us/point); RSS at start {start_rss:.1f} MiB; run file {size / 2**20:.1f} MiB")
    print(f"{'points':>8} {'us/point (window)':>18} {'RSS MiB':>8}")
    for n_done, us, rss in rows:
        print(f"{n_done:>8} {us:>18.1f} {rss:>8.1f}")
    first, lastrow = rows[0], rows[-1]
    print(f"per-point time last/first window: {lastrow[1] / first[1]:.2f}; "
          f"RSS growth after the first window: {lastrow[2] - first[2]:+.1f} MiB")


if __name__ == "__main__":
    main()
