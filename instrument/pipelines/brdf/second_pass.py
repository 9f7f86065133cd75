"""The second pass of a two-pass lobe plan (``[scan] lobe``), for ``scatterlab run`` and
the bench server's queue (both plan it here, from the first pass's run file).

After the first pass has run, :func:`second_pass_plan` reduces and fits it (the plan's
``lobe.prior`` model, or a selection among the default candidates), places the second
pass's points by Fisher information (:mod:`instrument.plans.lobe`) with the error budget
the fit will use (:func:`error_budget`: the camera's noise, the stages' angular error, the
neutral-density filters' transmissions, the common scale) and returns the plan of the
second pass, whose ``first_pass`` names the first run (the analysis reduces both).

It also predicts the single-pass plan the same time would buy
(:func:`instrument.plans.lobe.single_pass_alternative`); when the second pass would not
beat it, ``worthwhile`` is False and ``scatterlab run`` (or the server) says so instead of
running it.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from instrument.bench.angles import angular_model
from instrument.bench.profile import BenchProfile
from instrument.bench.timing import bench_timing
from instrument.pipelines.brdf.analyse import DEFAULT_MODELS, analyse
from instrument.pipelines.brdf.attenuation import nd_slots, nd_transmissions
from instrument.pipelines.brdf.reduce import reduce_run
from instrument.plans.build import build_plan
from instrument.plans.lobe import (
    SecondPass,
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
from instrument.plans.planfile import PlanSpec, parse_plan
from instrument.plans.tradeoff import Prior, ScanOption, setup_from_profile
from instrument.run.runfile import RunData, read_run

__all__ = ["SecondPass", "error_budget", "is_second_pass", "second_pass_plan"]


def is_second_pass(run_file: str | Path) -> bool:
    """Whether the run is the second pass of a two-pass lobe plan: its stored plan names
    the first pass (``[scan] first_pass``), as :func:`second_pass_plan` writes it."""
    text = read_run(run_file).plan_text
    return "first_pass" in tomllib.loads(text).get("scan", {})


def error_budget(run: RunData, profile: BenchProfile, u_scale_rel: float
                 ) -> ErrorBudget:
    """What the fit of ``run`` will add to the detector's noise (ADR 0016, 0018): the
    stages' angular error from the run's profile, the wheel's neutral-density filters with
    the transmissions the reduction will divide by (its calibration, the profile's
    certificate or the nominal value), one wheel turn per filtered reading, and the
    common scale."""
    ang = angular_model(run.profile())
    table, _ = nd_transmissions(run)
    steps = tuple(NDStep(t.slot, t.value, t.u, t.calibrated, t.label)
                  for t in sorted(table.values(), key=lambda t: -t.value))
    timing = bench_timing(profile)
    move = max((timing.wheel_move_s(1, s.slot) for s in steps), default=0.0)
    return ErrorBudget(ang.sigma_theta_i_rad, ang.sigma_theta_r_rad, steps, move,
                       float(u_scale_rel))


def second_pass_plan(first_run: str | Path, spec: PlanSpec, profile: BenchProfile
                     ) -> SecondPass:
    """Fit the first pass and plan the second (module docstring).

    Raises
    ------
    ValueError
        The plan has no lobe option, or the first pass cannot be reduced.
    """
    lobe = lobe_of(spec)
    if lobe is None:
        raise ValueError(f"plan {spec.name!r} has no [scan] lobe option")
    if spec.polarimetry is not None:
        # m00 of the Mueller reduction and a σ model fitted to it, not the camera's
        from instrument.pipelines.polarimetry.lobe import polarimetric_second_pass

        return polarimetric_second_pass(first_run, spec, profile)
    run = read_run(first_run)
    reduced = reduce_run(first_run)
    models = [lobe.prior] if lobe.prior else list(DEFAULT_MODELS)
    res = analyse(reduced.points, models, run_cv=False)
    fit = res.chosen_fit
    forward = res.models[res.chosen]
    _, det = setup_from_profile(profile, spec, prior=Prior(res.chosen,
                                                           tuple(fit.params.tolist())))
    pol = spec.acquisition
    pts = reduced.points
    first = np.stack([pts.theta_i, pts.phi_i, pts.theta_r, pts.phi_r], axis=-1)
    ok = pts.valid  # clipped readings carry no information
    u = pts.plain_u_indep()
    cov = pts.plain_cov_corr()
    budget = error_budget(run, profile, pts.u_scale_rel)
    option = ScanOption(1.0, pol.max_exposure_us, pol.frames)
    frames = pol.frames * (2 if pol.dark == "per_point" else 1)
    placement = place_points(
        forward, fit.params, first_angles_rad=first[ok], first_sigma=u[ok],
        candidates=candidate_pairs(spec, profile, lobe.step_deg), n_points=lobe.points,
        det=det, option=option, readout_s=pol.readout_s, frames_per_point=frames,
        move_s=pass_move_seconds(profile, lobe.step_deg), budget=budget,
        first_cov=None if cov is None else cov[np.ix_(ok, ok)],
        first_slots=nd_slots(run, reduced.rows)[ok],
        min_separation_deg=0.5 * lobe.step_deg, target=lobe.target)
    text = second_pass_text(spec.source_text, placement.pairs, Path(first_run).name)
    spec2 = parse_plan(text, source=f"second pass of {first_run}")
    plan2 = build_plan(replace(spec2, source_text=text), profile)
    kw: dict[str, Any] = {"det": det, "option": option, "budget": budget,
                          "readout_s": pol.readout_s}
    plan1 = build_plan(spec, profile)
    t1 = plan_seconds(plan1, plan_budget(plan1, forward, fit.params, **kw)[1],
                      pol.readout_s, frames)
    t2 = plan_seconds(plan2, plan_budget(plan2, forward, fit.params, **kw)[1],
                      pol.readout_s, frames)
    alt = single_pass_alternative(spec, profile, forward, fit.params, seconds=t1 + t2,
                                  frames_per_point=frames, **kw)
    target = lobe.target if lobe.target not in (None, "all") else forward.param_names[-1]
    return SecondPass(plan2, placement, res.chosen, res.verdict, str(target), t1, t2, alt)
