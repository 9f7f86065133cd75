"""Bounded least-squares fitting of BRDF models with uncertainties.

Method
------
* Parameters flagged ``log`` in the model (widths, exponents) are fitted as u = ln p, the
  others as u = p; bounds are mapped accordingly (a width spanning decades is well
  conditioned in its logarithm).
* Residuals r_j, chosen by ``residual``:

  - ``"absolute"``: r = (y − m)/σ, σ the per-point standard uncertainty (1 if not given);
  - ``"relative"``: r = (y − m)/|y|, divided by σ/|y| instead when σ is given (i.e. the same
    as absolute with σ) — without σ it is the fit of relative errors;
  - ``"log"``: r = (ln(y⁺+ε) − ln(m⁺+ε))/s with s = σ/(y⁺+ε) when σ is given, else 1; ε =
    ``log_floor`` keeps zeros finite (the log-relative metric of Nielsen, Jensen &
    Ramamoorthi, SIGGRAPH Asia 2015) and x⁺ =
    max(x, 0): a reading that noise (dark or signature subtraction) pushed below zero counts
    as zero instead of making the residual NaN.

* The noise model is explicit: the r_j are independent N(0, s²), with s = 1 when σ is given
  (``sigma`` known) and s estimated as √(χ²/dof) otherwise. The log-likelihood, AIC, AICc and
  BIC follow from it (:func:`information_criteria`); an estimated s counts as one more
  parameter. Likelihood constants that do not depend on the model are dropped, so compare
  criteria only between fits of the same data with the same residual and noise settings.
* ``loss`` ∈ {"linear", "soft_l1", "huber", "cauchy", "arctan"} is passed to
  :func:`scipy.optimize.least_squares` (robust loss keeps outliers and the specular peak from
  dominating); information criteria assume "linear".
* The Jacobian of the residuals is analytic where the model provides ∂f/∂p
  (chain rule through the log parameterisation and the residual transform), otherwise
  central differences on the cached geometry — the geometry is built once per fit.
* Solver: for the plain (linear) loss a lean Levenberg–Marquardt with Marquardt's diagonal
  scaling on the k×k normal equations and an active-set treatment of the box bounds
  (Levenberg 1944; Marquardt 1963; Nocedal & Wright §10.3) — one residual and one Jacobian
  evaluation per iteration and no n×k factorisation, which is what makes fits of 10⁴ points
  take milliseconds (benchmarks/bench_brdf_fit.py). Robust losses, or an LM run that does
  not converge, use :func:`scipy.optimize.least_squares` (``method="trf"``); ``solver``
  forces either.
* Multi-start: the default start plus ``n_starts − 1`` seeded random starts (log-uniform for
  log parameters), keeping the lowest cost.
* Covariance: C_u = s² (JᵀJ)⁺ at the optimum (pseudo-inverse; rank deficiency is flagged),
  mapped to natural units with the diagonal d p/d u (= p for log parameters); correlations
  from C. Optional case-resampling bootstrap (``n_bootstrap``) gives a second set of standard
  errors and percentile intervals.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.geometry import Geometry, make_geometry
from analysis.brdf.model import BRDFModel

_RESIDUALS = ("absolute", "relative", "log")
_LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")
# Marquardt damping: start and shrink factor after a successful step (Nielsen-style tuning;
# chosen on the benchmark problem and the test suite, see bench_brdf_fit.py)
_LM_LAMBDA0 = 1e-2
_LM_SHRINK = 3.0


@dataclass(frozen=True)
class BootstrapResult:
    """Case-resampling bootstrap of a fit.

    Attributes
    ----------
    samples : ndarray, shape (B_ok, k)
        Parameter vectors of the converged replicates (natural units).
    stderr : ndarray, shape (k,)
        Sample standard deviation of ``samples``.
    ci_low, ci_high : ndarray, shape (k,)
        2.5 % and 97.5 % percentiles.
    n_failed : int
        Replicates that did not converge (excluded).
    """

    samples: NDArray[np.float64]
    stderr: NDArray[np.float64]
    ci_low: NDArray[np.float64]
    ci_high: NDArray[np.float64]
    n_failed: int


@dataclass(frozen=True)
class FitResult:
    """Result of :func:`fit_brdf`.

    Attributes
    ----------
    model_name : str
    param_names, units : tuple of str
    params, stderr : ndarray, shape (k,)
        Best-fit values and 1σ standard errors from the covariance (natural units).
    covariance, correlation : ndarray, shape (k, k)
    chi2 : float
        Σ r² of the normalised residuals (the loss is not applied).
    dof : int
        n − k.
    noise_scale : float
        s: 1 if σ was given, else √(χ²/dof).
    log_likelihood, aic, aicc, bic : float
        From the noise model (see the module docstring).
    residuals : ndarray, shape (n,)
        Normalised residuals r at the optimum.
    converged : bool
    message : str
    nfev : int
        Model evaluations of the best start.
    at_bound : tuple of bool
        Parameters that ended on a bound (their standard errors are unreliable).
    rank_deficient : bool
        JᵀJ was singular at the optimum (parameters not all identifiable).
    residual_kind, loss : str
    noise_model : str
        The assumed noise model in words (for reports).
    bootstrap : BootstrapResult or None
    """

    model_name: str
    param_names: tuple[str, ...]
    units: tuple[str, ...]
    params: NDArray[np.float64]
    stderr: NDArray[np.float64]
    covariance: NDArray[np.float64]
    correlation: NDArray[np.float64]
    chi2: float
    dof: int
    noise_scale: float
    log_likelihood: float
    aic: float
    aicc: float
    bic: float
    residuals: NDArray[np.float64] = field(repr=False)
    converged: bool
    message: str
    nfev: int
    at_bound: tuple[bool, ...]
    rank_deficient: bool
    residual_kind: str
    loss: str
    noise_model: str = ""
    bootstrap: BootstrapResult | None = None

    @property
    def n_params(self) -> int:
        return len(self.params)

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    def param_dict(self) -> dict[str, float]:
        """{name: value}."""
        return dict(zip(self.param_names, (float(v) for v in self.params), strict=True))

    def to_dict(self) -> dict[str, object]:
        """Plain Python/NumPy values (for storing in a run file's analysis group or JSON)."""
        out: dict[str, object] = {
            "model": self.model_name,
            "param_names": list(self.param_names),
            "units": list(self.units),
            "params": self.params.tolist(),
            "stderr": self.stderr.tolist(),
            "covariance": self.covariance.tolist(),
            "correlation": self.correlation.tolist(),
            "chi2": self.chi2,
            "dof": self.dof,
            "noise_scale": self.noise_scale,
            "log_likelihood": self.log_likelihood,
            "aic": self.aic,
            "aicc": self.aicc,
            "bic": self.bic,
            "converged": self.converged,
            "message": self.message,
            "nfev": self.nfev,
            "at_bound": list(self.at_bound),
            "rank_deficient": self.rank_deficient,
            "residual_kind": self.residual_kind,
            "loss": self.loss,
            "noise_model": self.noise_model,
        }
        if self.bootstrap is not None:
            out["bootstrap_stderr"] = self.bootstrap.stderr.tolist()
            out["bootstrap_ci_low"] = self.bootstrap.ci_low.tolist()
            out["bootstrap_ci_high"] = self.bootstrap.ci_high.tolist()
            out["bootstrap_n"] = int(self.bootstrap.samples.shape[0])
        return out

    def table(self) -> list[tuple[str, float, float, str]]:
        """Rows (name, value, stderr, unit) for reports."""
        return [
            (n, float(v), float(e), u)
            for n, v, e, u in zip(
                self.param_names, self.params, self.stderr, self.units, strict=True
            )
        ]


@dataclass(frozen=True)
class _Problem:
    """Everything the residual function needs, computed once per fit."""

    model: BRDFModel
    geometry: Geometry
    y: NDArray[np.float64]
    scale: NDArray[np.float64]  # divides the residual
    residual: str
    log_floor: float
    log_mask: NDArray[np.bool_]

    @property
    def inv_scale(self) -> NDArray[np.float64]:
        # cached on first use: the residual and Jacobian multiply by it every iteration
        cached = self.__dict__.get("_inv_scale")
        if cached is None:
            cached = 1.0 / self.scale
            object.__setattr__(self, "_inv_scale", cached)
        return cached


def _to_internal(p: NDArray[Any], log_mask: NDArray[Any]) -> NDArray[Any]:
    return np.where(log_mask, np.log(np.where(log_mask, p, 1.0)), p)


def _to_natural(u: NDArray[Any], log_mask: NDArray[Any]) -> NDArray[Any]:
    return np.where(log_mask, np.exp(np.where(log_mask, u, 0.0)), u)


def _residuals(u: NDArray[Any], pr: _Problem) -> NDArray[Any]:
    p = _to_natural(u, pr.log_mask)
    m = pr.model.value_fn(p, pr.geometry)
    if pr.residual == "log":
        r = np.log(np.maximum(pr.y, 0.0) + pr.log_floor) - np.log(
            np.maximum(m, 0.0) + pr.log_floor)
        return r * pr.inv_scale
    return (pr.y - m) * pr.inv_scale


def _jacobian(u: NDArray[Any], pr: _Problem) -> NDArray[Any]:
    p = _to_natural(u, pr.log_mask)
    jf = pr.model.jacobian_geometry(p, pr.geometry)  # (n, k), ∂m/∂p; a fresh array
    jf *= -np.where(pr.log_mask, p, 1.0)  # ∂p/∂u and the sign of r = y − m
    if pr.residual == "log":
        m = pr.model.value_fn(p, pr.geometry)
        jf *= (pr.inv_scale / (np.maximum(m, 0.0) + pr.log_floor))[:, None]
        return jf
    jf *= pr.inv_scale[:, None]
    return jf


def information_criteria(
    chi2: float, n: int, k: int, *, sigma_known: bool, log_scale_sum: float = 0.0
) -> tuple[float, float, float, float]:
    """(log L, AIC, AICc, BIC) of Gaussian residuals.

    Known scale (s = 1): −2 ln L = χ² + n ln 2π + 2 Σ ln σ_j.
    Unknown scale (profiled, ŝ² = χ²/n): −2 ln L = n (ln(2π χ²/n) + 1) + 2 Σ ln σ_j, and the
    scale counts as a parameter. AIC = −2 ln L + 2k', AICc = AIC + 2k'(k'+1)/(n − k' − 1),
    BIC = −2 ln L + k' ln n (Akaike 1974; Hurvich & Tsai 1989; Schwarz 1978).
    ``log_scale_sum`` is Σ ln σ_j of the residual normalisation (model independent).
    """
    kk = k if sigma_known else k + 1
    if sigma_known:
        m2ll = chi2 + n * np.log(2.0 * np.pi) + 2.0 * log_scale_sum
    else:
        m2ll = n * (np.log(2.0 * np.pi * max(chi2, 1e-300) / n) + 1.0) + 2.0 * log_scale_sum
    aic = m2ll + 2.0 * kk
    aicc = aic + (2.0 * kk * (kk + 1) / (n - kk - 1) if n - kk - 1 > 0 else np.inf)
    bic = m2ll + kk * np.log(n)
    return -0.5 * m2ll, float(aic), float(aicc), float(bic)


def _internal_bounds(model: BRDFModel) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Bounds in the fitted coordinates u (ln p for log parameters)."""
    lm = model.log_mask
    lo = _to_internal(model.lower, lm)
    with np.errstate(divide="ignore"):
        hi = np.where(lm, np.log(np.where(lm, model.upper, 1.0)), model.upper)
    return lo, np.where(np.isinf(model.upper), np.inf, hi)


def _random_starts(model: BRDFModel, n: int, rng: np.random.Generator) -> list[NDArray[Any]]:
    """Random starts: log-uniform over the bounds for log parameters; uniform between the
    lower bound and 4× the default start's distance from it for linear ones (scale bounds
    such as ks ≤ 100 are deliberately wide, while the values that matter lie near the
    default start)."""
    lo, hi, lm = model.lower, model.upper, model.log_mask
    starts = []
    for _ in range(n):
        p = np.empty(model.n_params)
        for j in range(model.n_params):
            if lm[j]:
                a = np.log(lo[j])
                b = np.log(hi[j]) if np.isfinite(hi[j]) else a + 10.0
                p[j] = np.exp(rng.uniform(a, b))
            else:
                b = min(hi[j], lo[j] + 4.0 * max(abs(model.start[j] - lo[j]), 1e-3))
                p[j] = rng.uniform(lo[j], b)
        starts.append(p)
    return starts


def _covariance(
    jac: NDArray[Any], s2: float, p: NDArray[Any], log_mask: NDArray[Any]
) -> tuple[NDArray[Any], bool]:
    """s²(JᵀJ)⁺ in natural units and a rank-deficiency flag.

    Works on the k×k matrix JᵀJ with its columns equilibrated (unit diagonal) and an
    eigen-decomposition: cheap for n ≫ k, and eigenvalues below 1e-12 of the largest
    (singular values below 1e-6 relative, i.e. parameters not identifiable at any useful
    precision) are treated as zero. Variances along such directions are NaN.
    """
    a = jac.T @ jac
    dg = np.sqrt(np.diag(a))
    dg = np.where(dg > 0, dg, 1.0)
    w, v = np.linalg.eigh(a / np.outer(dg, dg))
    keep = w > 1e-12 * max(float(w.max()), 1e-300)
    rank_def = not bool(np.all(keep))
    inv = np.zeros_like(w)
    inv[keep] = 1.0 / w[keep]
    cov_u = (v * inv) @ v.T / np.outer(dg, dg) * s2
    d = np.where(log_mask, p, 1.0)
    cov = cov_u * np.outer(d, d)
    if rank_def:
        # directions with no information have unbounded variance
        bad = np.any(np.abs(v[:, ~keep]) > 1e-8, axis=1)
        cov[bad, :] = np.nan
        cov[:, bad] = np.nan
    return cov, rank_def


@dataclass(frozen=True)
class _SolveResult:
    x: NDArray[np.float64]
    cost: float
    status: int
    message: str
    nfev: int
    jac: NDArray[np.float64] | None = None  # residual Jacobian at x, when already known


def _lm_solve(
    u0: NDArray[np.float64],
    pr: _Problem,
    lo: NDArray[np.float64],
    hi: NDArray[np.float64],
    *,
    max_iter: int = 200,
    ftol: float = 1e-10,
    xtol: float = 1e-10,
    gtol: float = 1e-10,
) -> _SolveResult:
    """Levenberg–Marquardt on the normal equations with active-set box bounds.

    Minimises ½‖r(u)‖². A coordinate on a bound whose gradient points outwards is held fixed
    for that iteration; the step of the others is projected back into the box.
    """
    u = np.clip(u0, lo, hi)
    r = _residuals(u, pr)
    cost = 0.5 * float(r @ r)
    jac = _jacobian(u, pr)
    nfev = 1
    a = jac.T @ jac
    lam = _LM_LAMBDA0
    for _ in range(max_iter):
        g = jac.T @ r  # ½∇(r·r)
        span = 1e-12 * np.maximum(1.0, np.abs(u))
        active = ((u <= lo + span) & (g > 0)) | ((u >= hi - span) & (g < 0))
        free = ~active
        if not np.any(free) or np.max(np.abs(g[free])) <= gtol * max(2.0 * cost, 1e-300):
            return _SolveResult(u, cost, 1, "gradient tolerance reached", nfev)
        af = a[np.ix_(free, free)]
        d = np.maximum(np.diag(af), 1e-300)
        first_try = True
        while True:
            step = np.zeros_like(u)
            try:
                step[free] = np.linalg.solve(af + lam * np.diag(d), -g[free])
            except np.linalg.LinAlgError:
                lam *= 10.0
                if lam > 1e16:
                    return _SolveResult(u, cost, 0, "singular normal equations", nfev)
                continue
            if first_try and lam < 1.0:
                # Gauss–Newton model reduction −gᵀδ − ½δᵀAδ: when even the (nearly) undamped
                # step cannot gain ftol·cost, u is the optimum; skip evaluating it.
                pred = -float(g @ step) - 0.5 * float(step @ a @ step)
                if pred <= ftol * cost:
                    return _SolveResult(u, cost, 2, "predicted reduction below tolerance",
                                        nfev, jac)
            first_try = False
            u_new = np.clip(u + step, lo, hi)
            r_new = _residuals(u_new, pr)
            nfev += 1
            cost_new = 0.5 * float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new <= cost:
                dx = float(np.linalg.norm(u_new - u))
                small_f = cost - cost_new <= ftol * cost
                small_x = dx <= xtol * (xtol + float(np.linalg.norm(u)))
                u, r, cost = u_new, r_new, cost_new
                if small_f or small_x:
                    return _SolveResult(u, cost, 2, "cost or step tolerance reached", nfev)
                lam = max(lam / _LM_SHRINK, 1e-12)
                jac = _jacobian(u, pr)
                a = jac.T @ jac
                break
            lam *= 4.0
            if lam > 1e16:
                return _SolveResult(u, cost, 2, "no further decrease possible", nfev)
    return _SolveResult(u, cost, 0, "maximum number of iterations reached", nfev)


def _solve(
    p0: NDArray[np.float64],
    pr: _Problem,
    lo_u: NDArray[np.float64],
    hi_u: NDArray[np.float64],
    *,
    loss: str,
    f_scale: float,
    solver: str,
    max_nfev: int | None,
    ftol: float = 1e-10,
) -> _SolveResult:
    """One local optimisation from natural-unit start ``p0`` (see the module docstring)."""
    u0 = np.clip(_to_internal(p0, pr.log_mask), lo_u, hi_u)
    # strictly inside the box: trf requires it, and it avoids starting on an active set
    span = np.where(np.isfinite(hi_u - lo_u), hi_u - lo_u, 1.0)
    u0 = np.clip(u0, lo_u + 1e-10 * span, hi_u - 1e-10 * span)
    if solver == "lm" or (solver == "auto" and loss == "linear"):
        res = _lm_solve(u0, pr, lo_u, hi_u, max_iter=max_nfev or 200, ftol=ftol)
        if res.status > 0 or solver == "lm":
            return res
        u0 = np.clip(res.x, lo_u + 1e-10 * span, hi_u - 1e-10 * span)
    # SciPy's optimiser is imported where it is used: importing this module (the bench
    # server, the planners and the emulated bench reach it through analysis.brdf) then
    # does not load scipy.optimize, about 1 s of CPU per process that never fits.
    from scipy.optimize import least_squares

    ls = least_squares(
        _residuals,
        u0,
        jac=_jacobian,
        bounds=(lo_u, hi_u),
        method="trf",
        loss=loss,
        f_scale=f_scale,
        x_scale="jac",
        max_nfev=max_nfev,
        args=(pr,),
    )
    return _SolveResult(
        ls.x, float(ls.cost), int(ls.status), str(ls.message), int(ls.nfev),
        ls.jac if loss == "linear" else None,  # for a robust loss ls.jac is rescaled
    )


def fit_brdf(
    model: BRDFModel,
    brdf: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike | None = None,
    residual: str = "absolute",
    loss: str = "linear",
    f_scale: float = 1.0,
    start: ArrayLike | None = None,
    n_starts: int = 1,
    seed: int = 0,
    n_bootstrap: int = 0,
    log_floor: float = 1e-6,
    max_nfev: int | None = None,
    geometry: Geometry | None = None,
    solver: str = "auto",
    ftol: float = 1e-10,
) -> FitResult:
    """Fit ``model`` to measured BRDF values.

    Parameters
    ----------
    model : BRDFModel
    brdf : array_like, shape (n,)
        Measured BRDF (1/sr). Not modified.
    theta_i, phi_i, theta_r, phi_r : array_like, broadcast to shape (n,)
        Geometry in radians (conventions of :mod:`analysis.brdf.geometry`).
    sigma : array_like or None
        Standard uncertainty of ``brdf`` (same unit), scalar or shape (n,). When given the
        noise scale is known (s = 1); otherwise it is estimated.
    residual : {"absolute", "relative", "log"}
    loss : {"linear", "soft_l1", "huber", "cauchy", "arctan"}
    f_scale : float
        Soft margin of the robust loss (in units of the normalised residual).
    start : array_like or None
        Start vector (natural units); default the model's.
    n_starts : int
        Total starts (≥ 1), the extra ones random with ``seed``.
    n_bootstrap : int
        Bootstrap replicates (0 = none), resampling cases with ``seed``.
    log_floor : float
        ε of the log residual.
    geometry : Geometry or None
        Prebuilt geometry of the n points (saves rebuilding it, e.g. in cross-validation).
    solver : {"auto", "lm", "trf"}
        "auto": the lean LM for the linear loss (falling back to TRF if it does not
        converge), TRF otherwise; "lm" is only valid with the linear loss.
    ftol : float
        Relative cost change at which the LM iteration stops (default 1e-10; a screening
        fit that only needs χ² to 10⁻⁶ may stop at 1e-7).

    Returns
    -------
    FitResult
    """
    if residual not in _RESIDUALS:
        raise ValueError(f"residual must be one of {_RESIDUALS}")
    if loss not in _LOSSES:
        raise ValueError(f"loss must be one of {_LOSSES}")
    if n_starts < 1:
        raise ValueError("n_starts must be at least 1")
    if solver not in ("auto", "lm", "trf") or (solver == "lm" and loss != "linear"):
        raise ValueError("solver must be 'auto', 'trf' or 'lm' (lm needs loss='linear')")
    y_in = np.asarray(brdf, dtype=float)
    y = y_in.reshape(-1)
    if geometry is None:
        try:
            angles = [
                np.broadcast_to(np.asarray(a, dtype=float), y_in.shape).reshape(-1)
                for a in (theta_i, phi_i, theta_r, phi_r)
            ]
        except ValueError as err:
            raise ValueError(f"angles do not broadcast to the brdf shape {y_in.shape}") from err
        g = make_geometry(*angles)
    else:
        g = geometry
        if g.shape != y.shape:
            raise ValueError(f"geometry has shape {g.shape} but brdf has {y.shape} values")
    if not np.all(np.isfinite(y)):
        raise ValueError("brdf contains NaN or inf")
    n = y.size
    k = model.n_params
    if n <= k:
        raise ValueError(f"need more data points ({n}) than parameters ({k})")
    sigma_known = sigma is not None
    sig = (
        np.ones(n)
        if sigma is None
        else np.broadcast_to(np.asarray(sigma, float), y_in.shape).reshape(-1).copy()
    )
    if np.any(sig <= 0):
        raise ValueError("sigma must be positive")
    if residual == "absolute":
        scale = sig
    elif residual == "relative":
        scale = sig if sigma_known else np.maximum(np.abs(y), log_floor)
    else:
        scale = sig / (np.maximum(y, 0.0) + log_floor) if sigma_known else np.ones(n)
    log_mask = model.log_mask
    pr = _Problem(model, g, y, scale, residual, float(log_floor), log_mask)

    lo_u, hi_u = _internal_bounds(model)
    p0 = model.start if start is None else np.asarray(start, dtype=float).reshape(-1)
    if p0.size != k:
        raise ValueError(f"start must have {k} values")
    rng = np.random.default_rng(seed)
    starts = [np.clip(p0, model.lower, model.upper), *_random_starts(model, n_starts - 1, rng)]

    best = None
    for s in starts:
        res = _solve(s, pr, lo_u, hi_u, loss=loss, f_scale=f_scale, solver=solver,
                     max_nfev=max_nfev, ftol=ftol)
        if best is None or res.cost < best.cost:
            best = res
    assert best is not None
    fit = _finish(model, pr, best, sigma_known, float(np.sum(np.log(scale))), loss)
    if n_bootstrap > 0:
        boot = _bootstrap(
            model, pr, fit.params, loss=loss, f_scale=f_scale, solver=solver,
            n_boot=n_bootstrap, seed=seed,
        )
        fit = replace(fit, bootstrap=boot)
    return fit


def _describe_noise(residual: str, sigma_known: bool) -> str:
    r = {
        "absolute": "(y − f)/σ" if sigma_known else "y − f",
        "relative": "(y − f)/σ" if sigma_known else "(y − f)/|y|",
        "log": "(ln y − ln f)·y/σ" if sigma_known else "ln y − ln f",
    }[residual]
    s = "s = 1 (σ given)" if sigma_known else "s estimated from χ²/dof"
    return f"independent Gaussian: r = {r} ~ N(0, s²), {s}"


def _finish(
    model: BRDFModel,
    pr: _Problem,
    res: _SolveResult,
    sigma_known: bool,
    log_scale_sum: float,
    loss: str,
) -> FitResult:
    u = np.asarray(res.x)
    p = _to_natural(u, pr.log_mask)
    r = _residuals(u, pr)
    n, k = r.size, p.size
    chi2 = float(r @ r)
    dof = n - k
    s2 = 1.0 if sigma_known else chi2 / dof
    jac = res.jac if res.jac is not None else _jacobian(u, pr)
    cov, rank_def = _covariance(jac, s2, p, pr.log_mask)
    with np.errstate(invalid="ignore"):
        stderr = np.sqrt(np.diag(cov))
        corr = cov / np.outer(stderr, stderr)
    ll, aic, aicc, bic = information_criteria(
        chi2, n, k, sigma_known=sigma_known, log_scale_sum=float(log_scale_sum)
    )
    lo, hi = model.lower, model.upper
    tol = 1e-6 * np.maximum(1.0, np.abs(p))
    at_bound = tuple(bool(b) for b in (np.abs(p - lo) <= tol) | (np.abs(p - hi) <= tol))
    return FitResult(
        model_name=model.name,
        param_names=model.param_names,
        units=model.units,
        params=p,
        stderr=stderr,
        covariance=cov,
        correlation=corr,
        chi2=chi2,
        dof=dof,
        noise_scale=float(np.sqrt(s2)),
        log_likelihood=float(ll),
        aic=aic,
        aicc=aicc,
        bic=bic,
        residuals=r,
        # a non-finite residual (model NaN somewhere) leaves the solver where it started:
        # never report that as converged
        converged=res.status > 0 and bool(np.isfinite(chi2)),
        message=res.message,
        nfev=res.nfev,
        at_bound=at_bound,
        rank_deficient=rank_def,
        residual_kind=pr.residual,
        loss=loss,
        noise_model=_describe_noise(pr.residual, sigma_known),
    )


def _bootstrap(
    model: BRDFModel,
    pr: _Problem,
    p_best: NDArray[Any],
    *,
    loss: str,
    f_scale: float,
    solver: str,
    n_boot: int,
    seed: int,
) -> BootstrapResult:
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xB007]))
    n = pr.y.size
    log_mask = pr.log_mask
    lo_u, hi_u = _internal_bounds(model)
    samples = []
    failed = 0
    for _ in range(n_boot):
        idx = rng.integers(0, n, n)
        sub = _Problem(
            model, pr.geometry.take(idx), pr.y[idx], pr.scale[idx], pr.residual,
            pr.log_floor, log_mask,
        )
        res = _solve(p_best, sub, lo_u, hi_u, loss=loss, f_scale=f_scale, solver=solver,
                     max_nfev=None)
        if res.status > 0:
            samples.append(_to_natural(res.x, log_mask))
        else:
            failed += 1
    arr = np.array(samples).reshape(-1, model.n_params)
    if arr.shape[0] >= 2:
        se = arr.std(axis=0, ddof=1)
        lo_ci, hi_ci = np.percentile(arr, [2.5, 97.5], axis=0)
    else:
        se = lo_ci = hi_ci = np.full(model.n_params, np.nan)
    return BootstrapResult(arr, se, lo_ci, hi_ci, failed)


@dataclass(frozen=True)
class PredictionBand:
    """Model prediction with its 1σ uncertainty from the parameter covariance.

    Attributes
    ----------
    value : ndarray, shape S
        f(θ; p̂).
    stderr : ndarray, shape S
        √(g_θᵀ C g_θ), g_θ = ∂f/∂p (delta method; first order in the parameter errors).
    """

    value: NDArray[np.float64]
    stderr: NDArray[np.float64]


def prediction_band(
    model: BRDFModel,
    fit: FitResult,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
) -> PredictionBand:
    """Fitted BRDF and its standard uncertainty at new angles (radians), for uncertainty
    bands in reports. Uses ``fit.covariance`` (NaN where a parameter is unidentifiable)."""
    if fit.param_names != model.param_names:
        raise ValueError(f"fit is of {fit.model_name!r}, not of {model.name!r}")
    g = make_geometry(theta_i, phi_i, theta_r, phi_r)
    val = model.evaluate_geometry(fit.params, g)
    jac = model.jacobian_geometry(fit.params, g)
    var = np.einsum("...i,ij,...j->...", jac, fit.covariance, jac)
    return PredictionBand(val, np.sqrt(np.maximum(var, 0.0)))
