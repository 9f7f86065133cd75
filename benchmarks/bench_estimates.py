"""Duration estimates against actual runs: every example plan on its emulated bench.

For each plan in ``examples/`` the plan is built for its bench (``scatterlab plan``), its
estimate taken (what ``scatterlab plan`` prints and the run's first line says), and the plan
run through the engine exactly as ``scatterlab run`` does (real drivers, emulated
controllers on their scaled clocks, the simulated camera, fsync per point), in a temporary
folder. Reported: the estimate the run announced when it started (the console's first
line: the plan's estimate on this bench plus the homing of axes not homed yet) with its
parts, the run's duration from the engine's start to its end (the console's "run
finished ... in" line), and their ratio; and the load average of the machine meanwhile
(the simulated camera computes its frames, so a loaded machine runs slower).

    python benchmarks/bench_estimates.py             # every example, once
    python benchmarks/bench_estimates.py --repeat 3  # the median of three runs each
    python benchmarks/bench_estimates.py --only sphere_capture lightfield_scan
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.transport import add_url_handler_package  # noqa: E402
from instrument.bench.devices import open_bench  # noqa: E402
from instrument.bench.profile import load_profile  # noqa: E402
from instrument.plans import build_plan, load_plan  # noqa: E402
from instrument.run.events import RunFinished, RunStarted  # noqa: E402
from instrument.run.runner import start_run  # noqa: E402

#: The bench each example is written for (the rest run on ``sim``).
BENCHES = {"brdf_hemisphere": "sim_out_of_plane", "lightfield_scan": "sim-lightfield",
           "sphere_capture": "sim-spheres", "brdf_spectral_lockin": "sim-spectral"}


def run_once(name: str, folder: Path) -> tuple[object, float, float, float]:
    """(the plan's estimate, the run's announced estimate in s, its duration in s, the
    process's CPU seconds meanwhile: the emulators and the simulated camera compute in this
    process, so on a shared box their CPU time is the measure that the load does not
    stretch)."""
    from hw_mocks import registry
    from hw_mocks.sim.world import reset_worlds

    registry.reset()  # freshly powered controllers (unhomed), as at a new session
    reset_worlds()
    profile = load_profile(BENCHES.get(name, "sim"))
    plan = build_plan(load_plan(ROOT / "examples" / f"{name}.toml"), profile)
    est = plan.estimate()
    done: list = []
    cpu0 = time.process_time()
    with open_bench(profile) as bench:
        engine = start_run(plan, bench, runs_dir=folder, catalog=False)
        engine.subscribe(lambda ev: done.append(ev)
                         if isinstance(ev, RunStarted | RunFinished) else None)
        engine.run()
    if len(done) != 2 or done[1].status != "finished":
        raise RuntimeError(f"{name}: the run did not finish: {done}")
    return est, done[0].estimated_s, done[1].elapsed_s, time.process_time() - cpu0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1, help="runs per plan (median reported)")
    ap.add_argument("--only", nargs="*", help="example names (default: all)")
    args = ap.parse_args()
    add_url_handler_package("hw_mocks.urlhandler")
    names = args.only or sorted(p.stem for p in (ROOT / "examples").glob("*.toml"))
    print("| plan | bench | points | estimate s (motion + acquisition and storage + homing) "
          "| actual s | estimate / actual | CPU s | estimate / CPU | load |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    worst = 0.0
    t0 = time.monotonic()
    for name in names:
        actual, cpu = [], []
        with tempfile.TemporaryDirectory() as tmp:
            for k in range(args.repeat):
                est, announced, seconds, cpu_s = run_once(name, Path(tmp) / str(k))
                actual.append(seconds)
                cpu.append(cpu_s)
        a, c = statistics.median(actual), statistics.median(cpu)
        ratio = announced / a
        worst = max(worst, abs(ratio - 1))
        homing = announced - est.total_s
        print(f"| {name} | {BENCHES.get(name, 'sim')} | {est.n_points} | {announced:.2f} "
              f"({est.bench_motion_s:.2f} + {est.bench_acquisition_s:.2f} + {homing:.2f}) "
              f"| {a:.2f} | {ratio:.2f} | {c:.2f} | {announced / c:.2f} "
              f"| {os.getloadavg()[0]:.1f} |", flush=True)
    print(f"\nlargest deviation {100 * worst:.0f} %; benchmark took "
          f"{time.monotonic() - t0:.0f} s")


if __name__ == "__main__":
    main()
