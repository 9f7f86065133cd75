"""Sampling the lobe: σ(α) of a two-pass lobe plan against the uniform plan at
equal scan time.

Uniform plan: the closed loop's in-plane scan (θi = 20°, 40°, 60°; θr from −70° to 80° in
10° steps plus ±4° around specular in 2° steps; 57 points). Lobe plan
(:mod:`instrument.plans.lobe`): a coarse first pass (θr from −70° to 70° in 20° steps and
a ±4° search around the mirror direction in 2° steps), fitted; then points on a 0.25° grid
placed one at a time by Fisher information per second, as many as fit in the uniform
plan's duration less the first pass's. Durations: motion along the optimised route from
the engine's estimator (``Plan.estimate``, the ``sim`` profile's stage dynamics) plus
light + dark frames at the auto-exposure each point gets and a 20 ms readout per frame.
Beam attenuated to 20 nW, auto-exposure to 50 % of full well capped at 10 ms (exposure
and readout matter), 96-px camera integrating its pupil (tests/instrument/sim_scan.py).

Per seed, each plan is acquired with its own sensor noise and fitted with the true model
family (lambert+ggx) as the instrument sees it; σ(α) *measured* is the standard deviation
of the fitted α over seeds, *reported* the mean σ the fits report. The second pass is
planned from that seed's own first-pass fit (as ``scatterlab run`` does).

Run: ``python benchmarks/bench_brdf_lobe.py [--seeds N] [--alphas 0.2,0.05,0.02]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.brdf.reduction import BRDFPoints
from instrument.bench.profile import parse_profile
from instrument.pipelines.brdf.analyse import analyse
from instrument.plans.build import build_plan
from instrument.plans.lobe import (
    candidate_pairs,
    lobe_of,
    pass_move_seconds,
    place_points,
    second_pass_text,
)
from instrument.plans.planfile import parse_plan
from instrument.plans.tradeoff import Prior, ScanOption, setup_from_profile
from tests.instrument.sim_scan import (
    Sample,
    ScanSetup,
    acquisition_seconds,
    profile_text,
    reduce_seed,
    render,
)

READOUT_S = 0.02
MODEL = "lambert+ggx"


def lobe_plan_text(setup: ScanSetup) -> str:
    return setup.plan_text().replace(
        "theta_r = { start = -70.0, stop = 80.0, step = 10.0 }",
        "theta_r = { start = -70.0, stop = 70.0, step = 20.0 }").replace(
        "specular = { half_width_deg = 4.0, step_deg = 2.0 }",
        'lobe = { points = 400, step_deg = 0.25, search_half_width_deg = 4.0, '
        'search_step_deg = 2.0, prior = "lambert+ggx" }')


def concat(a: BRDFPoints, b: BRDFPoints) -> BRDFPoints:
    cat = np.concatenate
    return replace(a, theta_i=cat([a.theta_i, b.theta_i]), phi_i=cat([a.phi_i, b.phi_i]),
                   theta_r=cat([a.theta_r, b.theta_r]), phi_r=cat([a.phi_r, b.phi_r]),
                   brdf=cat([a.brdf, b.brdf]), u_stat=cat([a.u_stat, b.u_stat]),
                   u_angle=cat([a.u_angle, b.u_angle]), u_ref=cat([a.u_ref, b.u_ref]),
                   cov_corr=None, clipped=~cat([a.valid, b.valid]))


def duration(plan, r) -> tuple[float, float]:
    est = plan.estimate()
    return est.motion_s, acquisition_seconds(r, readout_s=READOUT_S)


def run_alpha(alpha: float, seeds: int) -> list[str]:
    sample = Sample(f"glossy-{alpha}", MODEL, (0.3, 0.5, alpha))
    setup = ScanSetup(power_w=2e-8, fill=0.5, max_exposure_us=10_000.0)
    profile = parse_profile(profile_text(setup, sample))
    cache: dict = {}
    uniform = build_plan(parse_plan(setup.plan_text()), profile)
    spec1 = parse_plan(lobe_plan_text(setup))
    first = build_plan(spec1, profile)
    r_u = render(setup, sample, plan=uniform, cache=cache)
    r_1 = render(setup, sample, plan=first, cache=cache)
    t_u = sum(duration(uniform, r_u))
    t_1 = sum(duration(first, r_1))
    lobe = lobe_of(spec1)
    assert lobe is not None
    cands = candidate_pairs(spec1, profile, lobe.step_deg)
    move_s = pass_move_seconds(profile, lobe.step_deg)
    fits = {"uniform": [], "lobe": []}
    n2, t2 = [], []
    for seed in range(seeds):
        pts_u = reduce_seed(r_u, seed)
        fits["uniform"].append(analyse(pts_u, [MODEL], run_cv=False).chosen_fit)
        pts_1 = reduce_seed(r_1, seed)
        res1 = analyse(pts_1, [MODEL], run_cv=False)
        fit1 = res1.chosen_fit
        _, det = setup_from_profile(profile, spec1, prior=Prior(MODEL, tuple(fit1.params)))
        det = replace(det, fill=setup.fill, readout_s=READOUT_S)
        ok = pts_1.valid
        first_angles = np.stack([pts_1.theta_i, pts_1.phi_i, pts_1.theta_r, pts_1.phi_r], -1)
        pl = place_points(res1.models[MODEL], fit1.params, first_angles_rad=first_angles[ok],
                          first_sigma=pts_1.u_point[ok], candidates=cands,
                          n_points=lobe.points, det=det,
                          option=ScanOption(1.0, setup.max_exposure_us, setup.frames),
                          readout_s=READOUT_S, frames_per_point=2 * setup.frames,
                          move_s=move_s, min_separation_deg=0.5 * lobe.step_deg)
        budget = t_u - t_1
        n = int(np.searchsorted(np.cumsum(pl.costs), budget, side="right"))
        # the route through the chosen points takes longer than the per-point estimate:
        # drop points until the second pass's estimated duration fits the budget
        while n > 0:
            text = second_pass_text(spec1.source_text, pl.pairs[:n], "first.h5")
            second = build_plan(parse_plan(text), profile)
            r_2 = render(setup, sample, plan=second, cache=cache)
            if sum(duration(second, r_2)) <= budget:
                break
            n -= 1
        n2.append(n)
        t2.append(sum(duration(second, r_2)))
        pts_2 = reduce_seed(r_2, 10_000 + seed)
        both = concat(pts_1, pts_2)
        fits["lobe"].append(analyse(both, [MODEL], run_cv=False).chosen_fit)
    rows = []
    for name in ("uniform", "lobe"):
        a = np.array([f.params[2] for f in fits[name]])
        s = np.array([f.stderr[2] for f in fits[name]])
        z = (a - alpha) / s
        npts = (len(uniform.points) if name == "uniform"
                else f"{len(first.points)} + {np.mean(n2):.1f}")
        dur = t_u if name == "uniform" else t_1 + float(np.mean(t2))
        rows.append((name, npts, dur, float(a.std(ddof=1)), float(s.mean()),
                     float(np.mean(np.abs(z) <= 2))))
    ratio = rows[0][3] / rows[1][3]
    out = []
    for name, npts, dur, meas, rep, cov in rows:
        out.append(f"| {alpha:g} | {name} | {npts} | {dur:.1f} | {meas:.3g} | {rep:.3g} | "
                   f"{cov:.0%} | {'' if name == 'uniform' else f'{ratio:.2f}×'} |")
    return out


def table_main(run_alpha, *, doc: str, header: str, seeds: int, alphas: str) -> int:
    """Print a Markdown table: ``header`` (its columns), then the rows of
    ``run_alpha(alpha, seeds)`` for each α of ``--alphas`` (also used by
    bench_adaptive_lobe.py)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=seeds)
    ap.add_argument("--alphas", default=alphas)
    args = ap.parse_args()
    print(header)
    print("|---:|---|---:|---:|---:|---:|---:|---:|")
    for alpha in (float(x) for x in args.alphas.split(",")):
        t0 = time.perf_counter()
        for line in run_alpha(alpha, args.seeds):
            print(line, flush=True)
        print(f"<!-- α = {alpha:g}: {time.perf_counter() - t0:.0f} s -->", flush=True)
    return 0


def main() -> int:
    return table_main(run_alpha, doc=__doc__, seeds=16, alphas="0.2,0.05,0.02",
                      header="| α | plan | points | duration (s) | σ(α) measured | "
                             "σ(α) reported | truth within 2σ | σ(α) uniform / lobe |")


if __name__ == "__main__":
    sys.exit(main())
