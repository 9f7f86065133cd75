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
   lobe averaged over beam and pupil), and σ includes the set-point scatter |∂F/∂θ|σθ, so
   points gather where the measured lobe curves, not on flanks steeper than the axes can
   hold. Each direction is used once (and none the first pass measured): the points
   spread over the region of highest information instead of piling onto its best angle,
   which keeps the design robust when the model is slightly wrong.

The second pass is a plan of explicit ``points`` with ``first_pass`` naming the first
pass's run (:func:`second_pass_text`); the analysis reduces the two runs together.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from analysis.brdf.geometry import make_geometry
from analysis.brdf.model import BRDFModel
from instrument.bench.dynamics import move_time
from instrument.bench.profile import BenchProfile
from instrument.plans.build import dynamics_of, guarded_points
from instrument.plans.planfile import PlanSpec, parse_plan
from instrument.plans.tradeoff import DetectorSetup, ScanOption, _point_noise

__all__ = ["LobeSpec", "Placement", "candidate_pairs", "lobe_of", "place_points",
           "second_pass_text"]


@dataclass(frozen=True)
class LobeSpec:
    """The ``[scan] lobe`` table of a plan (module docstring)."""

    points: int
    step_deg: float = 0.25
    search_half_width_deg: float = 5.0
    search_step_deg: float = 1.0
    prior: str | None = None
    target: str | None = None


def lobe_of(spec: PlanSpec) -> LobeSpec | None:
    """The plan's lobe option, or None for a one-pass plan."""
    lb = spec.scan.get("lobe")
    if lb is None:
        return None
    return LobeSpec(int(lb["points"]), float(lb.get("step_deg", 0.25)),
                    float(lb.get("search_half_width_deg", 5.0)),
                    float(lb.get("search_step_deg", 1.0)), lb.get("prior"), lb.get("target"))


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
        with the second pass (Cramér–Rao, the planner's noise model).
    """

    pairs: list[tuple[float, float]]
    seconds: float
    costs: list[float]
    sigma_first: dict[str, float]
    sigma_both: dict[str, float]


def _information(model: BRDFModel, params: np.ndarray, angles: np.ndarray,
                 sigma: np.ndarray) -> np.ndarray:
    g = make_geometry(*angles.T)
    j = model.jacobian_geometry(params, g).reshape(len(angles), -1)
    return (j / sigma[:, None]).T @ (j / sigma[:, None])


def _sigmas(model: BRDFModel, info: np.ndarray) -> dict[str, float]:
    cov = np.linalg.pinv(info, rcond=1e-12)
    return dict(zip(model.param_names, np.sqrt(np.maximum(np.diag(cov), 0.0)).tolist(),
                    strict=True))


def place_points(
    model: BRDFModel,
    params: Sequence[float],
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
    sigma_theta_rad: float = 0.0,
    min_separation_deg: float = 0.1,
    target: str | None = None,
) -> Placement:
    """Greedy D-optimal placement per unit time (module docstring).

    Parameters
    ----------
    model : BRDFModel
        The model fitted to the first pass, as the instrument sees it (forward model).
    params : sequence of float
        Its fitted parameters.
    first_angles_rad : ndarray, shape (n, 4)
        The first pass's angles; ``first_sigma`` (n,) its standard uncertainties.
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
    sigma_theta_rad : float
        Set-point uncertainty of the axes (adds |∂F/∂θr|σθ to each candidate's σ).
    min_separation_deg : float
        Candidates closer than this in θr (same θi) to a first-pass point are left out.
    target : str or None
        The parameter whose variance the points should reduce (default the model's last);
        ``"all"``: D-optimal over every parameter.
    """
    p = np.asarray(params, dtype=float)
    cand = _angles_rad(candidates)
    g = make_geometry(*cand.T)
    f = model.evaluate_geometry(p, g)
    f = np.maximum(f, 1e-300)
    rel, t_us = _point_noise(f, cand[:, 0], cand[:, 2], option, det)
    sig = rel * f
    if sigma_theta_rad > 0:
        h = 1e-4
        up = cand.copy()
        dn = cand.copy()
        up[:, 2] = np.clip(up[:, 2] + h, 0.0, np.pi / 2)
        dn[:, 2] = np.clip(dn[:, 2] - h, 0.0, np.pi / 2)
        slope = (model.evaluate_geometry(p, make_geometry(*up.T))
                 - model.evaluate_geometry(p, make_geometry(*dn.T))) / np.maximum(
                     up[:, 2] - dn[:, 2], 1e-12)
        sig = np.hypot(sig, slope * sigma_theta_rad)
    cost = frames_per_point * (t_us * 1e-6 + readout_s) + move_s
    jac = model.jacobian_geometry(p, g).reshape(len(cand), -1) / sig[:, None]
    info0 = _information(model, p, np.asarray(first_angles_rad, dtype=float),
                         np.asarray(first_sigma, dtype=float))
    ridge = 1e-12 * max(float(np.trace(info0)), 1e-300)
    inv = np.linalg.inv(info0 + ridge * np.eye(p.size))
    info = info0.copy()
    # each direction once, and none the first pass measured already: spreading the
    # points over the region of highest information keeps the design robust to a model
    # that is slightly wrong (a pile of repeats at one angle is optimal only if it is right)
    c_ti = np.array([c[0] for c in candidates])
    c_tr = np.array([c[1] for c in candidates])
    free = np.ones(len(cand), dtype=bool)
    for ti, tr in _signed(np.degrees(np.asarray(first_angles_rad, dtype=float))):
        free &= ~((np.abs(c_ti - ti) < 0.05) & (np.abs(c_tr - tr) < min_separation_deg))
    chosen: list[int] = []
    names = model.param_names
    t = None if target == "all" else names.index(target or names[-1])
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
        info = info + np.outer(jk, jk)
    return Placement([tuple(candidates[k]) for k in chosen], float(cost[chosen].sum()),
                     cost[chosen].tolist(), _sigmas(model, info0), _sigmas(model, info))


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
    for section in ("plan", "sample", "scan", "acquisition", "calibration"):
        if section not in data:
            continue
        lines.append(f"\n[{section}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in data[section].items()]
    text = "\n".join(lines) + "\n"
    parse_plan(text, source="second pass")  # what we write must read back
    return text
