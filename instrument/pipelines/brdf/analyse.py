"""BRDF model fits with selection and physical checks, from reduced points.

:func:`analyse` fits every candidate model to the reduced points with their independent
uncertainties (``u_point``) as a known noise scale, chooses the smallest model the data
support (:func:`analysis.brdf.selection.select_model`: information criterion with the
comparison table, grouped-by-θi cross-validation scores kept), then adds the run's common
scale uncertainty and the errors correlated between points (camera pixel response) to
every fit's covariance (:func:`analysis.brdf.reduction.with_scale_uncertainty`,
:func:`~analysis.brdf.reduction.with_correlated_uncertainty`). Physical checks: Helmholtz
reciprocity of the *data* where a geometry was measured both ways, and the
directional–hemispherical reflectance of each fitted model (≤ 1 where the model promises
energy conservation; Nicodemus et al. 1977).

:func:`model_band` gives a model's value with its standard uncertainty
σ_f² = J C Jᵀ from the parameter covariance (the report's ±1σ bands).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from analysis.brdf import get_model
from analysis.brdf.fit import FitResult, fit_brdf
from analysis.brdf.geometry import make_geometry
from analysis.brdf.integrate import dhr
from analysis.brdf.model import BRDFModel
from analysis.brdf.reduction import (
    BRDFPoints,
    ReciprocityCheck,
    receiver_model,
    reciprocity_check,
    with_correlated_uncertainty,
    with_scale_uncertainty,
)
from analysis.brdf.selection import SelectionResult, select_model

__all__ = ["DEFAULT_MODELS", "AnalysisResult", "analyse", "model_band"]

#: Candidates when ``--models`` is not given: diffuse, rough diffuse, diffuse + glossy lobe.
DEFAULT_MODELS = ("lambert", "oren_nayar", "lambert+ggx")
_DHR_THETA_DEG = np.arange(0.0, 86.0, 5.0)


@dataclass(frozen=True)
class AnalysisResult:
    """Fits, the selection and the checks of one reduced run.

    Attributes
    ----------
    selection : SelectionResult
        As fitted (covariances without the common scale).
    fits : dict str → FitResult
        The same fits with the common scale uncertainty in their covariance (report these).
    models : dict str → BRDFModel
    dhr_theta_deg : ndarray, shape (m,)
    dhr : dict str → ndarray (m,)
        DHR of each fitted model at ``dhr_theta_deg``.
    reciprocity : ReciprocityCheck
    """

    selection: SelectionResult
    fits: dict[str, FitResult]
    models: dict[str, BRDFModel]
    dhr_theta_deg: np.ndarray
    dhr: dict[str, np.ndarray]
    reciprocity: ReciprocityCheck
    notes: tuple[str, ...] = field(default=())

    @property
    def chosen(self) -> str:
        return self.selection.chosen

    @property
    def chosen_fit(self) -> FitResult:
        return self.fits[self.selection.chosen]

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
        }


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
) -> AnalysisResult:
    """Fit, select and check (module docstring). ``points`` may be cosine-corrected; the
    fits use the BRDF f either way.

    ``n_bootstrap`` > 0 refits the chosen model to that many case-resampled copies of the
    points (seeded with ``seed``; :func:`analysis.brdf.fit.fit_brdf`) and attaches the
    bootstrap σ and 95 % percentile interval to its fit: a check of the covariance σ that
    does not assume a linear model. It resamples the independent noise only, so it is to be
    compared with the σ *before* the common scale and pixel-response terms are added.

    With ``instrument_aware`` and a receiver geometry on ``points`` (the reduction records
    what each reading integrated: beam footprint and receiver aperture), every candidate is
    fitted as the receiver sees it (:func:`analysis.brdf.reduction.receiver_model`):
    near a specular peak a reading is the average of f over the directions from the
    footprint to the aperture, a few 10⁻⁴ below the peak value on the sim bench — many σ at
    high signal. The DHR checks use the BRDF itself.
    """
    f, u = points.plain_brdf()
    if np.any(u <= 0):
        raise ValueError("every point needs a positive uncertainty to be fitted")
    base = {m: get_model(m) for m in models}
    if instrument_aware and points.receiver is not None:
        cands = [receiver_model(b, points.receiver) for b in base.values()]
    else:
        cands = list(base.values())
    a = (points.theta_i, points.phi_i, points.theta_r, points.phi_r)
    sel = select_model(cands, f, *a, sigma=u, criterion=criterion, run_cv=run_cv,
                       n_starts=n_starts, seed=seed)
    by_name = {m.name: m for m in cands}
    cov = points.plain_cov_corr()
    fits = {}
    for name, fit in sel.fits.items():
        if not fit.converged:
            # nothing to propagate through a failed fit (its Jacobian may be NaN): it is
            # kept as it is and flagged in the notes
            fits[name] = fit
            continue
        fit = with_scale_uncertainty(fit, by_name[name], *a, sigma=u,
                                     scale_rel=points.u_scale_rel)
        if cov is not None:
            # errors shared between points (camera pixel response): propagated, not fitted
            fit = with_correlated_uncertainty(fit, by_name[name], *a, sigma=u, cov=cov)
        fits[name] = fit
    if n_bootstrap > 0:
        chosen = sel.chosen
        boot = fit_brdf(by_name[chosen], f, *a, sigma=u, start=sel.fits[chosen].params,
                        n_bootstrap=n_bootstrap, seed=seed).bootstrap
        fits[chosen] = replace(fits[chosen], bootstrap=boot)
    dhr_vals = {name: np.asarray(dhr(get_model(name), fit.params, np.radians(_DHR_THETA_DEG),
                                     n_mu=48, n_phi=96))
                for name, fit in fits.items()}
    notes = []
    for name, vals in dhr_vals.items():
        finite = vals[np.isfinite(vals)]
        if by_name[name].energy_bounded and finite.size and finite.max() > 1.0 + 1e-3:
            notes.append(f"{name}: fitted DHR reaches {finite.max():.3f} > 1 "
                         "(energy not conserved by these parameters)")
        if fits[name].rank_deficient:
            notes.append(f"{name}: parameters not all identifiable from these data")
        if not fits[name].converged:
            notes.append(f"{name}: the fit did not converge ({fits[name].message}); its "
                         "parameters and scores are not reliable")
    return AnalysisResult(sel, fits, by_name, _DHR_THETA_DEG.copy(), dhr_vals,
                          reciprocity_check(points), tuple(notes))


def model_band(model: BRDFModel, fit: FitResult, theta_i: np.ndarray, phi_i: np.ndarray,
               theta_r: np.ndarray, phi_r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Model value and its standard uncertainty σ_f = √(J C Jᵀ) at the given angles."""
    g = make_geometry(theta_i, phi_i, theta_r, phi_r)
    val = model.evaluate_geometry(fit.params, g)
    jac = model.jacobian_geometry(fit.params, g).reshape(-1, fit.n_params)
    cov = np.nan_to_num(fit.covariance)
    var = np.einsum("ij,jk,ik->i", jac, cov, jac)
    return val, np.sqrt(np.maximum(var, 0.0)).reshape(val.shape)
