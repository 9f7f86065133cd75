"""The second pass of a two-pass lobe plan with ``[polarimetry]`` (ADR 0106, amendment).

The first pass is polarimetric over the plan's coarse geometries (its θr grid and the
search around specular). What the lobe machinery of :mod:`instrument.plans.lobe` needs
from it is scalar: per geometry, m00 (the unpolarised BRDF, 1/sr) with the σ the Mueller
reduction's covariance gives it (:func:`m00_rows`). The lobe models are fitted to those
(:func:`instrument.pipelines.brdf.analyse.analyse`, point receiver: placing points needs
the lobe's shape, not the receiver's 10⁻³ on it, which the pBRDF fit of both passes does
model); the second pass is then placed by
:func:`instrument.plans.lobe.place_points_modelled` with

* **σ of a candidate's m00** from a noise model fitted to the first pass's own (m00, σ)
  pairs (:class:`M00Noise`): σ² = a + b·m00 + c·m00², the variance of a reading that has a
  floor (a), a part that grows with the signal (b: shot-like, or a lock-in's var ∝ |X|)
  and a relative part (c: source and gain noise), fitted by weighted least squares with
  a, b, c ≥ 0 (Lawson & Hanson, *Solving Least Squares Problems*, 1974, ch. 23, NNLS).
  The weights are 1/σ⁴: an estimated variance s² has a standard deviation ∝ σ² (for
  Gaussian noise var(s²) = 2σ⁴/ν, ν its degrees of freedom), so each pair counts by its
  relative error. The camera's noise model (``point_budget``) does not apply: the
  detector here is a power meter or a lock-in behind K retarder steps;
* **the cost of a geometry** from the polarimetric plan's own estimate: one geometry of
  the plan (its K retarder steps or its PEM settings, the mounts' moves, the modulator's
  settles) on this bench's clock, plus the goniometer's small step between neighbouring
  geometries (:func:`geometry_seconds`).

Over several ``[spectral]`` filters the first pass runs at every filter; the lobe and the
σ model are fitted to the m00 of one reference filter
(:func:`instrument.plans.lobe.reference_filter`: ``lobe.reference_filter``, by default the
filter nearest the centre of the band) and each placed geometry is read at every filter,
its cost the plan's estimate of it at all of them. One wavelength's placement, not the
union of each wavelength's own, because on the measured two-filter bench the placements
coincide while the union costs a geometry per filter (ADR 0106, amendment; BENCHMARKS.md
"polarimetry: a lobe over two filters").

The "worth it?" comparison (:func:`single_pass_alternative`) uses the same σ model and
costs; the second pass's plan (:func:`instrument.plans.lobe.second_pass_text`) carries
``[polarimetry]`` and ``[spectral]``, so it is polarimetric with the same settings, and
``scatterlab fit`` on it fits both runs' Mueller matrices together
(:func:`~instrument.pipelines.polarimetry.pipeline.fit_polarimetric_run`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls

from analysis.brdf.geometry import make_geometry
from analysis.brdf.model import BRDFModel
from analysis.brdf.reduction.values import BRDFPoints
from instrument.bench.profile import BenchProfile
from instrument.pipelines.brdf.analyse import DEFAULT_MODELS, analyse
from instrument.pipelines.polarimetry.pipeline import reduce_polarimetric
from instrument.plans.build import Plan, build_plan
from instrument.plans.lobe import (
    Placement,
    SecondPass,
    SinglePass,
    candidate_pairs,
    lobe_of,
    pass_move_seconds,
    place_points_modelled,
    reference_filter,
    second_pass_text,
    single_pass_plans,
)
from instrument.plans.lobe_budget import predicted_covariance
from instrument.plans.planfile import PlanSpec, parse_plan

__all__ = ["LobePlacement", "M00Noise", "M00Rows", "geometry_seconds", "lobe_placement",
           "m00_rows", "polarimetric_second_pass", "single_pass_alternative"]


@dataclass(frozen=True)
class M00Rows:
    """A polarimetric run's scalar data for the lobe fit: one row per reflected geometry
    whose m00 is positive (straight-through groups, which are transmittances, left out).

    Attributes
    ----------
    angles_rad : ndarray, shape (n, 4)
        θi, φi, θr, φr of each geometry (radians; the mean read-back angles).
    m00, sigma : ndarray, shape (n,)
        m00 of the Mueller-matrix BRDF (1/sr) and its standard uncertainty, the square root
        of the reduction's covariance of that element.
    """

    angles_rad: NDArray[np.float64]
    m00: NDArray[np.float64]
    sigma: NDArray[np.float64]

    def brdf_points(self) -> BRDFPoints:
        """The rows as scalar BRDF values for the lobe models (point receiver, no common
        scale: the second pass shares the first pass's source scale)."""
        a = self.angles_rad
        zero = np.zeros_like(self.m00)
        return BRDFPoints(a[:, 0], a[:, 1], a[:, 2], a[:, 3], self.m00, self.sigma, zero,
                          zero, 0.0, False, "polarimetric m00")


def m00_rows(path: str | Path, calibration: str | Path | None = None,
             wavelength_nm: float | None = None) -> M00Rows:
    """m00 and its σ per geometry of a polarimetric run (:class:`M00Rows`), reduced as
    ``scatterlab fit`` reduces it (``calibration`` as for
    :func:`~instrument.pipelines.polarimetry.pipeline.fit_polarimetric_run`); with
    ``wavelength_nm``, of the run's wavelength nearest to it only (a run over several
    filters has one group per geometry and filter).

    Raises
    ------
    ValueError
        No reflected geometry with a positive m00.
    """
    points = [p for p in reduce_polarimetric(path, calibration).points
              if not p.group.transmitted and p.brdf.normalised_valid]
    if wavelength_nm is not None and points:
        have = [p.group.wavelength_nm for p in points]
        nearest = min(have, key=lambda w: abs(w - wavelength_nm) if math.isfinite(w)
                      else math.inf)
        points = [p for p in points if abs(p.group.wavelength_nm - nearest) <= 0.5]
    if not points:
        raise ValueError(f"{path}: no reflected geometry with a positive m00 to fit the lobe "
                         "to")
    ang = np.radians([[p.group.theta_i, p.group.phi_i, p.group.theta_r, p.group.phi_r]
                      for p in points])
    m00 = np.array([float(p.brdf.m[0, 0]) for p in points])
    sigma = np.array([math.sqrt(max(float(p.brdf.cov[0, 0]), 0.0)) for p in points])
    return M00Rows(ang, m00, sigma)


@dataclass(frozen=True)
class M00Noise:
    """σ(m00)² = a + b·m00 + c·m00² (module docstring), each coefficient ≥ 0."""

    a: float
    b: float
    c: float

    @classmethod
    def fit(cls, m00: Sequence[float] | NDArray[np.float64],
            sigma: Sequence[float] | NDArray[np.float64]) -> M00Noise:
        """Weighted non-negative least squares of σ² on (1, m00, m00²), weights 1/σ⁴
        (module docstring). Columns are scaled to unit size first, so that a, b and c are
        fitted alike whatever the unit of m00.

        Raises
        ------
        ValueError
            No pair, or a σ that is not positive and finite.
        """
        m = np.abs(np.asarray(m00, dtype=float))
        s = np.asarray(sigma, dtype=float)
        if m.size == 0 or m.size != s.size:
            raise ValueError("the σ model of m00 needs (m00, σ) pairs of equal length")
        if not np.all(np.isfinite(s) & (s > 0)) or not np.all(np.isfinite(m)):
            raise ValueError("the σ model of m00 needs finite m00 and positive finite σ")
        var = s**2
        scale = max(float(m.max()), 1e-100)  # scale² stays a normal float
        design = np.stack([np.ones_like(m), m / scale, (m / scale) ** 2], axis=1)
        # row i divided by its own σ²: residuals relative to each variance
        coef, _ = nnls(design / var[:, None], np.ones_like(var))
        return cls(float(coef[0]), float(coef[1]) / scale, float(coef[2]) / scale**2)

    def sigma(self, m00: NDArray[np.float64]) -> NDArray[np.float64]:
        """The σ predicted for m00 values (1/sr); never below a thousandth of the floor's
        or relative part's, so that no candidate is weighed as noiseless."""
        m = np.abs(np.asarray(m00, dtype=float))
        var = self.a + self.b * m + self.c * m**2
        floor = 1e-6 * max(self.a, self.c * float(np.max(m, initial=0.0)) ** 2, 1e-300)
        out: NDArray[np.float64] = np.sqrt(np.maximum(var, floor))
        return out

    def describe(self) -> str:
        return (f"σ² = {self.a:.3g} + {self.b:.3g}·m00 + {self.c:.3g}·m00² "
                "(fitted to the first pass)")


def _one_geometry(spec: PlanSpec, pair: tuple[float, float]) -> PlanSpec:
    """``spec`` with its scan reduced to the one signed in-plane (θi, θr) ``pair``."""
    scan = {k: v for k, v in spec.scan.items()
            if k not in ("theta_i", "theta_r", "lobe", "specular", "first_pass")}
    return replace(spec, scan={**scan, "points": [[float(pair[0]), float(pair[1])]]})


def geometry_seconds(spec: PlanSpec, profile: BenchProfile, pair: tuple[float, float],
                     step_deg: float) -> float:
    """Seconds one polarimetric geometry costs on this bench: the plan's estimate of that
    geometry alone (its K retarder steps or PEM settings with the mounts' moves and the
    readings), started at its own first position so that no goniometer travel from home
    is counted, plus the goniometer's step of ``step_deg`` to the next geometry."""
    plan = build_plan(_one_geometry(spec, pair), profile)
    if not plan.points:
        raise ValueError(f"the geometry (θi {pair[0]:g}°, θr {pair[1]:g}°) is not reachable "
                         "on this bench")
    est = plan.estimate(start=plan.points[0].target_dict())
    return float(est.total_s) + pass_move_seconds(profile, step_deg)


def _geometries(plan: Plan) -> NDArray[np.float64]:
    """The distinct lit geometries (n, 4; radians) of a polarimetric plan, whose points
    repeat each geometry once per retarder step or PEM setting."""
    seen: dict[tuple[float, ...], tuple[float, ...]] = {}
    for q in plan.points:
        if q.light and q.angles is not None:
            a = q.angles.as_tuple()
            seen.setdefault(tuple(round(x, 6) for x in a), a)
    out: NDArray[np.float64] = np.radians(np.array(list(seen.values()), dtype=float)
                                          .reshape(-1, 4))
    return out


def single_pass_alternative(spec: PlanSpec, profile: BenchProfile, model: BRDFModel,
                            params: NDArray[np.float64], noise: M00Noise, *, seconds: float
                            ) -> SinglePass:
    """The densest one-pass polarimetric plan (θr steps of
    :data:`~instrument.plans.lobe.SINGLE_PASS_STEPS`, with the first pass's search around
    specular) that ``seconds`` pay for on this bench's estimate, and the σ of the lobe
    parameters it would give with the σ model ``noise``; the coarsest when none fits."""
    best: SinglePass | None = None
    for step, plan in single_pass_plans(spec, profile):
        dur = float(plan.estimate().total_s)
        if best is not None and dur > seconds:
            break
        ang = _geometries(plan)
        sig = noise.sigma(model.evaluate_geometry(params, make_geometry(*ang.T)))
        cov = predicted_covariance(model, params, ang, sig)
        best = SinglePass(step, len(ang), dur, dict(zip(
            model.param_names, np.sqrt(np.maximum(np.diag(cov), 0.0)).tolist(), strict=True)))
    assert best is not None
    return best


@dataclass(frozen=True)
class LobePlacement:
    """The lobe fitted to the first pass's m00 at one wavelength and the second pass's
    geometries placed from it (:func:`lobe_placement`)."""

    placement: Placement
    model: str
    verdict: str
    forward: BRDFModel
    params: NDArray[np.float64]
    noise: M00Noise


def lobe_placement(first_run: str | Path, spec: PlanSpec, profile: BenchProfile,
                   wavelength_nm: float | None = None) -> LobePlacement:
    """Fit the lobe to the first pass's m00 (at ``wavelength_nm``, or the run's one
    wavelength) and place the second pass's geometries (module docstring); each geometry
    costs the plan's estimate of it at every filter of the plan.

    Raises
    ------
    ValueError
        The first pass cannot be reduced, too few geometries for the lobe models, or no
        reachable direction.
    """
    lobe = lobe_of(spec)
    assert lobe is not None
    rows = m00_rows(first_run, wavelength_nm=wavelength_nm)
    models = [lobe.prior] if lobe.prior else list(DEFAULT_MODELS)
    res = analyse(rows.brdf_points(), models, run_cv=False)
    forward = res.models[res.chosen]
    params = np.asarray(res.chosen_fit.params, dtype=float)
    noise = M00Noise.fit(rows.m00, rows.sigma)
    candidates = candidate_pairs(spec, profile, lobe.step_deg)
    if not candidates:
        raise ValueError("no direction of the plan's θr range is reachable for the second "
                         "pass")
    per_geometry = geometry_seconds(spec, profile, candidates[0], lobe.step_deg)
    placement = place_points_modelled(
        forward, params, first_angles_rad=rows.angles_rad, first_sigma=rows.sigma,
        candidates=candidates, n_points=lobe.points, sigma_of=noise.sigma,
        geometry_s=per_geometry, min_separation_deg=0.5 * lobe.step_deg,
        target=lobe.target)
    return LobePlacement(placement, res.chosen, res.verdict, forward, params, noise)


def polarimetric_second_pass(first_run: str | Path, spec: PlanSpec, profile: BenchProfile
                             ) -> SecondPass:
    """Fit the lobe to the polarimetric first pass's m00 and plan the second pass (module
    docstring); what :func:`instrument.pipelines.brdf.second_pass.second_pass_plan` returns
    for a plan with ``[polarimetry]``. Over several filters the lobe is fitted at the
    plan's reference filter (:func:`instrument.plans.lobe.reference_filter`) and the second
    pass reads every filter at the geometries placed from it.

    Raises
    ------
    ValueError
        The first pass cannot be reduced, too few geometries for the lobe models, or a
        filter without a band in the profile.
    """
    lobe = lobe_of(spec)
    assert lobe is not None
    ref = reference_filter(spec, profile)
    lp = lobe_placement(first_run, spec, profile, None if ref is None else ref.center_nm)
    text = second_pass_text(spec.source_text, lp.placement.pairs, Path(first_run).name)
    spec2 = parse_plan(text, source=f"second pass of {first_run}")
    plan2 = build_plan(replace(spec2, source_text=text), profile)
    t1 = float(build_plan(spec, profile).estimate().total_s)
    t2 = float(plan2.estimate().total_s)
    alt = single_pass_alternative(spec, profile, lp.forward, lp.params, lp.noise,
                                  seconds=t1 + t2)
    target = lobe.target if lobe.target not in (None, "all") else lp.forward.param_names[-1]
    fitted_at = "" if ref is None else (f"the lobe fitted at {ref.describe()}; the second "
                                        "pass reads every filter of the plan")
    return SecondPass(plan2, lp.placement, lp.model, lp.verdict, str(target), t1, t2, alt,
                      fitted_at)
