"""What the plan editor's speed/accuracy planner computes for a polarimetric plan
(Qt-free; the editor runs :func:`plan_trade` on its background thread).

A dual rotating retarder (DRR) plan trades its steps per geometry:
:func:`instrument.plans.polarimetric_tradeoff.polarimetric_sweep` predicts each
candidate's duration (the engine's estimate), κ and the σ of the normalised Mueller
elements, and the front is the scalar trade's own :func:`~instrument.plans.tradeoff.
pareto_front` (ADR 0108) — the numbers ``scatterlab plan`` prints. A photoelastic
modulator (PEM) plan has no such front: the planner predicts no σ for it, so the editor
shows what it does compute, κ per wavelength and the plan's estimate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from instrument.bench.profile import BenchProfile
from instrument.plans.planfile import PlanSpec

__all__ = ["AXES", "PemSummary", "PolarimetricTrade", "pem_summary", "plan_trade"]

#: The σ axes a DRR trade can be ranked and targeted on (``PolarimetricResult.sigma``).
AXES = ("sigma_mean", "sigma_max", "kappa")


@dataclass(frozen=True)
class PolarimetricTrade:
    """The DRR trade of one plan.

    Attributes
    ----------
    axis : str
        The axis of the front and the target (one of :data:`AXES`).
    target : float
        The wanted value on that axis.
    front : list of PolarimetricResult
        The Pareto front on ``axis``, fastest first.
    best : PolarimetricResult or None
        The fastest candidate reaching ``target`` (None: none does).
    results : list of PolarimetricResult
        Every candidate, fewest steps first.
    plan_steps : int
        The plan's own steps per geometry.
    """

    axis: str
    target: float
    front: list[Any]
    best: Any | None
    results: list[Any]
    plan_steps: int


@dataclass(frozen=True)
class PemSummary:
    """What the planner computes for a PEM plan: κ per wavelength
    (:class:`instrument.plans.polarimetry_pem.PemConditioning`) and the plan's estimate
    (``duration_s``: the instrument's own motion and acquisition time, the figure the
    trades compare, :attr:`instrument.plans.build.PlanEstimate.real_time_s`)."""

    conditioning: list[Any]
    n_points: int
    duration_s: float
    time_constants: float
    reads: int
    settings: int


def plan_trade(spec: PlanSpec, profile: BenchProfile, axis: str | None,
               target: float) -> PolarimetricTrade:
    """The DRR trade of ``spec`` on ``profile``: the default candidates and the plan's
    own steps (:func:`instrument.plans.polarimetric_tradeoff.plan_candidates`).

    Raises
    ------
    ValueError
        ``axis`` is not one of :data:`AXES` (named), or ``spec`` is not a DRR plan.
    """
    from instrument.plans.polarimetric_tradeoff import plan_candidates, polarimetric_sweep
    from instrument.plans.tradeoff import fastest_for_target, pareto_front

    name = axis or "sigma_mean"
    if name not in AXES:
        raise ValueError(f"the polarimetric trade has no axis {name!r}; it has "
                         f"{', '.join(AXES)} (σ of m_ij/m00 mean or worst, κ)")
    if spec.polarimetry is None or spec.polarimetry.get("mode") == "pem":
        raise ValueError(f"plan {spec.name!r} is not a dual-rotating-retarder plan")
    results = polarimetric_sweep(spec, profile, plan_candidates(spec))
    return PolarimetricTrade(name, float(target), pareto_front(results, name),
                             fastest_for_target(results, name, target), results,
                             int(spec.polarimetry["steps"]))


def pem_summary(spec: PlanSpec, profile: BenchProfile) -> PemSummary:
    """κ per wavelength and the estimate of PEM plan ``spec`` on ``profile`` (what
    ``scatterlab plan`` prints for it)."""
    from instrument.plans.build import build_plan, plan_filter_wavelengths
    from instrument.plans.polarimetry import plan_wavelengths
    from instrument.plans.polarimetry_pem import pem_conditioning

    pol = spec.polarimetry
    if pol is None or pol.get("mode") != "pem":
        raise ValueError(f"plan {spec.name!r} is not a PEM plan")
    wavelengths = plan_wavelengths(profile, plan_filter_wavelengths(spec, profile))
    est = build_plan(spec, profile).estimate()
    return PemSummary(pem_conditioning(pol, profile, wavelengths), est.n_points,
                      est.real_time_s, float(pol["time_constants"]), int(pol["reads"]),
                      len(pol["generator_deg"]) * len(pol["analyser_deg"]))
