"""The second pass of a two-pass lobe plan (``[scan] lobe``), for ``scatterlab run``.

After the first pass has run, :func:`second_pass_plan` reduces and fits it (the plan's
``lobe.prior`` model, or a selection among the default candidates), places the second
pass's points by Fisher information (:mod:`instrument.plans.lobe`) and returns the plan of
the second pass, whose ``first_pass`` names the first run (the analysis reduces both).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from instrument.bench.profile import BenchProfile
from instrument.pipelines.brdf.analyse import DEFAULT_MODELS, analyse
from instrument.pipelines.brdf.reduce import reduce_run
from instrument.plans.build import Plan, build_plan
from instrument.plans.lobe import (
    Placement,
    candidate_pairs,
    lobe_of,
    pass_move_seconds,
    place_points,
    second_pass_text,
)
from instrument.plans.planfile import PlanSpec, parse_plan
from instrument.plans.tradeoff import Prior, ScanOption, setup_from_profile

__all__ = ["SecondPass", "second_pass_plan"]


@dataclass(frozen=True)
class SecondPass:
    """The second pass: its plan, the placement behind it and the model that guided it."""

    plan: Plan
    placement: Placement
    model: str
    verdict: str


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
    u = pts.plain_brdf()[1]
    receiver = pts.receiver
    placement = place_points(
        forward, fit.params, first_angles_rad=first[ok], first_sigma=u[ok],
        candidates=candidate_pairs(spec, profile, lobe.step_deg), n_points=lobe.points,
        det=det, option=ScanOption(1.0, pol.max_exposure_us, pol.frames),
        readout_s=pol.readout_s,
        frames_per_point=pol.frames * (2 if pol.dark == "per_point" else 1),
        move_s=pass_move_seconds(profile, lobe.step_deg),
        sigma_theta_rad=0.0 if receiver is None else receiver.sigma_theta_r_rad,
        min_separation_deg=0.5 * lobe.step_deg, target=lobe.target)
    text = second_pass_text(spec.source_text, placement.pairs, Path(first_run).name)
    spec2 = parse_plan(text, source=f"second pass of {first_run}")
    return SecondPass(build_plan(replace(spec2, source_text=text), profile), placement,
                      res.chosen, res.verdict)
