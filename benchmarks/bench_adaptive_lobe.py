"""Sharp-lobe refinement (an adaptive plan) against the fixed plan: σ(α) at equal scan
time, and the scan time to reach the fixed plan's σ(α).

Fixed plan: the closed loop's in-plane scan (θi = 20°, 40°, 60°; θr from −70° to 80° in
10° steps plus ±4° around specular in 2° steps; 57 points), as in
``benchmarks/bench_brdf_lobe.py`` (whose two-pass numbers, same setup, are the third
arm). Adaptive plan: :class:`instrument.plans.adaptive_lobe.SharpLobe` at θi = 40°, its
coarse pass θr from −70° to 70° in 20° steps plus ±4° around specular in 1° steps, then
batches of 4 points chosen from its own fit of the readings so far, exactly as the
engine asks it (``propose(history)`` with the reduced readings and their σ), until the
estimated scan time reaches the budget.

Durations are the engine's estimate, independent of this computer's speed: motion along
the route in the order the points are run (``Plan.estimate``, the ``sim`` profile's
stage dynamics) plus light and dark frames at the auto-exposure each point gets and a
20 ms readout per frame (tests/instrument/sim_scan.py; 20 nW beam, 50 % of full well,
exposures capped at 10 ms, 96-px camera integrating its pupil).

Per seed every plan is acquired with its own sensor noise (each batch of the adaptive
plan with its own seed) and fitted with the true model family (lambert+ggx) as the
instrument sees it, the fit ``scatterlab fit`` makes. σ(α) *measured* is the standard
deviation of the fitted α over seeds, *reported* the mean σ the fits report. *Time to
target*: after each batch the adaptive run is fitted; the first estimated time at which
the reported σ(α) is at or below the fixed plan's (mean over seeds) is recorded.

Run: ``python benchmarks/bench_adaptive_lobe.py [--seeds N] [--alphas 0.05,0.02]``.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_brdf_lobe import (  # the two-pass benchmark's setup and helpers
    MODEL,
    READOUT_S,
    concat,
    duration,
    table_main,
)

from instrument.bench.profile import parse_profile
from instrument.pipelines.brdf.analyse import analyse
from instrument.plans import scripted
from instrument.plans.adaptive import History, Measured
from instrument.plans.adaptive_lobe import SharpLobe
from instrument.plans.build import build_plan
from instrument.plans.planfile import parse_plan
from tests.instrument import sim_scan as sim

THETA_I = 40.0


def acquisition(setup: sim.ScanSetup) -> dict:
    return {"mode": "auto", "exposure_us": min(2000.0, setup.max_exposure_us),
            "max_exposure_us": setup.max_exposure_us, "frames": setup.frames,
            "dark": "per_point", "detectors": ["camera"]}


def explicit_plan(pairs, setup: sim.ScanSetup, profile):
    """The points ``pairs`` (signed θi, θr) run in the order given (as the engine runs an
    adaptive plan's batches after its base)."""
    spec = scripted.in_plane(points=[list(p) for p in pairs], order="raster", sample="sim",
                             acquisition=acquisition(setup))
    return build_plan(spec, profile)


def measured(pts, first: int) -> list[Measured]:
    out = []
    for k in range(len(pts.brdf)):
        ti = math.degrees(pts.theta_i[k])
        tr = math.degrees(pts.theta_r[k])
        same_side = abs(((math.degrees(pts.phi_r[k] - pts.phi_i[k]) + 180) % 360) - 180) < 90
        out.append(Measured(first + k, ti, -tr if same_side else tr, float(pts.brdf[k]),
                            float(pts.u_point[k]), bool(pts.valid[k])))
    return out


def adaptive_run(setup, sample, profile, seed: int, budget_s: float, target: float,
                 cache: dict) -> dict:
    """One adaptive run: per batch (estimated seconds, fitted α, its σ, points so far)."""
    plan = SharpLobe(THETA_I, theta_r=(-70, 70, 20), search_half_width_deg=4.0,
                     search_step_deg=1.0, target_sigma_alpha=0.0, budget_s=budget_s,
                     batch=4, acquisition=acquisition(setup), sample="sim", seed=seed)
    base = build_plan(plan.base, profile)
    pairs = [(THETA_I, m.theta_r) for m in measured_angles(base)]
    r = sim.render(setup, sample, plan=base, cache=cache)
    acc = sim.reduce_seed(r, 1000 * seed)
    acq_s = sim.acquisition_seconds(r, readout_s=READOUT_S)
    hist = measured(acc, 0)
    rounds = []
    t_target = math.nan
    for k in range(1, 200):
        seconds = explicit_plan(pairs, setup, profile).estimate().motion_s + acq_s
        fit = analyse(acc, [MODEL], run_cv=False).chosen_fit
        rounds.append((seconds, float(fit.params[2]), float(fit.stderr[2]), len(pairs)))
        if math.isnan(t_target) and fit.stderr[2] <= target:
            t_target = seconds
        props = plan.propose(History(tuple(hist), (), seconds))
        if not props:
            break
        new = [(p.theta_i, p.theta_r) for p in props]
        batch = explicit_plan(new, setup, profile)
        rb = sim.render(setup, sample, plan=batch, cache=cache)
        pts = sim.reduce_seed(rb, 1000 * seed + k)
        acq_s += sim.acquisition_seconds(rb, readout_s=READOUT_S)
        hist += measured(pts, len(hist))
        acc = concat(acc, pts)
        pairs += new
    return {"rounds": rounds, "t_target": t_target, "n_base": len(base.points)}


def measured_angles(plan) -> list[Measured]:
    out = []
    for p in plan.points:
        a = p.angles
        same_side = abs(((a.phi_r - a.phi_i + 180) % 360) - 180) < 90
        out.append(Measured(p.index, a.theta_i, -a.theta_r if same_side else a.theta_r,
                            math.nan))
    return out


def run_alpha(alpha: float, seeds: int) -> list[str]:
    sample = sim.Sample(f"glossy-{alpha}", MODEL, (0.3, 0.5, alpha))
    setup = sim.ScanSetup(power_w=2e-8, fill=0.5, max_exposure_us=10_000.0)
    profile = parse_profile(sim.profile_text(setup, sample))
    cache: dict = {}
    fixed = build_plan(parse_plan(setup.plan_text()), profile)
    r_u = sim.render(setup, sample, plan=fixed, cache=cache)
    t_u = sum(duration(fixed, r_u))
    fits_u = [analyse(sim.reduce_seed(r_u, seed), [MODEL], run_cv=False).chosen_fit
              for seed in range(seeds)]
    a_u = np.array([f.params[2] for f in fits_u])
    s_u = np.array([f.stderr[2] for f in fits_u])
    target = float(s_u.mean())
    runs = [adaptive_run(setup, sample, profile, seed, t_u, target, cache)
            for seed in range(seeds)]
    # equal time: the last batch that ends within the fixed plan's duration
    last = [max((r for r in run["rounds"] if r[0] <= t_u), key=lambda r: r[0])
            for run in runs]
    a_a = np.array([r[1] for r in last])
    s_a = np.array([r[2] for r in last])
    t_a = float(np.mean([r[0] for r in last]))
    t_hit = np.array([run["t_target"] for run in runs])
    rows = [
        f"| {alpha:g} | fixed | {len(fixed.points)} | {t_u:.1f} | {a_u.std(ddof=1):.3g} | "
        f"{s_u.mean():.3g} | {np.mean(np.abs(a_u - alpha) <= 2 * s_u):.0%} | {t_u:.1f} |",
        f"| {alpha:g} | adaptive | {runs[0]['n_base']} + "
        f"{np.mean([r[3] for r in last]) - runs[0]['n_base']:.1f} | {t_a:.1f} | "
        f"{a_a.std(ddof=1):.3g} | {s_a.mean():.3g} | "
        f"{np.mean(np.abs(a_a - alpha) <= 2 * s_a):.0%} | "
        f"{np.nanmedian(t_hit):.1f} (reached in {np.mean(np.isfinite(t_hit)):.0%}) |",
    ]
    return rows


def main() -> int:
    return table_main(run_alpha, doc=__doc__, seeds=8, alphas="0.05,0.02",
                      header="| α | plan | points | duration (s) | σ(α) measured | "
                             "σ(α) reported | truth within 2σ | time to the fixed plan's "
                             "σ(α) (s, median) |")


if __name__ == "__main__":
    sys.exit(main())
