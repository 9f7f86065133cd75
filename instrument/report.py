"""The BRDF fit report: model fits with selection, physical checks, PNG figures and an HTML page.

:func:`analyse` fits every candidate model to the reduced points with their independent
uncertainties (``u_point``) as a known noise scale, chooses the smallest model the data
support (:func:`analysis.brdf.selection.select_model`: information criterion with the
comparison table, grouped-by-θi cross-validation scores kept), then adds the run's common
scale uncertainty and the errors correlated between points (camera pixel response) to
every fit's covariance (:func:`analysis.brdf_reduction.with_scale_uncertainty`,
:func:`~analysis.brdf_reduction.with_correlated_uncertainty`). Physical checks: Helmholtz
reciprocity of the *data* where a geometry was measured both ways, and the
directional–hemispherical reflectance of each fitted model (≤ 1 where the model promises
energy conservation; physics.md §1).

:func:`write_report` renders PNG figures with matplotlib (Agg backend, no display) and an
``index.html`` that links them: in-plane BRDF per θi with the fits and their ±1σ bands
(σ of the model from the parameter covariance, σ_f² = J C Jᵀ), a polar plot, normalised
residuals, the parameter table, the model comparison and the checks.
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from analysis.brdf import get_model
from analysis.brdf.fit import FitResult, fit_brdf
from analysis.brdf.geometry import make_geometry
from analysis.brdf.integrate import dhr
from analysis.brdf.model import BRDFModel
from analysis.brdf.selection import SelectionResult, select_model
from analysis.brdf_reduction import (
    BRDFPoints,
    ReciprocityCheck,
    receiver_model,
    reciprocity_check,
    with_correlated_uncertainty,
    with_scale_uncertainty,
)

__all__ = ["DEFAULT_MODELS", "AnalysisResult", "analyse", "model_band", "write_report"]

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
    fitted as the receiver sees it (:func:`analysis.brdf_reduction.receiver_model`, issue 5
    §3): near a specular peak a reading is the average of f over the directions from the
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


# ------------------------------------------------------------------------------ figures
def _signed_deg(points: BRDFPoints) -> np.ndarray:
    """Signed viewing angle (deg): > 0 on the far side of the normal from the source."""
    far = np.abs(np.angle(np.exp(1j * (points.phi_r - points.phi_i)))) > np.pi / 2
    return np.degrees(np.where(far, points.theta_r, -points.theta_r))


def _curve(theta_i: float, phi_i: float, s_deg: np.ndarray) -> tuple[np.ndarray, ...]:
    s = np.radians(s_deg)
    return (np.full(s.shape, theta_i), np.full(s.shape, phi_i), np.abs(s),
            np.where(s >= 0, phi_i + np.pi, phi_i))


#: Incidence read-backs jitter by ~0.001–0.01° around the set angle (and φi by a full turn,
#: 0° vs 360°): angles within this step share one panel.
_GROUP_STEP_DEG = 0.1
#: A receiver direction within this angle of the plane of incidence counts as in-plane.
_PLANE_TOL_DEG = 0.5


def _groups(points: BRDFPoints) -> list[tuple[float, float, np.ndarray]]:
    """(θi, φi, indices) per incidence direction, angles snapped to _GROUP_STEP_DEG."""
    step = _GROUP_STEP_DEG
    ti_k = np.round(np.degrees(points.theta_i) / step) * step
    pi_k = np.mod(np.round(np.mod(np.degrees(points.phi_i), 360.0) / step) * step, 360.0)
    keys = np.round(ti_k, 6), np.round(pi_k, 6)
    out = []
    for ti, pi_ in sorted(set(zip(*keys, strict=True))):
        sel = np.flatnonzero((keys[0] == ti) & (keys[1] == pi_))
        out.append((math.radians(ti), math.radians(pi_), sel))
    return out


def _in_plane(points: BRDFPoints) -> np.ndarray:
    """True where the receiver lies within _PLANE_TOL_DEG of the plane of incidence: its
    angular distance from that plane is arcsin|sin θr sin(φr − φi)|."""
    off = np.abs(np.sin(points.theta_r) * np.sin(points.phi_r - points.phi_i))
    return np.degrees(np.arcsin(np.minimum(off, 1.0))) <= _PLANE_TOL_DEG


def _plot_inplane(points: BRDFPoints, res: AnalysisResult, path: Path) -> None:
    import matplotlib.pyplot as plt

    f, u = points.plain_brdf()
    signed = _signed_deg(points)
    groups = _groups(points)
    plane = _in_plane(points)
    fig, axes = plt.subplots(len(groups), 1, figsize=(7.5, 3.0 * len(groups)), squeeze=False)
    s_grid = np.linspace(-89.0, 89.0, 357)
    for ax, (ti, pi_, group) in zip(axes[:, 0], groups, strict=True):
        # the curves are the plane of incidence: out-of-plane points are left to the
        # residual plot instead of being drawn against the wrong curve
        sel = group[plane[group]]
        n_off = group.size - sel.size
        ax.errorbar(signed[sel], f[sel], yerr=u[sel], fmt="o", ms=3, color="k",
                    label="measured ±1σ", zorder=3)
        for name, fit in res.fits.items():
            val, sd = model_band(res.models[name], fit, *_curve(ti, pi_, s_grid))
            chosen = name == res.chosen
            line, = ax.plot(s_grid, val, lw=2.0 if chosen else 0.9,
                            label=f"{name}{' (chosen)' if chosen else ''}")
            if chosen:
                ax.fill_between(s_grid, val - sd, val + sd, color=line.get_color(), alpha=0.3,
                                label="chosen ±1σ")
        ax.set_yscale("log")
        ax.set_title(f"θi = {math.degrees(ti):.1f}°, φi = {math.degrees(pi_):.0f}°"
                     + (f" ({n_off} out-of-plane points not shown)" if n_off else ""))
        ax.set_xlabel("signed θr (deg; > 0 specular side)")
        ax.set_ylabel("BRDF (1/sr)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_polar(points: BRDFPoints, res: AnalysisResult, path: Path) -> None:
    import matplotlib.pyplot as plt

    f, _ = points.plain_brdf()
    signed = np.radians(_signed_deg(points))
    fig = plt.figure(figsize=(6.5, 5.0))
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)  # specular side (signed θr > 0) on the right
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    s_grid = np.linspace(-89.0, 89.0, 357)
    model, fit = res.models[res.chosen], res.chosen_fit
    plane = _in_plane(points)
    for ti, pi_, group in _groups(points):
        sel = group[plane[group]]
        val = model.evaluate_geometry(fit.params, make_geometry(*_curve(ti, pi_, s_grid)))
        line, = ax.plot(np.radians(s_grid), val, lw=1.2,
                        label=f"θi = {math.degrees(ti):.0f}°")
        ax.plot(signed[sel], f[sel], "o", ms=3, color=line.get_color())
    ax.set_title(f"{res.chosen}: BRDF (1/sr) vs signed θr", fontsize=9)
    # on a half-disc the default radial tick labels run together along the bottom edge
    from matplotlib.ticker import MaxNLocator

    ax.yaxis.set_major_locator(MaxNLocator(4))
    ax.tick_params(axis="y", labelsize=7)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_residuals(points: BRDFPoints, res: AnalysisResult, path: Path) -> None:
    import matplotlib.pyplot as plt

    signed = _signed_deg(points)
    r = res.selection.fits[res.chosen].residuals
    plane = _in_plane(points)
    fig, ax = plt.subplots(figsize=(7.5, 3.2))
    for ti, pi_, group in _groups(points):
        sel = group[plane[group]]
        line, = ax.plot(signed[sel], r[sel], "o", ms=3,
                        label=f"θi = {math.degrees(ti):.0f}°, φi = {math.degrees(pi_):.0f}°")
        off = group[~plane[group]]
        if off.size:
            # out of plane: x is ±θr (sign from the side of the plane of incidence)
            ax.plot(signed[off], r[off], "x", ms=4, color=line.get_color(),
                    label=f"θi = {math.degrees(ti):.0f}°, out of plane")
    ax.axhline(0.0, color="k", lw=0.8)
    for k in (-2, 2):
        ax.axhline(k, color="grey", lw=0.6, ls="--")
    ax.set_xlabel("signed θr (deg)")
    ax.set_ylabel("(data − model)/σ")
    ax.set_title(f"normalised residuals of {res.chosen} (χ²/dof = "
                 f"{res.selection.fits[res.chosen].reduced_chi2:.2f})", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_dhr(res: AnalysisResult, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 3.2))
    for name, vals in res.dhr.items():
        ax.plot(res.dhr_theta_deg, vals, lw=2.0 if name == res.chosen else 0.9, label=name)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xlabel("θi (deg)")
    ax.set_ylabel("DHR of the fitted model")
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------ html
def _table(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.5g}"
        return html.escape(str(v))

    h = "".join(f"<th>{html.escape(x)}</th>" for x in head)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table><tr>{h}</tr>{body}</table>"


def write_report(
    out_dir: str | Path,
    points: BRDFPoints,
    res: AnalysisResult,
    *,
    title: str,
    provenance: dict[str, Any] | None = None,
) -> Path:
    """Write the PNG figures and ``index.html`` into ``out_dir``; returns the HTML path."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures = {
        "inplane.png": ("In-plane BRDF per θi with fits (chosen model ±1σ band)",
                        _plot_inplane),
        "polar.png": ("Polar plot of the chosen model and the data", _plot_polar),
        "residuals.png": ("Normalised residuals of the chosen model", _plot_residuals),
    }
    for name, (_, fn) in figures.items():
        fn(points, res, out / name)
    _plot_dhr(res, out / "dhr.png")
    fit = res.chosen_fit
    head = ("parameter", "value", "σ (incl. common scale)", "unit", "at bound")
    rows = [(n, float(v), float(e), unit, "yes" if b else "")
            for (n, v, e, unit), b in zip(fit.table(), fit.at_bound, strict=True)]
    boot = fit.bootstrap
    if boot is not None:
        noise_only = res.selection.fits[res.chosen].stderr
        head = (*head, "σ (noise only)", f"bootstrap σ (B = {boot.samples.shape[0]})",
                "bootstrap 95 % interval")
        rows = [(*r, float(sn), float(sb), f"{lo:.6g} … {hi:.6g}")
                for r, sn, sb, lo, hi in zip(rows, noise_only, boot.stderr, boot.ci_low,
                                             boot.ci_high, strict=True)]
    params = _table(head, rows)
    corr = _table(("", *fit.param_names),
                  [(n, *[float(x) for x in row])
                   for n, row in zip(fit.param_names, fit.correlation, strict=True)])
    comp = _table(("model", "k", "χ²", "AIC", "AICc", "BIC", "CV score", "CV σ", "converged"),
                  [(r.name, r.n_params, r.chi2, r.aic, r.aicc, r.bic, r.cv_score, r.cv_stderr,
                    r.converged) for r in res.selection.table])
    rec = res.reciprocity
    if rec.n_pairs:
        rec_html = (f"<p>{rec.n_pairs} pair(s) measured both ways; "
                    f"{rec.fraction_within_2sigma:.0%} agree within 2σ.</p>" + _table(
                        ("point a", "point b", "f(a)/f(b)", "z"),
                        [(int(a), int(b), float(q), float(z)) for (a, b), q, z
                         in zip(rec.pairs, rec.ratio, rec.z, strict=True)]))
    else:
        rec_html = "<p>No geometry was measured both ways (no reciprocity pairs).</p>"
    dhr_rows = [(float(t), *[float(res.dhr[m][k]) for m in res.dhr])
                for k, t in enumerate(res.dhr_theta_deg)]
    dhr_html = _table(("θi (deg)", *res.dhr), dhr_rows)
    prov = _table(("item", "value"), sorted((k, v) for k, v in (provenance or {}).items()
                                            if k != "options"))
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in res.notes) or "<li>none</li>"
    figs = "".join(f'<h3>{html.escape(cap)}</h3><img src="{name}" alt="{html.escape(cap)}">'
                   for name, (cap, _) in figures.items())
    kind = "cosine-corrected BRDF f·cosθr" if points.cosine_corrected else "BRDF f"
    page = f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:960px;margin:auto}}
table{{border-collapse:collapse;margin:0.5em 0}}td,th{{border:1px solid #bbb;padding:2px 6px;
font-size:13px;text-align:right}}img{{max-width:100%}}</style></head><body>
<h1>{html.escape(title)}</h1>
<p>{points.n} points, {html.escape(points.method)} method, stored as the {kind}.
Common (correlated) relative scale uncertainty {points.u_scale_rel:.3%}, added to the
parameter uncertainties below. Chosen model: <b>{html.escape(res.chosen)}</b>
({html.escape(res.selection.rule)}).</p>
<h2>Parameters of {html.escape(res.chosen)}</h2>{params}
<h3>Correlations</h3>{corr}
<h2>Model comparison</h2>{comp}
<h2>Figures</h2>{figs}
<h2>Physical checks</h2>
<h3>Reciprocity of the data</h3>{rec_html}
<h3>Directional–hemispherical reflectance of the fitted models</h3>
<img src="dhr.png" alt="DHR">{dhr_html}
<h3>Notes</h3><ul>{notes}</ul>
<h2>Provenance</h2>{prov}
</body></html>
"""
    path = out / "index.html"
    path.write_text(page, encoding="utf-8")
    return path
