"""BRDF model fits with selection, the goodness-of-fit gate and physical checks.

:func:`analyse` fits every candidate model to the reduced points as the instrument saw
them, chooses the smallest model the data support, and checks that the choice describes
the data:

1. **Forward model.** With the reduction's receiver geometry (what each reading
   integrated: beam footprint and divergence, receiver aperture, axis set-point spread;
   :mod:`analysis.brdf.reduction.receiver`) every candidate is fitted as the instrument
   sees it, with the quadrature refined per point until it is well below the noise and the
   set-point scatter taken from the model's own slopes
   (:func:`analysis.brdf.reduction.fit_forward`). Readings the detector clipped (lower
   bounds, not values) are left out and named.
2. **Selection.** Information criterion (BIC by default) with grouped-by-θi
   cross-validation as the check
   (:func:`analysis.brdf.reduction.candidates.select_forward`). Without a receiver
   geometry the BRDF is fitted at the nominal angles
   (:func:`analysis.brdf.selection.select_model`).
3. **Uncertainties.** The run's common scale uncertainty and the errors correlated between
   points (camera pixel response) are added to every fit's covariance
   (:func:`analysis.brdf.reduction.with_scale_uncertainty`,
   :func:`~analysis.brdf.reduction.with_correlated_uncertainty`).
4. **Goodness of fit gates every result** (:mod:`analysis.brdf.goodness`, ADR 0051): a
   fit whose χ² has p < 0.001 does not describe the data; its standard errors are
   multiplied by the Birge ratio √(χ²/ν), it is flagged, and the disagreeing points are
   named.
5. **Physical checks.** Helmholtz reciprocity of the *data* where a geometry was measured
   both ways, and the directional–hemispherical reflectance of the chosen and plausible
   models (≤ 1 where the model promises energy conservation; Nicodemus et al. 1977).

:func:`model_band` gives a model's value with its standard uncertainty σ_f² = J C Jᵀ from
the parameter covariance (the report's ±1σ bands).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from analysis.brdf import get_model
from analysis.brdf.fit import FitResult, fit_brdf
from analysis.brdf.geometry import Geometry, make_geometry
from analysis.brdf.goodness import (
    DEFAULT_ALPHA,
    GoodnessOfFit,
    goodness_of_fit,
    offset_pattern,
)
from analysis.brdf.integrate import dhr
from analysis.brdf.model import BRDFModel
from analysis.brdf.reduction import (
    BRDFPoints,
    ReciprocityCheck,
    reciprocity_check,
    with_correlated_uncertainty,
    with_scale_uncertainty,
)
from analysis.brdf.reduction.candidates import select_forward
from analysis.brdf.registry import default_candidates
from analysis.brdf.selection import SelectionResult, select_model

__all__ = ["DEFAULT_MODELS", "UNCERTAINTY_RULE", "AnalysisResult", "analyse", "model_band",
           "model_band_at"]

#: Candidates when ``--models`` is not given: every family of the library alone and every
#: sum of one diffuse and one specular or physical-optics model
#: (:func:`analysis.brdf.registry.default_candidates`).
DEFAULT_MODELS = default_candidates()
#: How the uncertainties of a rejected model are reported (docs/decisions/0051).
UNCERTAINTY_RULE = ("when the model does not describe the data (χ² p < 0.001), its "
                    "standard errors are multiplied by the Birge ratio √(χ²/dof) and "
                    "flagged as inflated: they make the residuals consistent, they do not "
                    "make the model right")
#: The information-criterion margin by which a larger candidate must beat a smaller one
#: ("strong" evidence on Kass & Raftery's 1995 scale, ΔBIC 6–10). With 23 candidates of
#: different shapes, some fit a correct smaller model's noise better by 2–6 by chance: at
#: the "positive" margin of 2 a Lambertian sample came back as a larger model in 25 % of
#: closed-loop scans (benchmarks/bench_brdf_closed_loop.py --matrix).
SELECTION_DELTA = 6.0
_DHR_THETA_DEG = np.arange(0.0, 86.0, 5.0)


@dataclass(frozen=True)
class AnalysisResult:
    """Fits, the selection, the goodness-of-fit verdicts and the checks of one run.

    Attributes
    ----------
    selection : SelectionResult
        As fitted (covariances without the common scale; residuals of the fitted points).
    fits : dict str → FitResult
        The fits to report: common scale and correlated errors in their covariance, and
        for a model the data reject, standard errors multiplied by the Birge ratio.
    models : dict str → BRDFModel
        The models as fitted (forward models at their final quadrature levels).
    dhr_theta_deg : ndarray, shape (m,)
    dhr : dict str → ndarray (m,)
        DHR of the chosen and the plausible models at ``dhr_theta_deg``.
    reciprocity : ReciprocityCheck
    notes : tuple of str
    goodness : dict str → GoodnessOfFit
        χ² test of every fit; ``disagreeing`` indexes the *fitted* points
        (``fitted_index`` maps them to the reduced points).
    inflation : dict str → float
        The factor each fit's standard errors were multiplied by (1: not inflated).
    fitted_index : ndarray of int
        The reduced points that were fitted (all but the clipped ones).
    excluded_index : ndarray of int
        The reduced points left out (clipped readings: lower bounds).
    plausible : tuple of str
        Models within the plausible margin of the best score.
    """

    selection: SelectionResult
    fits: dict[str, FitResult]
    models: dict[str, BRDFModel]
    dhr_theta_deg: np.ndarray
    dhr: dict[str, np.ndarray]
    reciprocity: ReciprocityCheck
    notes: tuple[str, ...] = field(default=())
    goodness: dict[str, GoodnessOfFit] = field(default_factory=dict)
    inflation: dict[str, float] = field(default_factory=dict)
    fitted_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    excluded_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    plausible: tuple[str, ...] = ()

    @property
    def chosen(self) -> str:
        return self.selection.chosen

    @property
    def chosen_fit(self) -> FitResult:
        return self.fits[self.selection.chosen]

    @property
    def chosen_goodness(self) -> GoodnessOfFit:
        return self.goodness[self.selection.chosen]

    @property
    def adequate(self) -> bool:
        """Whether the chosen model describes the data (the gate of every result)."""
        return self.chosen_goodness.adequate

    @property
    def verdict(self) -> str:
        return self.chosen_goodness.verdict()

    def disagreeing_points(self) -> list[tuple[int, float]]:
        """(index into the reduced points, normalised residual) of the chosen fit's
        disagreeing points, largest first."""
        gof = self.chosen_goodness
        return [(int(self.fitted_index[j]), r)
                for j, r in zip(gof.disagreeing, gof.residuals, strict=True)]

    def to_dict(self) -> dict[str, Any]:
        sel = self.selection.to_dict()
        sel.pop("fits", None)
        return {
            "selection": sel,
            "fits": {k: f.to_dict() for k, f in self.fits.items()},
            "dhr_theta_deg": self.dhr_theta_deg.tolist(),
            "dhr": {k: v.tolist() for k, v in self.dhr.items()},
            "reciprocity": {"pairs": self.reciprocity.pairs.tolist(),
                            "ratio": self.reciprocity.ratio.tolist(),
                            "z": self.reciprocity.z.tolist()},
            "notes": list(self.notes),
            "goodness": {k: {**g.to_dict(), "disagreeing_points": [
                int(self.fitted_index[j]) for j in g.disagreeing]}
                for k, g in self.goodness.items()},
            "verdict": self.verdict,
            "model_adequate": self.adequate,
            "uncertainty_rule": UNCERTAINTY_RULE,
            "inflation": dict(self.inflation),
            "fitted_points": self.fitted_index.tolist(),
            "excluded_points": self.excluded_index.tolist(),
            "plausible": list(self.plausible),
        }


def _inflated(fit: FitResult, factor: float) -> FitResult:
    """The fit with its covariance scaled by factor² (standard errors by factor)."""
    if factor == 1.0:
        return fit
    return replace(fit, stderr=fit.stderr * factor, covariance=fit.covariance * factor**2)


def analyse(
    points: BRDFPoints,
    models: Sequence[str] = DEFAULT_MODELS,
    *,
    criterion: str = "bic",
    run_cv: bool = True,
    n_starts: int = 3,
    seed: int = 0,
    instrument_aware: bool = True,
    n_bootstrap: int = 0,
    alpha: float = DEFAULT_ALPHA,
    wavelength_nm: float | None = None,
    delta: float = SELECTION_DELTA,
) -> AnalysisResult:
    """Fit, select, gate and check (module docstring). ``points`` may be cosine-corrected;
    the fits use the BRDF f either way.

    ``n_bootstrap`` > 0 refits the chosen model to that many case-resampled copies of the
    points (seeded with ``seed``; :func:`analysis.brdf.fit.fit_brdf`) and attaches the
    bootstrap σ and 95 % percentile interval to its fit: a check of the covariance σ that
    does not assume a linear model. It resamples the independent noise only, so it is to be
    compared with the σ *before* the common scale and pixel-response terms are added.

    ``alpha`` is the p-value below which a model is rejected; ``wavelength_nm`` sets the
    wavelength of the models that depend on it (Rayleigh–Rice); ``delta`` is the
    information-criterion margin a larger model must beat a smaller one by
    (:data:`SELECTION_DELTA`).
    """
    f_all, u_all = points.plain_brdf()
    use = points.valid
    idx = np.flatnonzero(use)
    excluded = np.flatnonzero(~use)
    k_max = max(get_model(m).n_params for m in models)
    if idx.size <= k_max:
        raise ValueError(f"only {idx.size} unclipped points for models of up to {k_max} "
                         "parameters")
    if np.any(u_all[idx] <= 0):
        raise ValueError("every point needs a positive uncertainty to be fitted")
    lam = None if wavelength_nm is None else 1e-3 * float(wavelength_nm)
    # keyed by the model's own name: the fits are, and an alias ("lambertian") must
    # find its model again
    base = {mod.name: mod for mod in (get_model(m, wavelength_um=lam) for m in models)}
    a = tuple(np.asarray(x)[idx] for x in (points.theta_i, points.phi_i, points.theta_r,
                                           points.phi_r))
    f = f_all[idx]
    receiver = points.receiver if instrument_aware else None
    plausible: tuple[str, ...]
    if receiver is not None:
        # the plausible models are refitted with the angular scatter from their own slopes
        fs = select_forward(list(base.values()), f, *a, sigma=u_all[idx], receiver=receiver,
                            sigma_indep=points.plain_u_indep()[idx], criterion=criterion,
                            delta=delta, run_cv=run_cv, seed=seed, n_starts=n_starts)
        sel = fs.selection
        by_name = {n: ff.model for n, ff in fs.forward.items()}
        sigma_of = {n: ff.sigma for n, ff in fs.forward.items()}
        plausible = fs.plausible
        quad_notes = [n for ff in fs.forward.values() for n in ff.notes]
    else:
        u = u_all[idx]
        sel = select_model(list(base.values()), f, *a, sigma=u, criterion=criterion,
                           delta=delta, run_cv=run_cv, n_starts=n_starts, seed=seed)
        by_name = dict(base)
        sigma_of = {n: u for n in base}
        plausible = tuple(base)
        quad_notes = []
    cov = points.plain_cov_corr()
    if cov is not None:
        cov = cov[np.ix_(idx, idx)]
    fits: dict[str, FitResult] = {}
    goodness: dict[str, GoodnessOfFit] = {}
    inflation: dict[str, float] = {}
    for name, fit in sel.fits.items():
        goodness[name] = goodness_of_fit(fit.residuals, fit.n_params, alpha=alpha)
        if not fit.converged:
            # nothing to propagate through a failed fit (its Jacobian may be NaN): it is
            # kept as it is and flagged in the notes
            fits[name] = fit
            continue
        fit = with_scale_uncertainty(fit, by_name[name], *a, sigma=sigma_of[name],
                                     scale_rel=points.u_scale_rel)
        if cov is not None:
            # errors shared between points (camera pixel response): propagated, not fitted
            fit = with_correlated_uncertainty(fit, by_name[name], *a, sigma=sigma_of[name],
                                              cov=cov)
        factor = 1.0 if goodness[name].adequate else goodness[name].birge_ratio
        inflation[name] = factor
        fits[name] = _inflated(fit, factor)
    if n_bootstrap > 0:
        chosen = sel.chosen
        boot = fit_brdf(by_name[chosen], f, *a, sigma=sigma_of[chosen],
                        start=sel.fits[chosen].params, n_bootstrap=n_bootstrap,
                        seed=seed).bootstrap
        fits[chosen] = replace(fits[chosen], bootstrap=boot)
    shown = [n for n in fits if n == sel.chosen or n in plausible]
    dhr_vals = {name: np.asarray(dhr(base[name], fits[name].params,
                                     np.radians(_DHR_THETA_DEG), n_mu=48, n_phi=96))
                for name in shown if fits[name].converged}
    notes = _notes(points, sel, fits, goodness, dhr_vals, by_name, excluded, quad_notes)
    offset = _offset_note(sel.chosen, sel.fits[sel.chosen], base[sel.chosen], a,
                          sigma_of[sel.chosen], goodness[sel.chosen])
    if offset:
        notes.append(offset)
    return AnalysisResult(sel, fits, by_name, _DHR_THETA_DEG.copy(), dhr_vals,
                          reciprocity_check(points.take(idx)), tuple(notes), goodness,
                          inflation, idx, excluded, plausible)


def _notes(points: BRDFPoints, sel: SelectionResult, fits: dict[str, FitResult],
           goodness: dict[str, GoodnessOfFit], dhr_vals: dict[str, np.ndarray],
           models: dict[str, BRDFModel], excluded: np.ndarray,
           quad_notes: list[str]) -> list[str]:
    notes = []
    if excluded.size:
        deg = np.degrees
        where = ", ".join(f"{k} (θi={deg(points.theta_i[k]):.1f}°, "
                          f"θr={deg(points.theta_r[k]):.1f}°)" for k in excluded[:10])
        notes.append(f"{excluded.size} clipped reading(s) left out of the fits (pixels "
                     f"saturated even in the shortest exposure; lower bounds, not values): "
                     f"points {where}" + (" …" if excluded.size > 10 else ""))
    chosen = sel.chosen
    gof = goodness[chosen]
    if not gof.adequate:
        notes.append(f"{chosen}: the model does not describe the data — "
                     f"{gof.summary()}; parameter σ inflated ×{gof.birge_ratio:.3g}")
    elif gof.too_good:
        notes.append(f"{chosen}: χ² improbably small ({gof.summary()}): the stated "
                     "uncertainties of the data are likely too large")
    row = {r.name: r for r in sel.table}
    twins = [r.name for r in sel.table if r.name != chosen and r.converged
             and r.n_params == row[chosen].n_params
             and abs(r.score(sel.criterion if sel.criterion != "cv" else "bic")
                     - row[chosen].score(sel.criterion if sel.criterion != "cv" else "bic"))
             <= 2.0]
    if twins:
        notes.append(f"{chosen}: the data do not tell it from {', '.join(twins)} (same number "
                     "of parameters, information criterion within 2)")
    for name, vals in dhr_vals.items():
        finite = vals[np.isfinite(vals)]
        if models[name].energy_bounded and finite.size and finite.max() > 1.0 + 1e-3:
            notes.append(f"{name}: fitted DHR reaches {finite.max():.3f} > 1 "
                         "(energy not conserved by these parameters)")
    for name, fit in fits.items():
        if fit.rank_deficient:
            notes.append(f"{name}: parameters not all identifiable from these data")
        if not fit.converged:
            notes.append(f"{name}: the fit did not converge ({fit.message}); its "
                         "parameters and scores are not reliable")
    notes.extend(quad_notes)
    return notes


def _offset_note(name: str, fit: FitResult, model: BRDFModel, angles: tuple[np.ndarray, ...],
                 sigma: np.ndarray, gof: GoodnessOfFit) -> str | None:
    """A rejected fit whose residuals are mostly a constant offset of the detector reading
    (:func:`analysis.brdf.goodness.offset_pattern`; in BRDF units such an offset goes as
    1/cos θr): the note names the likely cause and the fix."""
    if gof.adequate or not fit.converged:
        return None
    template = 1.0 / np.maximum(np.cos(angles[2]), 1e-3)
    jac = model.jacobian_geometry(fit.params, make_geometry(*angles)).reshape(
        -1, fit.n_params)
    pat = offset_pattern(fit.residuals, sigma, template, jacobian=jac, dof=gof.dof)
    if not pat.looks_like_offset():
        return None
    return (f"{name}: the residuals look like a constant offset of every detector reading "
            f"(a term ∝ 1/cos θr, {pat.z:+.1f}σ, explains {pat.fraction:.0%} of the excess "
            "χ²): a dark reading (the photodiode's dark current, ambient light, a lock-in's "
            "pickup) was probably not subtracted — set [acquisition] dark = \"per_point\" "
            "(or \"start\") in the plan so that every detector is read with the light off, "
            "and fit again; until then the parameters are biased by it")


def model_band(model: BRDFModel, fit: FitResult, theta_i: np.ndarray, phi_i: np.ndarray,
               theta_r: np.ndarray, phi_r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Model value and its standard uncertainty σ_f = √(J C Jᵀ) at the given angles."""
    return model_band_at(model, fit, make_geometry(theta_i, phi_i, theta_r, phi_r))


def model_band_at(model: BRDFModel, fit: FitResult, g: Geometry
                  ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`model_band` on a prepared geometry: the receiver's quadrature nodes are cached
    on ``g``, so the curves of several models at the same angles share them."""
    val = model.evaluate_geometry(fit.params, g)
    jac = model.jacobian_geometry(fit.params, g).reshape(-1, fit.n_params)
    cov = np.nan_to_num(fit.covariance)
    var = np.einsum("ij,jk,ik->i", jac, cov, jac)
    return val, np.sqrt(np.maximum(var, 0.0)).reshape(val.shape)
