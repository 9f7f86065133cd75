"""Laser speckle and the sample spinner: what spinning buys (ADR 0098).

1. ``--contrast``: the speckle contrast C = σ_I/⟨I⟩ of the simulated camera's generator
   (:mod:`hw_mocks.sim.speckle`) against N, the independent patterns an exposure
   averages, on pixels finer than the grain (1 µm, grain λ·F# = 3.2 µm) and on the sim
   camera's 5.5 µm pixels; 4 seeds per N. The log-log slope is fitted by least squares
   with its standard error from the scatter about the line (expected −1/2).
2. ``--brdf``: the σ of the fitted BRDF parameters with a static and with a spun sample
   (the K10CR1 at its 10 °/s) at equal total time (the same exposures: the spinner costs
   one acceleration ramp per run), on the scan of
   tests/instrument/pipelines/brdf/test_speckle_sigma.py (lambert+ggx, a 0.3 mm beam):
   per parameter the mean reported σ, the scatter of the estimates over seeds, and the
   mean pull spread.
3. ``--cost``: CPU seconds of a frame of the simulated camera, incoherent and under a
   laser (static, spun).

Run: ``python benchmarks/bench_speckle.py [--contrast] [--brdf] [--cost] [--seeds N]``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hw_mocks.sim.speckle import SpeckleOptics, speckle_image, speckle_seed


def contrast_table(seeds: int) -> None:
    y, x = np.mgrid[0:96, 0:128]
    rate = 1e6 * np.exp(-2.0 * (((x - 64) / 77.0) ** 2 + ((y - 48) / 58.0) ** 2))
    core = rate > 0.8 * rate.max()
    ns = np.array([1, 2, 4, 8, 16, 32, 64, 128, 256])
    for pitch in (1.0, 5.5):
        optics = SpeckleOptics(633.0, 5.0, pitch)
        t0 = time.perf_counter()
        # contrast[seed, N]: each seed is one sample surface, its patterns shared by all N
        c = np.array([[float((speckle_image(
            rate, optics, [speckle_seed(s, [pitch], k) for k in range(min(n, 8))],
            patterns=float(n))[core] / rate[core]).std()) for n in ns] for s in range(seeds)])
        elapsed = time.perf_counter() - t0
        print(f"\npixel {pitch:g} µm (grain {optics.grain_um:.2f} µm), {seeds} seeds, "
              f"{elapsed:.1f} s")
        print("   N   contrast   ± (se)   C·√N")
        for j, n in enumerate(ns):
            m, e = c[:, j].mean(), c[:, j].std(ddof=1) / math.sqrt(seeds)
            print(f"{n:4d}   {m:.4f}   {e:.4f}   {m * math.sqrt(n):.3f}")
        # the slope per seed (its points are correlated: they share patterns), then its
        # mean and standard error over seeds; N ≤ 8 are all drawn patterns
        for label, sel in (("N = 1–8 (drawn)", ns <= 8), ("N = 1–256", ns > 0)):
            slopes = [np.polyfit(np.log(ns[sel]), np.log(row[sel]), 1)[0] for row in c]
            print(f"log-log slope, {label}: {np.mean(slopes):+.4f} ± "
                  f"{np.std(slopes, ddof=1) / math.sqrt(seeds):.4f} (expected −0.5)")


def brdf_table(seeds: int) -> None:
    from tests.instrument.pipelines.brdf.test_speckle_sigma import (
        SAMPLE,
        SETUP,
        SPIN,
        fit_seed,
    )
    from tests.instrument.sim_scan import acquisition_seconds, render, spun_patterns

    r = render(SETUP, SAMPLE)
    truth = np.array(SAMPLE.params)
    n = spun_patterns(r, SPIN)
    print(f"\n{len(r.angles_rad)} points, exposure time {acquisition_seconds(r):.2f} s "
          f"(light + dark), N per point {n.min():.1f} to {n.max():.1f} "
          f"(median {np.median(n):.1f}); {seeds} seeds")
    print("sample     param    reported σ   scatter   pull std   max χ²/ν")
    out = {}
    for label, spin in (("static", 0.0), (f"spun {SPIN:g}°/s", SPIN)):
        est, sig, chi = [], [], []
        t0 = time.perf_counter()
        for seed in range(1, seeds + 1):
            fit, gof = fit_seed(r, seed, speckle_sigma=True, spin_deg_s=spin)
            est.append(fit.params)
            sig.append(fit.stderr)
            chi.append(gof.chi2 / gof.dof)
        est_a, sig_a = np.array(est), np.array(sig)
        out[label] = sig_a.mean(axis=0)
        for j, name in enumerate(("rho", "ks", "alpha")):
            pull = (est_a[:, j] - truth[j]) / sig_a[:, j]
            print(f"{label:12s} {name:6s} {sig_a[:, j].mean():.5f}     "
                  f"{est_a[:, j].std(ddof=1):.5f}    {pull.std(ddof=1):.2f}     "
                  f"{max(chi):.2f}")
        print(f"   ({time.perf_counter() - t0:.0f} s)")
    ratio = out["static"] / out[f"spun {SPIN:g}°/s"]
    print("σ static / σ spun: " + ", ".join(f"{v:.2f}" for v in ratio))


def cost_table() -> None:
    """CPU seconds of one frame of the simulated camera at θi = 30°, θr = 40°: the
    incoherent frame (render cached: the sensor's noise alone), and under a laser the
    speckle of a static sample and of an exposure of 0.2 s spun at 10 °/s."""
    from hw_mocks.sim.camera import SimulatedCamera
    from hw_mocks.sim.sensor import SensorParams
    from hw_mocks.sim.state import SourceState
    from hw_mocks.sim.world import VirtualBench

    print("\npixels   beam    frame                        N      CPU s")
    for width, beam in ((256, 0.5), (1024, 2.0)):
        world = VirtualBench(f"cost{width}", source=SourceState(
            on=True, beam_radius_mm=beam, coherence="laser"),
            roles={"sample_theta": 30.0, "detector_theta": 70.0})
        cam = SimulatedCamera("c", world=world, seed=1,
                              sensor=SensorParams(width=width, height=width))
        state = world.snapshot()
        rate = cam.photon_rate(state)
        t = time.process_time()
        for _ in range(5):
            cam.sensor.expose(rate, 2e5, gain_db=0.0, bits=12, roi=(0, 0, width, width))
        print(f"{width:5d}   {beam:.1f} mm  incoherent (noise only)        -   "
              f"{(time.process_time() - t) / 5:.3f}")
        for label, spin in (("laser, static", (0.0, 0.0)),
                            ("laser, 0.2 s spun at 10 °/s", (0.0, 10.0))):
            cam._speckle_rate = None  # recompute: the first frame at a geometry
            t = time.process_time()
            n = cam.speckle_patterns(state, spin, 2e5)[1]
            cam._speckled(state, cam.roi, rate, spin, 2e5)
            print(f"{width:5d}   {beam:.1f} mm  {label:28s} {n:5.1f}   "
                  f"{time.process_time() - t:.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--contrast", action="store_true")
    ap.add_argument("--brdf", action="store_true")
    ap.add_argument("--cost", action="store_true")
    ap.add_argument("--seeds", type=int, default=4)
    args = ap.parse_args()
    if not (args.contrast or args.brdf or args.cost):
        args.contrast = args.brdf = args.cost = True
    if args.contrast:
        contrast_table(args.seeds)
    if args.brdf:
        brdf_table(args.seeds)
    if args.cost:
        cost_table()


if __name__ == "__main__":
    main()
