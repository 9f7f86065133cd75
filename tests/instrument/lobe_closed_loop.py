"""A two-pass lobe plan acquired without the engine, seed by seed: the planner's promise
against what the fit of both passes delivers (benchmarks/bench_lobe_planner.py and the
slow test in tests/instrument/plans/test_lobe.py).

Per seed, the first pass is acquired with its own sensor noise (tests/instrument/sim_scan.py),
read through the sim bench's neutral-density filters where the peak clips at the shortest
exposure (the engine's rule, ADR 0018; each seed's calibrated transmissions drawn about the
truth with their stated σ, so that the spread over seeds holds their shared error), and
fitted; the second pass is placed by :func:`instrument.plans.lobe.place_points` with the
fit's error budget, acquired with another seed, and both passes are fitted together as
``scatterlab fit`` does.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

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
            "pred_each": pred_a, "errors": est_a - np.array(sample.params),
            "pred_spread": pred_a.std(axis=0) / pred_a.mean(axis=0),
            "reported": np.sqrt(np.mean(rep_a**2, axis=0)), "delivered": delivered,
            "bias": est_a.mean(axis=0) - np.array(sample.params),
            "clipped": (sum(clip1), sum(clip2)), "filtered": float(np.mean(filt)),
            "alt": alt, "seeds": seeds}


