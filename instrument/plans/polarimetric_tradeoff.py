"""Speed against accuracy of a polarimetric scan: the Mueller elements' σ and the condition
number κ against the dual rotating retarder's steps per geometry and the scan's duration.

For a candidate step count K the planner predicts

* the **duration** with the engine's own estimator
  (:meth:`instrument.plans.build.Plan.estimate`: the instrument's own motion time along
  the route, the four mounts' moves included, and acquisition; the same figure as
  :mod:`instrument.plans.tradeoff`'s);
* **κ**, the condition number of the instrument matrix W of the K steps with the
  profile's nominal retardances (Smith 2002, Appl. Opt. 41, 2488), the worst over
  the plan's wavelengths;
* the **σ of the normalised elements** m_ij/m00 of a *prior* sample (the identity, i.e. a
  non-depolarising, non-diattenuating sample, unless given) from the weighted
  least-squares covariance (WᵀΣ⁻¹W)⁻¹ of the reduction
  (:func:`analysis.polarimetry.drr.reduce`, ADR 0102), propagated to first order through
  the division by m00;
  the readings' σ is the power meter's noise of the profile
  (:func:`instrument.bench.meter_noise.meter_noise`): its relative noise times the
  noise-free intensity W·vec(M), in quadrature with its absolute floor (``noise_floor_w``)
  for a mean reading of ``reading_w`` (default :data:`TYPICAL_READING_W`, the order of the
  glass's specular readings on ``sim-polarimetric``; the floor keeps the σ finite for
  steps where a pure sample sends no light to the meter). The mean and the worst σ over
  the 15 elements are reported.

The prediction is the reduction's own covariance: at equal noise per reading, σ falls as
1/√K once the steps are ≥ 25 (where κ no longer changes), and the time grows with K. The
Pareto front over the candidates is :func:`instrument.plans.tradeoff.pareto_front`, the
scalar trade's, on the ``sigma_mean`` (or ``sigma_max``, ``kappa``) axis.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from instrument.bench.meter_noise import meter_noise
from instrument.bench.profile import BenchProfile
from instrument.plans.build import build_plan, plan_filter_wavelengths
from instrument.plans.planfile import PlanSpec
from instrument.plans.polarimetry import conditioning, plan_wavelengths

__all__ = [
    "DEFAULT_STEP_COUNTS",
    "TYPICAL_READING_W",
    "PolarimetricOption",
    "PolarimetricResult",
    "element_sigma",
    "plan_candidates",
    "polarimetric_sweep",
    "predict_polarimetric",
]

#: The candidate steps per geometry: 25 (the fewest with a regular W at ratio 5) to 96.
DEFAULT_STEP_COUNTS = (25, 30, 36, 48, 60, 72, 96)
#: The mean reading (W) against which the meter's floor is set: 1 mW into the 5 mm
#: aperture at 300 mm off a few % specular reflector, about 0.1 µW.
TYPICAL_READING_W = 1e-7
#: The floor's least fraction of the mean reading, for a profile that declares none.
MIN_FLOOR_FRACTION = 1e-6
#: The σ axes a result carries (:attr:`PolarimetricResult.sigma`).
SIGMA_AXES = ("sigma_mean", "sigma_max", "kappa")


@dataclass(frozen=True)
class PolarimetricOption:
    """One candidate: the retarder steps per geometry."""

    steps: int

    def label(self) -> str:
        return f"{self.steps} steps"


@dataclass(frozen=True)
class PolarimetricResult:
    """Prediction for one :class:`PolarimetricOption`.

    Attributes
    ----------
    motion_s, acquisition_s : float
        The engine's estimate of the plan with these steps (the instrument's own time).
    kappa : float
        The condition number of W, the worst over the plan's wavelengths.
    sigma : dict str → float
        ``sigma_mean`` and ``sigma_max``: the mean and the worst predicted σ of the 15
        normalised elements m_ij/m00 (worst wavelength); ``kappa`` as well, so that
        :func:`instrument.plans.tradeoff.pareto_front` can trade on any of the three.
    """

    option: PolarimetricOption
    n_points: int
    motion_s: float
    acquisition_s: float
    kappa: float
    sigma: dict[str, float]

    @property
    def duration_s(self) -> float:
        return self.motion_s + self.acquisition_s


def element_sigma(w: ArrayLike, prior: ArrayLike, relative_noise: float,
                  floor_fraction: float = MIN_FLOOR_FRACTION) -> NDArray[np.float64]:
    """σ (4×4) of the normalised elements m_ij/m00 of ``prior`` measured with instrument
    matrix ``w`` (K×16, unit source) and readings of relative noise ``relative_noise`` in
    quadrature with a floor of ``floor_fraction`` of the mean reading (module docstring;
    m00's own entry is 0)."""
    from analysis.polarimetry.drr import reduce

    wm = np.asarray(w, dtype=float)
    intensity = wm @ np.asarray(prior, dtype=float).ravel()
    mean = float(np.mean(intensity))
    if not mean > 0:
        raise ValueError("the prior sample sends no light to the meter: its normalised "
                         "elements' σ is undefined")
    sigma = np.hypot(relative_noise * intensity, max(floor_fraction, MIN_FLOOR_FRACTION)
                     * mean)
    est = reduce(intensity, sigma, wm)
    return np.asarray(est.sigma_normalised, dtype=float)


def predict_polarimetric(spec: PlanSpec, profile: BenchProfile, option: PolarimetricOption,
                         *, prior: ArrayLike | None = None,
                         reading_w: float = TYPICAL_READING_W) -> PolarimetricResult:
    """Duration, κ and the normalised elements' σ of polarimetric ``spec`` with
    ``option.steps`` steps per geometry (module docstring).

    Raises
    ------
    ValueError
        ``spec`` has no ``[polarimetry]`` table.
    instrument.plans.errors.PlanError
        The steps make W singular, or the profile has no retarder in an arm.
    """
    from analysis.polarimetry.drr import drr_angles, instrument_matrix

    if spec.polarimetry is None:
        raise ValueError(f"plan {spec.name!r} has no [polarimetry] table: the polarimetric "
                         "trade varies its steps per geometry")
    pol = {**spec.polarimetry, "steps": int(option.steps)}
    plan = build_plan(replace(spec, polarimetry=pol), profile)
    est = plan.estimate()
    wavelengths = plan_wavelengths(profile, plan_filter_wavelengths(spec, profile))
    data = tomllib.loads(profile.source_text) if profile.source_text else {}
    noise = meter_noise(data)
    rel, floor = noise.relative, (noise.floor_w or 0.0) / reading_w
    m = np.eye(4) if prior is None else np.asarray(prior, dtype=float)
    g, a = drr_angles(int(option.steps), float(pol["ratio"]))
    # the polarisers' datasheet extinction, as the run's W takes it (ADR 0108, 0113)
    extinction = {} if profile.optics is None else profile.optics.extinctions()
    kappa, mean, worst = 0.0, 0.0, 0.0
    for c in conditioning(pol, profile, wavelengths):
        w = instrument_matrix(g, a, psg_retardance=math.radians(c.psg_retardance_deg),
                              psa_retardance=math.radians(c.psa_retardance_deg),
                              **extinction)
        s = element_sigma(w, m, rel, floor).ravel()[1:]
        kappa = max(kappa, c.kappa)
        mean, worst = max(mean, float(s.mean())), max(worst, float(s.max()))
    return PolarimetricResult(option, len(plan.points), est.motion_s, est.acquisition_s,
                              kappa, {"sigma_mean": mean, "sigma_max": worst,
                                      "kappa": kappa})


def polarimetric_sweep(spec: PlanSpec, profile: BenchProfile,
                       options: Iterable[PolarimetricOption] | None = None, *,
                       prior: ArrayLike | None = None,
                       reading_w: float = TYPICAL_READING_W) -> list[PolarimetricResult]:
    """:func:`predict_polarimetric` for every option (default: :data:`DEFAULT_STEP_COUNTS`),
    in order."""
    chosen: Sequence[PolarimetricOption] = (
        [PolarimetricOption(k) for k in DEFAULT_STEP_COUNTS] if options is None
        else list(options))
    return [predict_polarimetric(spec, profile, o, prior=prior, reading_w=reading_w)
            for o in chosen]


def plan_candidates(spec: PlanSpec) -> list[PolarimetricOption]:
    """The candidates the planner shows for ``spec`` (``scatterlab plan`` and the GUI's
    plan editor): :data:`DEFAULT_STEP_COUNTS` and the plan's own steps, fewest first (the
    plan's own steps are regular once the plan is built; the defaults are all ≥ 25)."""
    if spec.polarimetry is None:
        raise ValueError(f"plan {spec.name!r} has no [polarimetry] table")
    steps = sorted({*DEFAULT_STEP_COUNTS, int(spec.polarimetry["steps"])})
    return [PolarimetricOption(k) for k in steps]
