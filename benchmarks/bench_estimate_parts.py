"""What an emulated run spends its CPU on, counted and timed per event, against the estimate.

Runs one example plan through the engine on its emulated bench, as
``benchmarks/bench_estimates.py`` does, and counts and times (process CPU seconds, which
a loaded shared box does not stretch the way it stretches wall time) the simulated
bench's computations that a duration estimate has to cover:

* the scattered-light integrals over a detector aperture
  (``GoniometerScene.power_on_aperture``: the power meter's head, the lock-in's
  photodiode, one integral per world state and two for the lock-in with the light on);
* the simulated camera's renders of a new view (``SimulatedCamera.photon_rate`` when it
  is not cached) and its frames (``SimulatedCamera._capture``, the noise synthesis
  included), with the exposures the frames were taken at.

Prints the counts, the mean CPU seconds per event, and the estimate's parts
(:meth:`instrument.plans.build.Plan.estimate`) with the run's wall and CPU time.

    python benchmarks/bench_estimate_parts.py calibration_nd
    python benchmarks/bench_estimate_parts.py brdf_spectral_lockin --bench sim-spectral
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.transport import add_url_handler_package  # noqa: E402
from hw_mocks.sim import photodiode  # noqa: E402
from hw_mocks.sim.camera import SimulatedCamera  # noqa: E402
from hw_mocks.sim.goniometer_scene import GoniometerScene  # noqa: E402
from instrument.bench.devices import open_bench  # noqa: E402
from instrument.bench.profile import load_profile  # noqa: E402
from instrument.plans import build_plan, load_plan  # noqa: E402
from instrument.run.engine import RunEngine  # noqa: E402
from instrument.run.runner import start_run  # noqa: E402

COUNTS: collections.Counter = collections.Counter()
CPU: collections.Counter = collections.Counter()
EXPOSURES: list[tuple[float, bool]] = []
#: Which detector's integral is being computed in this thread (the lock-in's photodiode
#: and the power meter's head integrate over the same aperture).
_CALLER = threading.local()


def _timed(name: str, fn, clock=time.process_time, counts=COUNTS, totals=CPU):
    """``fn`` counting its calls and the seconds of ``clock`` they take under ``name``."""
    def wrapper(*args, **kwargs):
        t0 = clock()
        try:
            return fn(*args, **kwargs)
        finally:
            counts[name] += 1
            totals[name] += clock() - t0
    return wrapper


WALL: collections.Counter = collections.Counter()
WALL_N: collections.Counter = collections.Counter()
#: The engine's stages timed on the wall clock (they run one after another in its thread).
STAGES = ("_move", "_set_light", "_select_filter", "_frame", "_read_power", "_read_lockin",
          "_read_lockin_dark", "_submit", "_commit_wait_or_pause")


def _instrument() -> None:
    for name in STAGES:
        setattr(RunEngine, name, _timed(name, getattr(RunEngine, name), time.monotonic,
                                         WALL_N, WALL))
    integral = GoniometerScene.power_on_aperture
    timed = {(who, on): _timed(f"aperture integral, {who}, light {'on' if on else 'off'}",
                               integral)
             for who in ("power meter", "lock-in") for on in (True, False)}

    def split_integral(self, center, facing, diameter_mm, state, *args, **kwargs):
        who = getattr(_CALLER, "who", "power meter")
        return timed[who, bool(state.source.on)](self, center, facing, diameter_mm, state,
                                                 *args, **kwargs)
    GoniometerScene.power_on_aperture = split_integral
    split = photodiode.split_power_w

    def lockin_split(*args, **kwargs):
        _CALLER.who = "lock-in"
        try:
            return split(*args, **kwargs)
        finally:
            _CALLER.who = "power meter"
    photodiode.split_power_w = lockin_split
    render = SimulatedCamera._render
    lit = _timed("camera render (new view), light on", render)
    dark = _timed("camera render (new view), light off", render)

    def split_render(self, state, roi):
        return (lit if state.source.on else dark)(self, state, roi)
    SimulatedCamera._render = split_render
    capture = SimulatedCamera._capture

    def counted_capture(self):
        EXPOSURES.append((float(self._exposure_us), bool(self.world.snapshot().source.on)))
        return capture(self)
    SimulatedCamera._capture = _timed("camera frame (render included)", counted_capture)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("example", help="name of a plan in examples/")
    ap.add_argument("--bench", default="sim")
    args = ap.parse_args()
    add_url_handler_package("hw_mocks.urlhandler")
    from hw_mocks import registry
    from hw_mocks.sim.world import reset_worlds

    _instrument()
    registry.reset()
    reset_worlds()
    profile = load_profile(args.bench)
    plan = build_plan(load_plan(ROOT / "examples" / f"{args.example}.toml"), profile)
    est = plan.estimate()
    with tempfile.TemporaryDirectory() as tmp, open_bench(profile) as bench:
        engine = start_run(plan, bench, runs_dir=Path(tmp), catalog=False)
        w0, c0 = time.monotonic(), time.process_time()
        engine.run()
        wall, cpu = time.monotonic() - w0, time.process_time() - c0
    print(f"{args.example} on {args.bench}: {est.n_points} points; estimate "
          f"{est.total_s:.2f} s (motion {est.bench_motion_s:.2f} + acquisition and storage "
          f"{est.bench_acquisition_s:.2f}); run {wall:.2f} s wall, {cpu:.2f} s CPU; "
          f"load {os.getloadavg()[0]:.1f}")
    for line in est.predicted:
        print("  estimate:", line)
    print("| event | count | CPU s each | CPU s total |")
    print("|---|---:|---:|---:|")
    for name in sorted(COUNTS):
        n = COUNTS[name]
        print(f"| {name} | {n} | {CPU[name] / n:.4f} | {CPU[name]:.2f} |")
    print("| engine stage (wall clock) | calls | s each | s total |")
    print("|---|---:|---:|---:|")
    for name in STAGES:
        if WALL_N[name]:
            print(f"| {name} | {WALL_N[name]} | {WALL[name] / WALL_N[name]:.4f} "
                  f"| {WALL[name]:.2f} |")
    print("frames in order (exposure µs, + lit, - dark):",
          " ".join(f"{e:g}{'+' if on else '-'}" for e, on in EXPOSURES))


if __name__ == "__main__":
    main()
