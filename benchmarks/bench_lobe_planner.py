"""Does the lobe planner keep its promise? Predicted against delivered σ over seeds.

A two-pass lobe plan (:mod:`instrument.plans.lobe`) promises, before its second pass runs,
the σ of every parameter the fit of both passes will have. This script checks the promise
as ``scatterlab run`` makes it: per seed, the first pass (θi = 20°, 40°, 60°; θr every 20°
from −70° to 70° and ±4° around the mirror direction in 1° steps) is acquired with its own
sensor noise, read through the sim bench's neutral-density filters where the peak clips at
the shortest exposure (the engine's rule, ADR 0018; calibrated transmissions, their error
shared by the points of a filter, and each seed's calibrated values drawn about the
truth with their stated σ, so that the seed spread holds that shared error), fitted; the
second pass (24 points on a 0.25° grid) is placed by
:func:`~instrument.plans.lobe.place_points` with the fit's error budget
(:mod:`instrument.plans.lobe_budget`), acquired with another seed, and both passes are
fitted together as ``scatterlab fit`` does (forward model, shared filter errors
propagated).

Per parameter: the mean *predicted* σ, the mean σ the fits *report*, and the *delivered* σ
— the standard deviation of the fitted values over the seeds (its own relative standard
error is 1/√(2(N−1)), 16 % at 20 seeds). The promise holds when predicted/delivered is
within 0.7–1.3. The first line per α is the single-pass plan of equal time the planner
weighs the second pass against (:func:`~instrument.plans.lobe.single_pass_alternative`).

Scans are rendered without the motion emulators (tests/instrument/sim_scan.py): 96-px
camera integrating its pupil, beam 2 µW (the peak of a GGX α = 0.05 lobe clips at 10 µs
without a filter), auto-exposure to 50 % of full well capped at 10 ms, 20 ms readout.

Run: ``python benchmarks/bench_lobe_planner.py [--seeds 20] [--alphas 0.05,0.2]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

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
    plan_budget,
    plan_seconds,
    second_pass_text,
    single_pass_alternative,
)
from instrument.plans.lobe_budget import ErrorBudget, NDStep
from instrument.plans.planfile import parse_plan
from instrument.plans.tradeoff import Prior, ScanOption, setup_from_profile
from tests.instrument.sim_scan import (
    NDFilters,
    Sample,
    ScanSetup,
    profile_text,
    reduce_seed_nd,
    render,
)

READOUT_S = 0.02
MODEL = "lambert+ggx"
POINTS = 24
ND = NDFilters()


def lobe_plan_text(setup: ScanSetup, points: int = POINTS) -> str:
    return setup.plan_text().replace(
        "theta_r = { start = -70.0, stop = 80.0, step = 10.0 }",
        "theta_r = { start = -70.0, stop = 70.0, step = 20.0 }").replace(
        "specular = { half_width_deg = 4.0, step_deg = 2.0 }",
        f'lobe = {{ points = {points}, step_deg = 0.25, search_half_width_deg = 4.0, '
        'search_step_deg = 1.0, prior = "lambert+ggx" }').replace(
        "[acquisition]", f"[acquisition]\nreadout_s = {READOUT_S}")


def budget_of(nd: NDFilters) -> ErrorBudget:
    """The fit's budget on this bench: read-backs exact (rendered at the targets), the
    filters' calibrated transmissions."""
    return ErrorBudget(filters=tuple(NDStep(s, v, u) for s, v, u in
                                     zip(nd.slots, nd.value, nd.u, strict=True)))


def joined(a: BRDFPoints, sa: np.ndarray, b: BRDFPoints, sb: np.ndarray,
           nd: NDFilters) -> BRDFPoints:
    """Both passes as one set of points, as the reduction of a second pass joins them: a
    filter's error shared by its points in either pass."""
    cat = np.concatenate
    slots = cat([sa, sb])
    f = cat([a.brdf, b.brdf])
    rel_of = dict(zip(nd.slots, (u / v for u, v in zip(nd.u, nd.value, strict=True)),
                      strict=True))
    rel = np.array([rel_of.get(int(s), 0.0) for s in slots])
    same = (slots[:, None] == slots[None, :]) & (rel[:, None] > 0)
    cov = np.where(same, np.outer(f * rel, f * rel), 0.0)
    return replace(a, theta_i=cat([a.theta_i, b.theta_i]), phi_i=cat([a.phi_i, b.phi_i]),
                   theta_r=cat([a.theta_r, b.theta_r]), phi_r=cat([a.phi_r, b.phi_r]),
                   brdf=f, u_stat=cat([a.u_stat, b.u_stat]),
                   u_angle=cat([a.u_angle, b.u_angle]), u_ref=cat([a.u_ref, b.u_ref]),
                   cov_corr=cov if cov.any() else None, clipped=~cat([a.valid, b.valid]))


def run_alpha(alpha: float, seeds: int, power_w: float, verbose: bool) -> dict:
    sample = Sample(f"ggx-{alpha}", MODEL, (0.3, 0.5, alpha))
    setup = ScanSetup(power_w=power_w, fill=0.5, max_exposure_us=10_000.0)
    profile = parse_profile(profile_text(setup, sample))
    spec1 = parse_plan(lobe_plan_text(setup))
    first = build_plan(spec1, profile)
    cache: dict = {}
    r_1 = render(setup, sample, plan=first, cache=cache)
    lobe = lobe_of(spec1)
    assert lobe is not None
    cands = candidate_pairs(spec1, profile, lobe.step_deg)
    move_s = pass_move_seconds(profile, lobe.step_deg)
    option = ScanOption(1.0, setup.max_exposure_us, setup.frames)
    frames = 2 * setup.frames
    names = None
    pred, rep, est, alt, clip1, clip2, filt = [], [], [], [], [], [], []
    for seed in range(seeds):
        # each seed a calibration of its own: the filters' values drawn about the truth
        # with their stated σ, so that the spread over seeds holds their shared error
        rng = np.random.default_rng(50_000 + seed)
        nd = replace(ND, value=tuple(t + u * rng.standard_normal()
                                     for t, u in zip(ND.true, ND.u, strict=True)))
        budget = budget_of(nd)
        pts_1, slots_1 = reduce_seed_nd(r_1, seed, nd=nd)
        res1 = analyse(pts_1, [MODEL], run_cv=False)
        fit1 = res1.chosen_fit
        forward = res1.models[MODEL]
        _, det = setup_from_profile(profile, spec1, prior=Prior(MODEL, tuple(fit1.params)))
        det = replace(det, fill=setup.fill, readout_s=READOUT_S)
        ok = pts_1.valid
        a1 = np.stack([pts_1.theta_i, pts_1.phi_i, pts_1.theta_r, pts_1.phi_r], -1)
        cov1 = pts_1.plain_cov_corr()
        pl = place_points(forward, fit1.params, first_angles_rad=a1[ok],
                          first_sigma=pts_1.plain_u_indep()[ok], candidates=cands,
                          n_points=lobe.points, det=det, option=option, readout_s=READOUT_S,
                          frames_per_point=frames, move_s=move_s, budget=budget,
                          first_cov=None if cov1 is None else cov1[np.ix_(ok, ok)],
                          first_slots=slots_1[ok], min_separation_deg=0.5 * lobe.step_deg)
        second = build_plan(parse_plan(second_pass_text(spec1.source_text, pl.pairs,
                                                        "first.h5")), profile)
        r_2 = render(setup, sample, plan=second, cache=cache)
        pts_2, slots_2 = reduce_seed_nd(r_2, 10_000 + seed, nd=nd)
        fit = analyse(joined(pts_1, slots_1, pts_2, slots_2, nd), [MODEL],
                      run_cv=False).chosen_fit
        names = fit.param_names
        kw = {"det": det, "option": option, "budget": budget, "readout_s": READOUT_S}
        t1 = plan_seconds(first, plan_budget(first, forward, fit1.params, **kw)[1],
                          READOUT_S, frames)
        t2 = plan_seconds(second, plan_budget(second, forward, fit1.params, **kw)[1],
                          READOUT_S, frames)
        one = single_pass_alternative(spec1, profile, forward, fit1.params, seconds=t1 + t2,
                                      frames_per_point=frames, **kw)
        pred.append([pl.sigma_both[n] for n in names])
        rep.append(fit.stderr)
        est.append(fit.params)
        alt.append((one, t1 + t2))
        clip1.append(int((~pts_1.valid).sum()))
        clip2.append(int((~pts_2.valid).sum()))
        filt.append(int((slots_2 >= 0).sum()))
        if verbose:
            print(f"<!-- seed {seed}: predicted σ(α) {pl.sigma_both[names[-1]]:.3g}, "
                  f"reported {fit.stderr[-1]:.3g}, α − truth {fit.params[-1] - alpha:+.3g}; "
                  f"clipped {clip1[-1]} + {clip2[-1]}, {filt[-1]} second-pass points "
                  f"through a filter (predicted {sum(s >= 0 for s in pl.slots)}) -->",
                  flush=True)
    pred_a, rep_a, est_a = np.array(pred), np.array(rep), np.array(est)
    delivered = est_a.std(axis=0, ddof=1)
    return {"alpha": alpha, "names": names, "pred": pred_a.mean(axis=0),
            "pred_spread": pred_a.std(axis=0) / pred_a.mean(axis=0),
            "reported": np.sqrt(np.mean(rep_a**2, axis=0)), "delivered": delivered,
            "bias": est_a.mean(axis=0) - np.array(sample.params),
            "clipped": (sum(clip1), sum(clip2)), "filtered": float(np.mean(filt)),
            "alt": alt, "seeds": seeds}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--alphas", default="0.05,0.2")
    ap.add_argument("--power-w", type=float, default=2e-6)
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args()
    print("| α | parameter | σ predicted | σ reported (RMS) | σ delivered (seed spread) | "
          "predicted / delivered | mean − truth |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for alpha in (float(x) for x in args.alphas.split(",")):
        t0 = time.perf_counter()
        r = run_alpha(alpha, args.seeds, args.power_w, args.verbose)
        for k, name in enumerate(r["names"]):
            print(f"| {alpha:g} | {name} | {r['pred'][k]:.3g} | {r['reported'][k]:.3g} | "
                  f"{r['delivered'][k]:.3g} | {r['pred'][k] / r['delivered'][k]:.2f} | "
                  f"{r['bias'][k]:+.2g} |", flush=True)
        one, both_s = r["alt"][0]
        target = r["names"][-1]
        print(f"<!-- α = {alpha:g}: {r['seeds']} seeds, {time.perf_counter() - t0:.0f} s; "
              f"clipped readings {r['clipped'][0]} (first passes) + {r['clipped'][1]} "
              f"(second passes); {r['filtered']:.1f} second-pass points per seed through a "
              f"filter; seed-to-seed spread of the prediction {r['pred_spread'][-1]:.1%}; "
              f"single pass of equal time ({both_s:.0f} s): θr every "
              f"{one.theta_r_step_deg:g}°, {one.n_points} points, predicted σ({target}) "
              f"{one.sigma[target]:.3g} -->", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
