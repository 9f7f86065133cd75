"""Accuracy and cost of the emulated bench's integral over a detector's aperture.

The sim-spectral bench's photodiode (5 mm at 300 mm) under the 2 mm beam, on the lock-in
pulls' two samples (Lambert ρ 0.5; Lambert 0.3 + GGX ks 0.5, α 0.2): the power on the
aperture at ``aperture_samples`` = each of ``--m`` against the last (the reference), as a
relative error, and the seconds of one integral (median of ``--repeat``). The lock-in's
relative noise over four snapshots is 5·10⁻⁵ (BENCHMARKS.md); the integral must be far
below it. Run with ``PYTHONPATH=/work/main`` to measure main's rule for the same m.

    python benchmarks/bench_aperture_rule.py [--m 9,27,60] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# appended: PYTHONPATH (another checkout) comes first
sys.path.append(str(Path(__file__).resolve().parents[1]))

from hw_mocks.sim.goniometer_scene import GoniometerScene, brdf_from_model
from hw_mocks.sim.world import PowerMeterHead, VirtualBench

SAMPLES = {"lambert-0.5": ("lambert", [0.5]),
           "glossy-ggx": ("lambert+ggx", {"lambert.rho": 0.3, "ggx.ks": 0.5,
                                          "ggx.alpha": 0.2})}
#: (sample stage, detector arm) in degrees: θi 20° and 50°, off and on the specular peak.
GEOMETRIES = ((20.0, -40.0), (20.0, 30.0), (20.0, 40.0), (50.0, 0.0), (50.0, 100.0),
              (50.0, 104.0))


def power(world: VirtualBench, brdf, m: int) -> tuple[float, float]:
    world.scene = GoniometerScene(brdf=brdf, aperture_samples=m)
    t0 = time.perf_counter()
    p = world.optical_power_w(550.0)
    return p, time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", default="9,27,60")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    ms = [int(x) for x in args.m.split(",")]
    print(f"scene code: {sys.modules[GoniometerScene.__module__].__file__}")
    print("| sample | θi, θr (°) | " + " | ".join(f"m = {m}: rel. error, s" for m in ms[:-1])
          + " |\n|---|---|" + "---:|" * (len(ms) - 1))
    for name, (model, params) in SAMPLES.items():
        brdf = brdf_from_model(model, params)
        for stage, arm in GEOMETRIES:
            world = VirtualBench("aperture", roles={"sample_theta": stage,
                                                    "detector_theta": arm},
                                 power_meter=PowerMeterHead(distance_mm=300.0,
                                                            aperture_diameter_mm=5.0))
            world.update_source(on=True, power_w=1e-3)
            ref, _ = power(world, brdf, ms[-1])
            cells = []
            for m in ms[:-1]:
                runs = [power(world, brdf, m) for _ in range(args.repeat)]
                cells.append(f"{runs[0][0] / ref - 1:+.1e}, "
                             f"{statistics.median(t for _, t in runs):.3f}")
            print(f"| {name} | {stage:g}, {arm - stage:g} | " + " | ".join(cells) + " |",
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
