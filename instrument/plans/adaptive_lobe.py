"""Sharp-lobe refinement: an adaptive plan that measures a specular lobe's width α.

1. **Coarse pass** (the base plan): θr on a coarse grid at one incidence θi, and a search
   of ±``search_half_width_deg`` around the mirror direction at ``search_step_deg``, so a
   narrow peak near specular is found wherever it lies.
2. **Refinement**, after every batch: the readings so far are fitted with a microfacet lobe
   on a constant, in the half-angle θh = (θr − θi − δ)/2 of the in-plane geometry,

       y(θr) = b + A · α⁴ / (cos⁴θh · (α² + tan²θh)²),

   the GGX (Trowbridge–Reitz) distribution D(θh) of Walter et al., "Microfacet models for
   refraction through rough surfaces", EGSR 2007, eq. 33, scaled to 1 at its peak (the
   Fresnel, shadowing and cosine factors vary slowly across a sharp lobe and are absorbed
   in A). Its parameters are p = (b, A, δ, α); the readings are weighted by their σ when
   known, otherwise as shot-noise limited (variance ∝ the fitted reading plus 1 % of the
   peak), with the scale taken from the residuals (χ²/dof). The covariance is
   C = s² (JᵀWJ)⁻¹.
3. The next ``batch`` points are chosen on a ``step_deg`` grid within ``window_deg`` of
   the fitted peak, one at a time, each where it most decreases the variance of α: by
   Sherman–Morrison a reading with Jacobian row j and weight w lowers Var(α) by
   w (e_αᵀ C j)² / (1 + w jᵀ C j) (c-optimal sequential design: Atkinson, Donev & Tobias,
   *Optimum Experimental Designs*, 2007, §10.1–10.3 and §11.2), C being updated after each
   choice. No direction is measured twice.
4. The plan stops when the fit's σ(α) reaches ``target_sigma_alpha``, the estimated
   instrument time of the points planned (``History.seconds``) reaches ``budget_s``, or
   the run holds ``max_points`` points.

The fitted α is the lobe *as the instrument sees it* (averaged over beam and pupil),
which is what decides where points help; the BRDF analysis (``scatterlab fit``) fits the
finished run with its forward model as for any run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from scipy.optimize import least_squares

from instrument.plans.adaptive import History, Measured, Proposal, register
from instrument.plans.planfile import PlanSpec
from instrument.plans.scripted import in_plane

__all__ = ["LobeFit", "SharpLobe", "fit_lobe", "lobe_model"]


def lobe_model(theta_r_deg: np.ndarray, theta_i_deg: float,
               p: Sequence[float] | np.ndarray) -> np.ndarray:
    """y(θr) of the module docstring for p = (b, A, δ in degrees, α)."""
    b, a, delta, alpha = p
    th = np.radians(np.asarray(theta_r_deg, float) - theta_i_deg - delta) / 2.0
    t2 = np.tan(th) ** 2
    return b + a * alpha**4 / (np.cos(th) ** 4 * (alpha**2 + t2) ** 2)


def _jacobian(theta_r: np.ndarray, theta_i: float, p: np.ndarray) -> np.ndarray:
    """∂y/∂p by central differences (steps relative to each parameter's scale)."""
    steps = np.array([max(abs(p[0]), abs(p[1])) * 1e-6 + 1e-12, abs(p[1]) * 1e-6 + 1e-12,
                      1e-4, max(abs(p[3]), 1e-4) * 1e-5])
    cols = []
    for k, h in enumerate(steps):
        hi, lo = p.copy(), p.copy()
        hi[k] += h
        lo[k] -= h
        cols.append((lobe_model(theta_r, theta_i, hi) - lobe_model(theta_r, theta_i, lo))
                    / (2 * h))
    return np.stack(cols, axis=-1)


@dataclass(frozen=True)
class LobeFit:
    params: np.ndarray       # (b, A, δ deg, α)
    cov: np.ndarray          # 4 × 4
    floor: float             # the variance model's constant term (signal units)
    scale: float             # s² = χ²/dof of the weighted fit

    @property
    def alpha(self) -> float:
        return float(self.params[3])

    @property
    def sigma_alpha(self) -> float:
        return float(math.sqrt(max(self.cov[3, 3], 0.0)))

    def variance(self, y: np.ndarray) -> np.ndarray:
        """The variance model at readings ``y`` (module docstring, step 2)."""
        return cast(np.ndarray, self.scale * (np.maximum(y, 0.0) + self.floor))  # stubs: Any


def fit_lobe(points: Sequence[Measured], theta_i: float) -> LobeFit | None:
    """Fit the lobe model to the measured points at incidence ``theta_i`` (None: fewer than
    six usable readings, or a fit that does not converge to a lobe)."""
    pts = [p for p in points if p.ok and math.isfinite(p.signal) and math.isfinite(p.theta_r)
           and abs(p.theta_i - theta_i) < 0.5]
    if len(pts) < 6:
        return None
    x = np.array([p.theta_r for p in pts])
    y = np.array([p.signal for p in pts])
    u = np.array([p.u_signal for p in pts])
    known = bool(np.all(np.isfinite(u) & (u > 0)))
    k = int(np.argmax(y))
    b0 = float(np.median(np.sort(y)[: max(1, len(y) // 3)]))
    a0 = max(float(y[k] - b0), 1e-12)
    above = x[y - b0 >= a0 / 2]
    fwhm = max(float(above.max() - above.min()) if above.size > 1 else 1.0, 0.5)
    alpha0 = min(max(math.tan(math.radians(fwhm) / 4) / 0.6436, 0.005), 0.5)
    p0 = np.array([b0, a0, float(x[k] - theta_i), alpha0])
    floor = 0.01 * a0
    sig = u if known else np.sqrt(np.maximum(y, 0.0) + floor)
    for _ in range(2):  # the second pass weighs by the fitted readings, not the noisy ones
        res = least_squares(lambda p, s=sig: (lobe_model(x, theta_i, p) - y) / s, p0,
                            bounds=([-np.inf, 0.0, -20.0, 1e-4], [np.inf, np.inf, 20.0, 2.0]),
                            x_scale=np.array([a0, a0, 1.0, alpha0]))
        p0 = res.x
        if not known:
            sig = np.sqrt(np.maximum(lobe_model(x, theta_i, p0), 0.0) + floor)
    dof = max(len(x) - 4, 1)
    scale = 1.0 if known else float(np.sum(res.fun**2) / dof)
    jw = _jacobian(x, theta_i, p0) / sig[:, None]
    try:
        cov = np.linalg.inv(jw.T @ jw) * scale
    except np.linalg.LinAlgError:
        return None
    if not (res.success and np.all(np.isfinite(cov)) and p0[1] > 0):
        return None
    return LobeFit(p0, cov, floor if not known else float(np.median(u**2)), scale)


@register("sharp_lobe")
class SharpLobe:
    """The sharp-lobe refinement (module docstring) at one incidence ``theta_i`` (deg).

    Parameters
    ----------
    theta_r : (start, stop, step) of the coarse pass in degrees, signed as in a plan file.
    search_half_width_deg, search_step_deg : the coarse search around the mirror direction.
    target_sigma_alpha : stop when the fit's σ(α) is at or below this.
    budget_s : stop when the points planned take this long (instrument time, estimated).
    batch : points chosen per decision; step_deg : their grid; window_deg : how far from
        the fitted peak they may lie.
    max_points : stop when the run holds this many points (None: no limit).
    acquisition, sample : the plan's ``[acquisition]`` table and sample name.
    seed : offsets the refinement grid by a seeded fraction of a step, so repeated runs do
        not all sample the same directions; stored, so a resumed run decides the same.
    """

    def __init__(self, theta_i: float = 30.0, *, theta_r: Sequence[float] = (-70, 80, 10),
                 search_half_width_deg: float = 4.0, search_step_deg: float = 1.0,
                 target_sigma_alpha: float = 1e-3, budget_s: float = 600.0, batch: int = 4,
                 step_deg: float = 0.25, window_deg: float = 15.0,
                 max_points: int | None = None,
                 acquisition: dict[str, Any] | None = None, sample: str = "sample",
                 seed: int | None = 0) -> None:
        self.theta_i = float(theta_i)
        self.theta_r = tuple(float(v) for v in theta_r)
        self.search_half_width_deg = float(search_half_width_deg)
        self.search_step_deg = float(search_step_deg)
        self.target_sigma_alpha = float(target_sigma_alpha)
        self.budget_s = float(budget_s)
        self.batch = int(batch)
        self.step_deg = float(step_deg)
        self.window_deg = float(window_deg)
        self.max_points = None if max_points is None else int(max_points)
        self.acquisition = dict(acquisition or {})
        self.sample = str(sample)
        self.seed = 0 if seed is None else int(seed)
        rng = np.random.default_rng(self.seed)
        self._offset = float(rng.uniform(0.0, self.step_deg))
        #: The newest fit (None before the first decision or when it failed).
        self.fit: LobeFit | None = None

    @property
    def base(self) -> PlanSpec:
        start, stop, step = self.theta_r
        return in_plane(theta_i=[self.theta_i],
                        theta_r={"start": start, "stop": stop, "step": step},
                        specular={"half_width_deg": self.search_half_width_deg,
                                  "step_deg": self.search_step_deg},
                        skip_beam_points=True,  # the coarse grid may cross the beam
                        acquisition=self.acquisition or None, sample=self.sample,
                        name="sharp-lobe refinement")

    def curve(self, theta_r_deg: Sequence[float] | np.ndarray) -> np.ndarray:
        """The newest fit's lobe at signed ``theta_r_deg`` (NaN before a fit)."""
        x = np.asarray(theta_r_deg, float)
        if self.fit is None:
            return np.full(x.shape, np.nan)
        return lobe_model(x, self.theta_i, self.fit.params)

    def describe(self) -> dict[str, Any]:
        return {"name": "sharp_lobe", "seed": self.seed, "params": {
            "theta_i": self.theta_i, "theta_r": list(self.theta_r),
            "search_half_width_deg": self.search_half_width_deg,
            "search_step_deg": self.search_step_deg,
            "target_sigma_alpha": self.target_sigma_alpha, "budget_s": self.budget_s,
            "batch": self.batch, "step_deg": self.step_deg, "window_deg": self.window_deg,
            "max_points": self.max_points,
            "acquisition": self.acquisition, "sample": self.sample}}

    def propose(self, history: History) -> list[Proposal] | None:
        n = len(history.points)
        if history.seconds >= self.budget_s or (self.max_points is not None
                                                and n >= self.max_points):
            return None
        fit = fit_lobe(history.points, self.theta_i)
        self.fit = fit
        if fit is None:
            return None
        if fit.sigma_alpha <= self.target_sigma_alpha:
            return None
        room = self.batch if self.max_points is None else min(self.batch, self.max_points - n)
        return [Proposal(self.theta_i, float(t)) for t in self._choose(fit, history, room)]

    def _choose(self, fit: LobeFit, history: History, room: int) -> list[float]:
        peak = self.theta_i + float(fit.params[2])
        k = np.arange(-math.floor(self.window_deg / self.step_deg),
                      math.floor(self.window_deg / self.step_deg) + 1)
        cand = peak + self._offset - self.step_deg / 2 + k * self.step_deg
        cand = cand[np.abs(cand) < 89.0]
        taken = [p.theta_r for p in history.points if abs(p.theta_i - self.theta_i) < 0.5]
        taken += [r.proposal.theta_r for r in history.refused]
        if taken:
            near = np.min(np.abs(cand[:, None] - np.array(taken)[None, :]), axis=1)
            cand = cand[near >= self.step_deg / 2]
        if cand.size == 0:
            return []
        jac = _jacobian(cand, self.theta_i, fit.params)
        w = 1.0 / fit.variance(lobe_model(cand, self.theta_i, fit.params))
        cov = fit.cov.copy()
        chosen: list[float] = []
        free = np.ones(cand.size, bool)
        for _ in range(min(room, cand.size)):
            cj = jac @ cov                                   # (n, 4): rows (C j)ᵀ
            gain = w * cj[:, 3] ** 2 / (1.0 + w * np.einsum("ij,ij->i", cj, jac))
            gain[~free] = -np.inf
            best = int(np.argmax(gain))
            if not np.isfinite(gain[best]) or gain[best] <= 0:
                break
            chosen.append(float(cand[best]))
            free[best] = False
            c = cj[best]
            cov -= w[best] * np.outer(c, c) / (1.0 + w[best] * c @ jac[best])
        return sorted(chosen)
