"""The README's main job, timed by stage: ``scatterlab run examples/brdf_inplane.toml`` on
the ``sim`` bench (real drivers over the firmware emulators, the simulated 1024² camera),
run in this process exactly as the command runs it, with clocks around the stages that
cost: the camera's rendering of a new view, the sensor's noise synthesis per frame, the
storage of each point (HDF5 + journal, fsync'd). The rest is the engine, the drivers, the
emulators' clocks and the power meter. Wall time from the run's start to its end, CPU
time of the whole process (all threads).

    python benchmarks/bench_main_job.py                       # fast renderer, 3 runs
    python benchmarks/bench_main_job.py --renderer reference  # the exhaustive renderer
    python benchmarks/bench_main_job.py --repeat 1

The renderer is chosen by handing it to every ``SimulatedCamera`` the run opens (the
bench profile's camera URL does not name one).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hw_mocks.sim.camera import SimulatedCamera  # noqa: E402
from hw_mocks.sim.sensor import Sensor  # noqa: E402
from instrument.cli import main as cli_main  # noqa: E402
from instrument.run.engine import _Writer  # noqa: E402
from instrument.run.storage import RunStore  # noqa: E402

PLAN = ROOT / "examples" / "brdf_inplane.toml"


class StageClock:
    """Wall seconds and calls per stage, summed over threads (the stages never overlap:
    the engine runs one point at a time)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._lock = threading.Lock()

    def wrap(self, owner: type, name: str, stage: str, *, only=None) -> None:
        original = getattr(owner, name)

        @functools.wraps(original)
        def timed(obj, *args, **kwargs):
            if only is not None and not only(obj, *args, **kwargs):
                return original(obj, *args, **kwargs)
            t0 = time.perf_counter()
            try:
                return original(obj, *args, **kwargs)
            finally:
                with self._lock:
                    self.seconds[stage] += time.perf_counter() - t0
                    self.calls[stage] += 1

        setattr(owner, name, timed)


def _renders(cam: SimulatedCamera, state=None, *, roi=None) -> bool:
    """Whether this photon_rate call renders (a new view) rather than hitting the cache."""
    state = state if state is not None else cam.world.snapshot()
    roi = roi if roi is not None else cam.roi
    return (state.key, roi, cam.optics, cam.renderer) != cam._cache_key


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--renderer", choices=("fast", "reference"), default="fast")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    original_init = SimulatedCamera.__init__

    @functools.wraps(original_init)
    def init(self, *a, **kw):  # the profile's simcam:// URL names no renderer
        original_init(self, *a, **(kw | {"renderer": args.renderer}))

    SimulatedCamera.__init__ = init
    clock = StageClock()
    clock.wrap(SimulatedCamera, "photon_rate", "camera: render a new view", only=_renders)
    clock.wrap(Sensor, "expose", "camera: sensor noise per frame")
    clock.wrap(RunStore, "append", "storage: append a point (HDF5, journal, fsync)")
    # the engine's wait for the previous point's commit (ADR 0010): the part of the
    # storage that the run waits for, and does not overlap with the next move
    commit_wait = StageClock()
    commit_wait.wrap(_Writer, "drain", "engine: waits for the commit")
    print(f"renderer = {args.renderer}; {PLAN.relative_to(ROOT)}")
    for k in range(args.repeat):
        for c in (clock, commit_wait):
            c.seconds.clear()
            c.calls.clear()
        with tempfile.TemporaryDirectory() as out:
            t0, c0 = time.perf_counter(), time.process_time()
            with contextlib.redirect_stdout(io.StringIO()):
                rc = cli_main(["run", str(PLAN), "--out", out, "--quiet"])
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        if rc != 0:
            raise SystemExit(f"scatterlab run failed (exit {rc})")
        staged = sum(clock.seconds.values())
        print(f"run {k + 1}: wall {wall:.1f} s, CPU {cpu:.1f} s")
        for stage, seconds in sorted(clock.seconds.items()):
            print(f"    {stage:<48} {seconds:6.1f} s  ({clock.calls[stage]} calls)")
        print(f"    {'the rest (engine, drivers, emulators, meter)':<48} {wall - staged:6.1f} s")
        for stage, seconds in commit_wait.seconds.items():  # part of the rest
            n = commit_wait.calls[stage]
            print(f"      of the rest, {stage:<35} {seconds:6.1f} s  ({n} calls)")
    SimulatedCamera.__init__ = original_init


if __name__ == "__main__":
    main()
