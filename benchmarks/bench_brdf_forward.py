"""The forward model against the simulated camera: lobes α = 0.3 … 0.02,
incidence 0° … 80°, noise-free.

For each lobe and incidence angle the in-plane scan of the closed loop (θr from −70° to
80° in 10° steps plus ±4° around specular in 2° steps) is rendered by the simulated
camera (pupil integrated, tests/instrument/sim_scan.py), reduced by the absolute method
without noise, and compared with the forward model the fit uses
(:func:`analysis.brdf.reduction.forward_model`) at the quadrature levels the fit's rule
would choose at the true parameters (refine a point while the next level moves it by more
than 0.1σ). The difference is given relative to the value and in units of the noise σ of
two acquisitions: the closed loop's (auto-exposure to 2 % of full well, 1 frame, 96 px)
and a high-SNR one (80 % of full well, 4 frames averaged), with no exposure clamped at
the camera's shortest (no reading clips).

The same table shows what the old model (chief ray through the pupil centre, no sample
edge) and the BRDF at the nominal angles would miss.

Run: ``python benchmarks/bench_brdf_forward.py [--quick]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.brdf import get_model
from analysis.brdf.geometry import make_geometry
from analysis.brdf.reduction import LEVELS, forward_model, receiver_model
from analysis.brdf.reduction.forward import point_keys
from tests.instrument.sim_scan import Sample, ScanSetup, noise_free, receiver, reduce_seed, render


def adaptive_levels(model, rg, params, g, sigma, tau=0.1) -> dict:
    """The levels the forward fit would settle on at ``params`` (its refinement rule)."""
    keys = point_keys(g)
    lev = np.zeros(len(keys), dtype=int)
    top = len(LEVELS) - 1
    while True:
        f = [receiver_model(model, rg, level=k).evaluate_geometry(params, g)
             for k in range(len(LEVELS))]
        cur = np.array([f[k][j] for j, k in enumerate(lev)])
        nxt = np.array([f[min(k + 1, top)][j] for j, k in enumerate(lev)])
        move = (np.abs(nxt - cur) > tau * sigma) & (lev < top)
        if not move.any():
            return {k: int(v) for k, v in zip(keys, lev, strict=True)}
        lev[move] += 1


def compare(alpha: float, theta_i: float, px: int) -> dict:
    setup = ScanSetup(theta_i_deg=(theta_i,), sensor_px=px)
    sample = Sample(f"a{alpha}", "lambert+ggx", (0.3, 0.5, alpha))
    r = render(setup, sample)
    a = r.angles_rad
    rg = receiver(setup)
    data = noise_free(r).brdf
    model = get_model(sample.model)
    p = np.array(sample.params)
    g = make_geometry(*a.T)
    # noise σ of the two acquisitions (same render, one sensor seed each; the exposure
    # is never clamped at the camera's shortest, so no reading clips)
    loop = replace(r, setup=replace(setup, min_exposure_us=1e-3))
    sig_loop = reduce_seed(loop, 0).u_point
    hi = replace(r, setup=replace(setup, fill=0.8, frames=4, min_exposure_us=1e-3))
    sig_hi = reduce_seed(hi, 0).u_point
    levels = adaptive_levels(model, rg, p, g, sig_hi)
    fwd = forward_model(model, rg, levels).evaluate_geometry(p, g)
    old_rg = replace(rg, sample_aperture=False, sample_radius_mm=None)
    old = receiver_model(model, old_rg, level=2).evaluate_geometry(p, g)
    nominal = model.evaluate_geometry(p, g)
    d = data - fwd
    return {
        "alpha": alpha, "theta_i": theta_i, "n": len(a),
        "rel": float(np.max(np.abs(d / data))),
        "z_loop": float(np.max(np.abs(d / sig_loop))),
        "z_hi": float(np.max(np.abs(d / sig_hi))),
        "levels": np.bincount(list(levels.values()), minlength=len(LEVELS)),
        "z_old": float(np.max(np.abs((data - old) / sig_loop))),
        "z_nominal": float(np.max(np.abs((data - nominal) / sig_loop))),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="α 0.3 and 0.02 at 40° and 80° only")
    ap.add_argument("--px", type=int, default=96, help="sensor pixels per side (default 96)")
    args = ap.parse_args()
    alphas = (0.3, 0.02) if args.quick else (0.3, 0.1, 0.05, 0.02)
    thetas = (40.0, 80.0) if args.quick else (0.0, 20.0, 40.0, 60.0, 80.0)
    print("| α | θi | points | max abs Δ/f | max abs Δ/σ, closed loop | max abs Δ/σ, high SNR "
          "| points per level 0–4 | old model: max abs Δ/σ, closed loop "
          "| nominal angles: max abs Δ/σ, closed loop | time (s) |")
    print("|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|")
    for alpha in alphas:
        for ti in thetas:
            t0 = time.perf_counter()
            c = compare(alpha, ti, args.px)
            lv = ", ".join(str(int(x)) for x in c["levels"])
            print(f"| {alpha:g} | {ti:g}° | {c['n']} | {c['rel']:.1e} | {c['z_loop']:.3f} | "
                  f"{c['z_hi']:.2f} | {lv} | {c['z_old']:.3g} | {c['z_nominal']:.3g} | "
                  f"{time.perf_counter() - t0:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
