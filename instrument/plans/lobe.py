"""Sampling the lobe in two passes: a coarse pass finds the peak, Fisher information places
the rest.

A plan with ``[scan] lobe = {points = N, ...}`` (:mod:`instrument.plans.planfile`) is run
in two passes:

1. **First pass** — the plan as built (:func:`instrument.plans.build.build_plan`): its θr
   grid and a search of ±``search_half_width_deg`` around the mirror direction at
   ``search_step_deg``, so that a narrow peak is found wherever it lies near specular.
   The pass is reduced and fitted (the ``prior`` model, or a selection among the default
   candidates), which gives the lobe's position and width.
2. **Second pass** — N points chosen among the reachable in-plane directions on a fine grid
   (``step_deg``) of the plan's θr range at each θi, one at a time, each where it adds the
   most information about the parameters per second of scan time (:func:`place_points`):
   the greedy D-optimal design on the Fisher information of the speed/accuracy planner
   (:mod:`instrument.plans.tradeoff`: C = (JᵀWJ)⁻¹, W = 1/σ² with σ from the camera noise
   model at the exposure each point will get), seeded with the information of the first
   pass. By default a point's gain is the decrease of the variance of the target
   parameter t (``target``; default the model's last parameter — its lobe width, e.g.
   ``ggx.alpha``, as in the planner's ``--target-param``), by Sherman–Morrison
   w (e_tᵀ C j)² / (1 + w jᵀ C j) (c-optimality); ``target = "all"`` uses the increase
   of log det(JᵀWJ), log(1 + w jᵀ C j) by the matrix determinant lemma (D-optimality);
   Atkinson, Donev & Tobias, *Optimum Experimental Designs*, 2007, §10.1–10.3 and §11.2 on
   sequential construction. Either gain is divided by the point's acquisition and move
   time. J is the Jacobian of the *forward model* (what the instrument sees: the
   lobe averaged over beam and pupil), and σ is the σ the fit will give the reading
   (:mod:`instrument.plans.lobe_budget`, ADR 0022: the detector's noise, the angular error
   of both stages from the model's slopes, the neutral-density filter a clipping peak will
   be read through and its transmission error), so points gather where the measured lobe
   curves, not on flanks steeper than the axes can hold, and never where the reading
   would clip behind every filter. Each direction is used once (and none the first pass
   measured): the points spread over the region of highest information instead of piling
   onto its best angle, which keeps the design robust when the model is slightly wrong.
   The promised σ are the fit's covariance of both passes, shared errors (a filter's
   transmission, the common scale) propagated as the fit propagates them.
3. **Worth it?** :func:`single_pass_alternative` predicts, with the same budget, the one-pass
   plan the two passes' time would buy; the second pass is run only when it promises a
   smaller σ of the target.

The second pass is a plan of explicit ``points`` with ``first_pass`` naming the first
pass's run (:func:`second_pass_text`); the analysis reduces the two runs together.

A plan with ``[polarimetry]`` is placed by :func:`place_points_modelled` instead: the same
greedy design, with σ from a function of the predicted value and one cost per geometry
(:mod:`instrument.pipelines.polarimetry.lobe` fits both to the polarimetric first pass).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from analysis.brdf.geometry import make_geometry
from analysis.brdf.model import BRDFModel
from instrument.bench.dynamics import move_time
from instrument.bench.profile import BenchProfile
from instrument.plans.build import (
    Plan,
    build_plan,
    dynamics_of,
    filter_bands,
    guarded_points,
)
from instrument.plans.lobe_budget import (
    ErrorBudget,
    PointBudget,
    angular_sigma,
    point_budget,
    predicted_covariance,
    shared_covariance,
)
from instrument.plans.planfile import PlanSpec, parse_plan
from instrument.plans.tradeoff import DetectorSetup, ScanOption

__all__ = ["LobeSpec", "Placement", "ReferenceFilter", "SecondPass", "SinglePass",
           "candidate_pairs", "lobe_of", "place_points", "place_points_modelled",
           "plan_budget", "plan_seconds", "reference_filter", "second_pass_text",
           "single_pass_alternative", "single_pass_plans"]


@dataclass(frozen=True)
class LobeSpec:
    """The ``[scan] lobe`` table of a plan (module docstring)."""

    points: int
    step_deg: float = 0.25
    search_half_width_deg: float = 5.0
    search_step_deg: float = 1.0
    prior: str | None = None
    target: str | None = None
    reference_filter: int | None = None


def lobe_of(spec: PlanSpec) -> LobeSpec | None:
    """The plan's lobe option, or None for a one-pass plan."""
    lb = spec.scan.get("lobe")
    if lb is None:
        return None
    ref = lb.get("reference_filter")
    return LobeSpec(int(lb["points"]), float(lb.get("step_deg", 0.25)),
                    float(lb.get("search_half_width_deg", 5.0)),
                    float(lb.get("search_step_deg", 1.0)), lb.get("prior"), lb.get("target"),
                    None if ref is None else int(ref))


@dataclass(frozen=True)
class ReferenceFilter:
    """The ``[spectral]`` filter a polarimetric lobe over several filters is fitted at:
    its slot, its centre wavelength (nm), and ``named`` whether the plan named it
    (``lobe.reference_filter``) or it is the default, the filter nearest the centre of the
    plan's band (the midpoint of its shortest and longest centre wavelengths; on a tie, as
    always for two filters, the shorter wavelength)."""

    slot: int
    center_nm: float
    named: bool
    band_centre_nm: float

    def describe(self) -> str:
        why = ("named by lobe.reference_filter" if self.named else
               f"the filter nearest the band's centre, {self.band_centre_nm:g} nm; "
               "lobe.reference_filter names another")
        return f"filter {self.slot} ({self.center_nm:g} nm; {why})"


def reference_filter(spec: PlanSpec, profile: BenchProfile) -> ReferenceFilter | None:
    """The filter the lobe of ``spec`` is fitted at (:class:`ReferenceFilter`); None for a
    plan without a lobe, without ``[spectral]`` or with one filter only (its own).

    Raises
    ------
    ValueError
        A filter of the plan whose band the bench profile does not give.
    """
    lobe = lobe_of(spec)
    filters = list((spec.spectral or {}).get("filters", ()))
    if lobe is None or len(filters) < 2:
        return None
    bands = filter_bands(profile) or {}
    missing = [f for f in filters if f not in bands]
    if missing:
        raise ValueError(f"spectral.filters: slot(s) {missing} have no band in the bench "
                         f"profile {profile.name!r}")
    centres = {f: bands[f][0] for f in filters}
    mid = 0.5 * (min(centres.values()) + max(centres.values()))
    if lobe.reference_filter is not None:
        slot = lobe.reference_filter
    else:
        slot = min(filters, key=lambda f: (abs(centres[f] - mid), centres[f]))
    return ReferenceFilter(slot, centres[slot], lobe.reference_filter is not None, mid)


def candidate_pairs(spec: PlanSpec, profile: BenchProfile, step_deg: float
                    ) -> list[tuple[float, float]]:
    """Signed (θi, θr) pairs (degrees) on a ``step_deg`` grid of the plan's θr range at each
    of its θi that the guard lets the bench reach."""
    tr = spec.scan["theta_r"]
    if isinstance(tr, dict):
        lo, hi = float(tr["start"]), float(tr["stop"])
    else:
        lo, hi = float(min(tr)), float(max(tr))
    ti_values = spec.scan["theta_i"]
    if isinstance(ti_values, dict):
        n_i = math.floor((ti_values["stop"] - ti_values["start"]) / ti_values["step"] + 1e-9)
        ti_values = [ti_values["start"] + k * ti_values["step"] for k in range(n_i + 1)]
    n = math.floor((hi - lo) / step_deg + 1e-9)
    grid = [round(lo + k * step_deg, 9) for k in range(n + 1)]
    pairs = [[float(ti), float(r)] for ti in ti_values for r in grid]
    scan = {k: v for k, v in spec.scan.items()
            if k not in ("theta_i", "theta_r", "lobe", "specular", "first_pass")}
    probe = replace(spec, scan={**scan, "points": pairs})
    out = []
    for p in guarded_points(probe, profile):
        a = p.angles
        assert a is not None
        signed = a.theta_r if abs(((a.phi_r - a.phi_i) + 180.0) % 360.0 - 180.0) > 90 \
            else -a.theta_r
        ti = a.theta_i if a.phi_i < 90 or a.phi_i > 270 else -a.theta_i
        out.append((float(ti), float(signed)))
    return out


def _signed(angles_deg: np.ndarray) -> list[tuple[float, float]]:
    """Signed in-plane (θi, θr) of sample-frame angles (n, 4) in degrees."""
    out = []
    for ti, pi_, tr, pr in angles_deg:
        side = abs(((pr - pi_) + 180.0) % 360.0 - 180.0) > 90.0
        out.append((float(ti if (pi_ % 360.0 < 90 or pi_ % 360.0 > 270) else -ti),
                    float(tr if side else -tr)))
    return out


def _angles_rad(pairs: Sequence[tuple[float, float]]) -> np.ndarray:
    """(n, 4) sample-frame angles (radians) of signed in-plane pairs (plan conventions)."""
    out = np.empty((len(pairs), 4))
    for k, (ti, tr) in enumerate(pairs):
        phi_i = 0.0 if ti >= 0 else 180.0
        phi_r = (phi_i + 180.0) % 360.0 if tr >= 0 else phi_i
        out[k] = np.radians([abs(ti), phi_i, abs(tr), phi_r])
    return out


@dataclass(frozen=True)
class Placement:
    """The second pass :func:`place_points` chose.

    Attributes
    ----------
    pairs : list of (float, float)
        Signed (θi, θr) in degrees, in the order they were chosen.
    seconds : float
        Predicted acquisition and move time of the second pass (s).
    costs : list of float
        Predicted seconds of each point (the greedy order: a prefix is the design for a
        shorter budget).
    sigma_first, sigma_both : dict str → float
        Predicted standard uncertainty of each parameter after the first pass alone and
        with the second pass: the covariance the fit will report
        (:func:`instrument.plans.lobe_budget.predicted_covariance`, the fit's error budget).
    slots : list of int
        The wheel slot each chosen point is predicted to be read through (-1: open beam).
    not_measurable : int
        Candidates left out because they would clip whatever filter is in the beam.
    """

    pairs: list[tuple[float, float]]
    seconds: float
    costs: list[float]
    sigma_first: dict[str, float]
    sigma_both: dict[str, float]
    slots: list[int] = field(default_factory=list)
    not_measurable: int = 0


def _sigmas(model: BRDFModel, cov: np.ndarray) -> dict[str, float]:
    return dict(zip(model.param_names, np.sqrt(np.maximum(np.diag(cov), 0.0)).tolist(),
                    strict=True))


def _joint_shared(first_f: np.ndarray, first_slots: np.ndarray | None,
                  first_cov: np.ndarray | None, second: PointBudget, budget: ErrorBudget,
                  chosen: list[int]) -> np.ndarray | None:
    """Errors shared between the readings of both passes: the first pass's correlated
    covariance as reduced, the second pass's calibrated filters, and the filters the two
    passes share."""
    n1, n2 = first_f.size, len(chosen)
    s2 = second.slots(budget)[chosen]
    block2 = shared_covariance(second.f[chosen], s2, second.rel_shared[chosen])
    if first_cov is None and block2 is None:
        return None
    out = np.zeros((n1 + n2, n1 + n2))
    if first_cov is not None:
        out[:n1, :n1] = first_cov
    if block2 is not None:
        out[n1:, n1:] = block2
    if first_slots is not None and block2 is not None:
        rel_of = {st.slot: st.u / st.transmission for st in budget.filters if st.calibrated}
        for j, slot in enumerate(s2):
            rel = rel_of.get(int(slot), 0.0)
            if rel > 0:
                hit = np.asarray(first_slots) == slot
                out[:n1, n1 + j] = np.where(hit, first_f * second.f[chosen[j]] * rel**2, 0.0)
                out[n1 + j, :n1] = out[:n1, n1 + j]
    return out


def _weighted_information(model: BRDFModel, p: np.ndarray, cand: np.ndarray,
                         sig: np.ndarray, first: np.ndarray, sig1: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """The candidates' Jacobian rows weighted by 1/σ, and the inverse of the first pass's
    information (JᵀWJ, with a ridge that only keeps it invertible)."""
    jac = model.jacobian_geometry(p, make_geometry(*cand.T)).reshape(len(cand), -1)
    j1 = model.jacobian_geometry(p, make_geometry(*first.T)).reshape(len(first), -1)
    j1 = j1 / sig1[:, None]
    info0 = j1.T @ j1
    ridge = 1e-12 * max(float(np.trace(info0)), 1e-300)
    return jac / sig[:, None], np.linalg.inv(info0 + ridge * np.eye(p.size))


def _unmeasured(candidates: Sequence[tuple[float, float]], first: np.ndarray,
                min_separation_deg: float) -> NDArray[np.bool_]:
    """Candidates that no first-pass reading measured already. Each direction is used once,
    too: spreading the points over the region of highest information keeps the design
    robust to a model that is slightly wrong (a pile of repeats at one angle is optimal
    only if it is right)."""
    c_ti = np.array([c[0] for c in candidates])
    c_tr = np.array([c[1] for c in candidates])
    free = np.ones(len(candidates), dtype=bool)
    for ti, tr in _signed(np.degrees(first)):
        free &= ~((np.abs(c_ti - ti) < 0.05) & (np.abs(c_tr - tr) < min_separation_deg))
    return free


def _target_index(model: BRDFModel, target: str | None) -> int | None:
    """The index of the target parameter (default the model's last); None: D-optimal."""
    names = model.param_names
    return None if target == "all" else names.index(target or names[-1])


def _greedy(jac: np.ndarray, inv: np.ndarray, cost: np.ndarray, free: np.ndarray,
            n_points: int, t: int | None) -> list[int]:
    """The greedy c-optimal (target index ``t``) or D-optimal (``t`` None) choice per unit
    time among the ``free`` candidates, each used once (module docstring)."""
    free = free.copy()
    chosen: list[int] = []
    for _ in range(min(int(n_points), int(free.sum()))):
        q = np.einsum("ij,jk,ik->i", jac, inv, jac)
        if t is None:
            value = np.log1p(np.maximum(q, 0.0))
        else:
            value = (jac @ inv[:, t]) ** 2 / (1.0 + np.maximum(q, 0.0))
        gain = np.where(free, value / cost, -np.inf)
        k = int(np.argmax(gain))
        free[k] = False
        chosen.append(k)
        jk = jac[k]
        u = inv @ jk
        inv = inv - np.outer(u, u) / (1.0 + jk @ u)  # Sherman–Morrison
    return chosen


def place_points(
    model: BRDFModel,
    params: Sequence[float] | NDArray[np.float64],
    *,
    first_angles_rad: np.ndarray,
    first_sigma: np.ndarray,
    candidates: Sequence[tuple[float, float]],
    n_points: int,
    det: DetectorSetup,
    option: ScanOption,
    readout_s: float,
    frames_per_point: int,
    move_s: float,
    budget: ErrorBudget | None = None,
    first_cov: np.ndarray | None = None,
    first_slots: np.ndarray | None = None,
    min_separation_deg: float = 0.1,
    target: str | None = None,
) -> Placement:
    """Greedy c- or D-optimal placement per unit time (module docstring), each candidate
    weighed with the σ the fit will give it (:mod:`instrument.plans.lobe_budget`).

    Parameters
    ----------
    model : BRDFModel
        The model fitted to the first pass, as the instrument sees it (forward model).
    params : sequence of float
        Its fitted parameters.
    first_angles_rad : ndarray, shape (n, 4)
        The first pass's fitted (unclipped) readings' angles; ``first_sigma`` (n,) their
        independent σ as reduced (the angular term is added here from the model's slopes,
        as the fit adds it).
    candidates : sequence of (θi, θr)
        Signed in-plane pairs in degrees (:func:`candidate_pairs`).
    n_points : int
        Points of the second pass.
    det, option : DetectorSetup, ScanOption
        The planner's camera noise model and the exposure cap and frames.
    readout_s : float
        Per-frame readout overhead; ``frames_per_point`` frames (light and dark) per point.
    move_s : float
        Move and settle time added per point.
    budget : ErrorBudget
        Angular error, filters, common scale (default: none of them).
    first_cov, first_slots : ndarray or None
        The first pass's covariance of shared errors (n, n; BRDF units²) and the wheel slot
        of each of its readings (-1: open), so that a filter both passes read through
        shares its error across them.
    min_separation_deg : float
        Candidates closer than this in θr (same θi) to a first-pass point are left out.
    target : str or None
        The parameter whose variance the points should reduce (default the model's last);
        ``"all"``: D-optimal over every parameter.
    """
    budget = budget or ErrorBudget()
    p = np.asarray(params, dtype=float)
    first = np.asarray(first_angles_rad, dtype=float)
    sig1 = np.hypot(np.asarray(first_sigma, dtype=float),
                    angular_sigma(model, p, first, budget.sigma_theta_i_rad,
                                  budget.sigma_theta_r_rad))
    cand = _angles_rad(candidates)
    pb = point_budget(model, p, cand, det=det, option=option, budget=budget,
                      readout_s=readout_s)
    cost = frames_per_point * (pb.t_us * 1e-6 + readout_s) + move_s + pb.extra_s
    sig = np.where(pb.measurable, pb.sigma, 1.0)
    g1 = make_geometry(*first.T)
    jac, inv = _weighted_information(model, p, cand, sig, first, sig1)
    # never a reading predicted to clip (a lower bound the fit leaves out)
    free = pb.measurable & _unmeasured(candidates, first, min_separation_deg)
    chosen = _greedy(jac, inv, cost, free, n_points, _target_index(model, target))
    f1 = model.evaluate_geometry(p, g1)
    cov_first = predicted_covariance(model, p, first, sig1, shared=first_cov,
                                     scale_rel=budget.scale_rel)
    both = np.concatenate([first, cand[chosen]])
    shared = _joint_shared(f1, first_slots, first_cov, pb, budget, chosen)
    cov_both = predicted_covariance(model, p, both, np.concatenate([sig1, pb.sigma[chosen]]),
                                    shared=shared, scale_rel=budget.scale_rel)
    return Placement([cast("tuple[float, float]", tuple(candidates[k])) for k in chosen],
                     float(cost[chosen].sum()),
                     cost[chosen].tolist(), _sigmas(model, cov_first),
                     _sigmas(model, cov_both), pb.slots(budget)[chosen].tolist(),
                     int((~pb.measurable).sum()))


def place_points_modelled(
    model: BRDFModel,
    params: Sequence[float] | NDArray[np.float64],
    *,
    first_angles_rad: np.ndarray,
    first_sigma: np.ndarray,
    candidates: Sequence[tuple[float, float]],
    n_points: int,
    sigma_of: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    geometry_s: float,
    min_separation_deg: float = 0.1,
    target: str | None = None,
) -> Placement:
    """:func:`place_points` for readings whose σ is a function of the value alone: the
    same greedy c- or D-optimal choice per unit time, with each candidate weighed by
    ``sigma_of`` at the value the model predicts there and every geometry costing
    ``geometry_s`` seconds (a polarimetric geometry: its K retarder steps or PEM settings,
    whatever its value). No filters, angular term or shared errors: the caller's σ hold
    all the fit will use.

    ``first_angles_rad`` (n, 4) and ``first_sigma`` (n,) are the first pass's readings as
    fitted; ``candidates`` signed (θi, θr) pairs in degrees (:func:`candidate_pairs`).
    """
    p = np.asarray(params, dtype=float)
    first = np.asarray(first_angles_rad, dtype=float)
    sig1 = np.asarray(first_sigma, dtype=float)
    cand = _angles_rad(candidates)
    sig = np.asarray(sigma_of(model.evaluate_geometry(p, make_geometry(*cand.T))), float)
    jac, inv = _weighted_information(model, p, cand, sig, first, sig1)
    cost = np.full(len(cand), float(geometry_s))
    free = _unmeasured(candidates, first, min_separation_deg)
    chosen = _greedy(jac, inv, cost, free, n_points, _target_index(model, target))
    cov_first = predicted_covariance(model, p, first, sig1)
    cov_both = predicted_covariance(model, p, np.concatenate([first, cand[chosen]]),
                                    np.concatenate([sig1, sig[chosen]]))
    return Placement([cast("tuple[float, float]", tuple(candidates[k])) for k in chosen],
                     float(cost[chosen].sum()), cost[chosen].tolist(),
                     _sigmas(model, cov_first), _sigmas(model, cov_both),
                     [-1] * len(chosen), 0)


@dataclass(frozen=True)
class SinglePass:
    """The one-pass plan a second pass is weighed against: the plan's θi and θr range with
    the first pass's search around specular, its θr step the finest whose predicted
    duration fits the two passes' time (:func:`single_pass_alternative`)."""

    theta_r_step_deg: float
    n_points: int
    seconds: float
    sigma: dict[str, float]


#: θr steps (deg) a single-pass alternative is tried at, coarsest first.
SINGLE_PASS_STEPS = (20.0, 15.0, 10.0, 7.5, 5.0, 4.0, 3.0, 2.5, 2.0, 1.5, 1.0, 0.75, 0.5,
                     0.25)


def plan_seconds(plan: Plan, pb: PointBudget, readout_s: float, frames_per_point: int
                 ) -> float:
    """Predicted duration of ``plan`` (s): motion along its route (the engine's estimate)
    and each point's frames at the exposure ``pb`` predicts, with the filters' costs."""
    acq = frames_per_point * (pb.t_us * 1e-6 + readout_s) + pb.extra_s
    return float(plan.estimate().motion_s + acq[pb.measurable].sum())


def plan_budget(plan: Plan, model: BRDFModel, params: Sequence[float] | np.ndarray, *,
                det: DetectorSetup, option: ScanOption, budget: ErrorBudget,
                readout_s: float) -> tuple[np.ndarray, PointBudget]:
    """The angles (n, 4; radians) of ``plan``'s scattering points and their budget."""
    pts = [q for q in plan.points if q.angles is not None and q.light]
    # pts holds only points with angles (filtered just above)
    ang = np.radians(np.array([q.angles.as_tuple() for q in pts]))  # type: ignore[union-attr]
    return ang, point_budget(model, np.asarray(params, dtype=float), ang, det=det,
                             option=option, budget=budget, readout_s=readout_s)


def single_pass_plans(spec: PlanSpec, profile: BenchProfile) -> Iterator[tuple[float, Plan]]:
    """The one-pass plans a lobe plan is weighed against, coarsest first: its θi and θr
    range at each step of :data:`SINGLE_PASS_STEPS`, with the first pass's search around
    specular (built one at a time: the caller stops at the first its time cannot pay)."""
    lobe = lobe_of(spec)
    assert lobe is not None
    scan = {k: v for k, v in spec.scan.items() if k not in ("lobe", "specular")}
    scan["specular"] = {"half_width_deg": lobe.search_half_width_deg,
                        "step_deg": lobe.search_step_deg}
    tr = spec.scan["theta_r"]
    lo, hi = ((float(tr["start"]), float(tr["stop"])) if isinstance(tr, dict)
              else (float(min(tr)), float(max(tr))))
    for step in SINGLE_PASS_STEPS:
        one = replace(spec, scan={**scan, "theta_r": {"start": lo, "stop": hi, "step": step}})
        yield step, build_plan(one, profile)


def single_pass_alternative(spec: PlanSpec, profile: BenchProfile, model: BRDFModel,
                            params: Sequence[float] | NDArray[np.float64], *, seconds: float,
                            det: DetectorSetup,
                            option: ScanOption, budget: ErrorBudget, readout_s: float,
                            frames_per_point: int) -> SinglePass:
    """The densest single-pass plan (:data:`SINGLE_PASS_STEPS`) that the lobe plan's two
    passes' ``seconds`` pay for, with its predicted σ (the same error budget); the coarsest
    when none fits."""
    p = np.asarray(params, dtype=float)
    best: SinglePass | None = None
    for step, plan in single_pass_plans(spec, profile):
        ang, pb = plan_budget(plan, model, p, det=det, option=option, budget=budget,
                              readout_s=readout_s)
        dur = plan_seconds(plan, pb, readout_s, frames_per_point)
        if best is not None and dur > seconds:
            break
        ok = pb.measurable
        cov = predicted_covariance(model, p, ang[ok], pb.sigma[ok],
                                   shared=shared_covariance(pb.f[ok], pb.slots(budget)[ok],
                                                            pb.rel_shared[ok]),
                                   scale_rel=budget.scale_rel)
        best = SinglePass(step, int(ok.sum()), dur, _sigmas(model, cov))
    assert best is not None
    return best


def pass_move_seconds(profile: BenchProfile, step_deg: float) -> float:
    """Move and settle time of one small in-plane step of ``step_deg`` on the slowest
    goniometer axis: the per-point motion a densely placed second pass costs."""
    dyn = dynamics_of(profile, ("sample_theta", "detector_theta"))
    return max(move_time(step_deg, d) for d in dyn.values())


# ------------------------------------------------------------------------------ TOML out
def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to a plan file")


def second_pass_text(first_text: str, pairs: Sequence[tuple[float, float]],
                     first_pass: str) -> str:
    """The plan file of the second pass: the first pass's plan with its ``[scan]`` replaced
    by the explicit ``points`` and ``first_pass`` (other scan options, such as
    ``skip_beam_points``, kept)."""
    data = tomllib.loads(first_text)
    scan = {k: v for k, v in data.get("scan", {}).items()
            if k not in ("theta_i", "theta_r", "lobe", "specular", "first_pass")}
    scan["points"] = [[round(float(a), 6), round(float(b), 6)] for a, b in pairs]
    scan["first_pass"] = str(first_pass)
    data["scan"] = scan
    plan = dict(data.get("plan", {}))
    plan["name"] = f"{plan.get('name', 'lobe')} (second pass)"
    data["plan"] = plan
    lines = ["# Second pass of a two-pass lobe plan (instrument.plans.lobe): points placed",
             "# by Fisher information after the first pass named in first_pass."]
    # a polarimetric or spectral first pass: the second pass takes the same settings
    for section in ("plan", "sample", "scan", "acquisition", "calibration", "spectral",
                    "polarimetry"):
        if section not in data:
            continue
        lines.append(f"\n[{section}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in data[section].items()]
    text = "\n".join(lines) + "\n"
    parse_plan(text, source="second pass")  # what we write must read back
    return text


@dataclass(frozen=True)
class SecondPass:
    """The second pass: its plan, the placement behind it, the model that guided it, and
    the single pass of equal time it was weighed against (``worthwhile``: it beats it)."""

    plan: Plan
    placement: Placement
    model: str
    verdict: str
    target: str
    first_seconds: float
    second_seconds: float
    alternative: SinglePass
    #: where the lobe was fitted, for a plan over several filters (else "")
    fitted_at: str = ""

    @property
    def worthwhile(self) -> bool:
        return self.placement.sigma_both[self.target] < self.alternative.sigma[self.target]

    def refusal(self) -> str:
        """The one line that says why the second pass is not run."""
        a = self.alternative
        t = self.target
        return (f"second pass not run: it cannot beat a single pass of equal time — "
                f"predicted σ({t}) {self.placement.sigma_both[t]:.3g} with it "
                f"({self.first_seconds + self.second_seconds:.0f} s for both passes) against "
                f"{a.sigma[t]:.3g} for one pass with θr every {a.theta_r_step_deg:g}° "
                f"({a.n_points} points, {a.seconds:.0f} s); scan that plan instead")
