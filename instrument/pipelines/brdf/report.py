"""The BRDF fit report: PNG figures and an HTML page of one analysed run.

:func:`write_report` renders with matplotlib (Agg backend, no display) and writes an
``index.html`` that links the figures: in-plane BRDF per θi with the fits and the chosen
model's ±1σ band (:func:`instrument.pipelines.brdf.analyse.model_band`), a polar plot,
normalised residuals, the parameter table, the model comparison and the physical checks.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from analysis.brdf.geometry import Geometry, make_geometry
from analysis.brdf.reduction import BRDFPoints
from instrument.pipelines.brdf.analyse import UNCERTAINTY_RULE, AnalysisResult, model_band_at

if TYPE_CHECKING:
    from matplotlib.projections.polar import PolarAxes

__all__ = ["coincident_with", "unit_text", "write_report"]


def unit_text(unit: str) -> str:
    """A parameter's unit as shown to people: empty for a dimensionless "1"."""
    return "" if unit.strip() == "1" else unit


#: Two curves closer than this (relative, everywhere) are drawn as coinciding.
_COINCIDENT_REL = 1e-3


def coincident_with(curves: dict[str, np.ndarray]) -> dict[str, str]:
    """For each curve that coincides everywhere with an earlier one (within
    _COINCIDENT_REL of its value), the name of that earlier curve."""
    out: dict[str, str] = {}
    names = list(curves)
    for k, name in enumerate(names):
        for prev in names[:k]:
            a, b = curves[name], curves[prev]
            scale = np.maximum(np.abs(b), 1e-300)
            if a.shape == b.shape and np.all(np.abs(a - b) <= _COINCIDENT_REL * scale):
                out[name] = out.get(prev, prev)
                break
    return out


def _coincidence_styles(curves: dict[str, np.ndarray], chosen: str
                        ) -> dict[str, dict[str, Any]]:
    """Line styles and legend labels that keep coinciding curves visible: the later one
    is drawn dashed on top of the earlier, and its label says which curve it covers."""
    same = coincident_with(curves)
    styles = {}
    for name in curves:
        style: dict[str, Any] = {"lw": 2.0 if name == chosen else 1.2, "ls": "-",
                                 "label": name + (" (chosen)" if name == chosen else "")}
        if name in same:
            style.update(ls=(0, (4, 3)), lw=style["lw"] + 0.6,
                         label=f"{style['label']} (same curve as {same[name]})")
        styles[name] = style
    return styles


def _signed_deg(points: BRDFPoints) -> np.ndarray:
    """Signed viewing angle (deg): > 0 on the far side of the normal from the source."""
    far = np.abs(np.angle(np.exp(1j * (points.phi_r - points.phi_i)))) > np.pi / 2
    return np.degrees(np.where(far, points.theta_r, -points.theta_r))


#: Signed θr of the drawn model curves (deg; > 0 specular side), half-degree steps.
_S_GRID = np.linspace(-89.0, 89.0, 357)


def _curve(theta_i: float, phi_i: float) -> Geometry:
    """The plane of incidence at (θi, φi) along :data:`_S_GRID`, as one geometry.

    The same object is handed to every figure and model (:func:`_curves`): a receiver-averaged
    model caches its quadrature nodes on the geometry, and building them is most of a
    curve's cost."""
    s = np.radians(_S_GRID)
    return make_geometry(np.full(s.shape, theta_i), np.full(s.shape, phi_i), np.abs(s),
                         np.where(s >= 0, phi_i + np.pi, phi_i))


def _curves(points: BRDFPoints) -> dict[tuple[float, float], Geometry]:
    """One curve geometry per incidence group of ``points`` (keyed by (θi, φi))."""
    return {(ti, pi_): _curve(ti, pi_) for ti, pi_, _ in _groups(points)}


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
    return cast(np.ndarray, np.degrees(np.arcsin(np.minimum(off, 1.0))) <= _PLANE_TOL_DEG)


def _band_width_px(ax: Any, x: np.ndarray, val: np.ndarray, sd: np.ndarray) -> float:
    """The widest ±1σ band on the panel, in display pixels (after autoscaling)."""
    ax.autoscale_view()
    ok = np.isfinite(val) & (val - sd > 0)
    if not np.any(ok):
        return float("inf")
    lo = ax.transData.transform(np.column_stack([x[ok], (val - sd)[ok]]))[:, 1]
    hi = ax.transData.transform(np.column_stack([x[ok], (val + sd)[ok]]))[:, 1]
    return float(np.max(np.abs(hi - lo)))


def _plot_inplane(points: BRDFPoints, res: AnalysisResult, path: Path,
                  curves: dict[tuple[float, float], Geometry]) -> str:
    """Draw the in-plane panels; return a sentence on the ±1σ band's visibility."""
    import matplotlib.pyplot as plt

    f, u = points.plain_brdf()
    signed = _signed_deg(points)
    groups = _groups(points)
    plane = _in_plane(points)
    clipped = ~points.valid
    fig, axes = plt.subplots(len(groups), 1, figsize=(7.5, 3.0 * len(groups)), squeeze=False)
    s_grid = _S_GRID
    # the models on every panel, so that coinciding curves are found once for the figure
    values = {name: [model_band_at(res.models[name], fit, curves[ti, pi_])
                     for ti, pi_, _ in groups] for name, fit in _shown(res).items()}
    styles = _coincidence_styles(
        {name: np.concatenate([v for v, _ in bands]) for name, bands in values.items()},
        res.chosen)
    band_rel, band_px, line_px, bar_px = 0.0, 0.0, 0.0, 0.0
    dot_px = 3.0 * fig.dpi / 72.0  # the marker's diameter (ms = 3 pt)
    for k, (ax, (ti, pi_, group)) in enumerate(zip(axes[:, 0], groups, strict=True)):
        # the curves are the plane of incidence: out-of-plane points are left to the
        # residual plot instead of being drawn against the wrong curve
        sel = group[plane[group] & ~clipped[group]]
        low = group[plane[group] & clipped[group]]
        n_off = int(np.sum(~plane[group]))
        ax.errorbar(signed[sel], f[sel], yerr=u[sel], fmt="o", ms=3, color="k",
                    label="measured ±1σ", zorder=3)
        if low.size:
            ax.plot(signed[low], f[low], "^", ms=6, mfc="none", color="r", zorder=3,
                    label="clipped (lower bound, not fitted)")
        for name in values:
            val, sd = values[name][k]
            line, = ax.plot(s_grid, val, **styles[name])
            if name == res.chosen:
                ax.fill_between(s_grid, val - sd, val + sd, color=line.get_color(),
                                alpha=0.3, label="chosen ±1σ", zorder=2.5)
                chosen_val, chosen_sd = val, sd
                line_px = line.get_linewidth() * fig.dpi / 72.0
        ax.set_yscale("log")
        ax.set_title(f"θi = {math.degrees(ti):.1f}°, φi = {math.degrees(pi_):.0f}°"
                     + (f" ({n_off} out-of-plane points not shown)" if n_off else ""))
        ax.set_xlabel("signed θr (deg; > 0 specular side)")
        ax.set_ylabel("BRDF (1/sr)")
        ax.grid(True, which="both", alpha=0.3)
        band_px = max(band_px, _band_width_px(ax, s_grid, chosen_val, chosen_sd))
        if sel.size:
            bar_px = max(bar_px, _band_width_px(ax, signed[sel], f[sel], u[sel]))
        ok = chosen_val > 0
        band_rel = max(band_rel, float(np.max(chosen_sd[ok] / chosen_val[ok])))
    ok = f > 0
    bar_rel = float(np.max(u[ok] / f[ok])) if np.any(ok) else 0.0
    relabel = {}
    if band_px < line_px:
        sentence = (f"The chosen model's ±1σ band is narrower than its line (at most "
                    f"±{band_rel:.2%} of the value).")
        relabel["chosen ±1σ"] = f"chosen ±1σ (narrower than the line: ≤ ±{band_rel:.2%})"
    else:
        sentence = (f"The shaded band is the chosen model's ±1σ (at most ±{band_rel:.2%} of "
                    f"the value).")
    if bar_px < dot_px:
        sentence += (f" The measured points' ±1σ error bars are shorter than the dots (at "
                     f"most ±{bar_rel:.2%}).")
        relabel["measured ±1σ"] = f"measured (±1σ smaller than the dot: ≤ ±{bar_rel:.2%})"
    handles, labels = axes[0, 0].get_legend_handles_labels()
    axes[0, 0].legend(handles, [relabel.get(lab, lab) for lab in labels], fontsize=7,
                      loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return sentence


def _shown(res: AnalysisResult) -> dict[str, Any]:
    """The fits drawn as curves: the chosen model and the plausible ones (the comparison
    table lists every candidate)."""
    return {n: f for n, f in res.fits.items()
            if (n == res.chosen or n in res.plausible) and f.converged}


def _plot_polar(points: BRDFPoints, res: AnalysisResult, path: Path,
                curves: dict[tuple[float, float], Geometry]) -> None:
    import matplotlib.pyplot as plt

    f, _ = points.plain_brdf()
    signed = np.radians(_signed_deg(points))
    fig = plt.figure(figsize=(6.5, 5.0))
    ax = cast("PolarAxes", fig.add_subplot(projection="polar"))
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)  # specular side (signed θr > 0) on the right
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    s_grid = _S_GRID
    model, fit = res.models[res.chosen], res.chosen_fit
    plane = _in_plane(points)
    for ti, pi_, group in _groups(points):
        sel = group[plane[group]]
        val = model.evaluate_geometry(fit.params, curves[ti, pi_])
        line, = ax.plot(np.radians(s_grid), val, lw=1.2,
                        label=f"θi = {math.degrees(ti):.0f}°")
        ax.plot(signed[sel], f[sel], "o", ms=3, color=line.get_color())
    ax.set_title(f"{res.chosen} (lines) and the measured points (dots)", fontsize=9)
    ax.set_xlabel("radius: BRDF (1/sr); angle: signed θr (deg, > 0 specular side)",
                  fontsize=8)
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
    r = np.full(points.n, np.nan)
    r[res.fitted_index] = res.selection.fits[res.chosen].residuals
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
    ax.set_xlabel("signed θr (deg; > 0 specular side)")
    ax.set_ylabel("(data − model)/σ (dimensionless)")
    gof = res.chosen_goodness
    ax.set_title(f"normalised residuals of {res.chosen} ({gof.summary()})", fontsize=9,
                 color="k" if gof.adequate else "r")
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_dhr(res: AnalysisResult, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 3.2))
    styles = _coincidence_styles({n: np.asarray(v, float) for n, v in res.dhr.items()},
                                 res.chosen)
    for name, vals in res.dhr.items():
        ax.plot(res.dhr_theta_deg, vals, **styles[name])
    ax.axhline(1.0, color="k", lw=0.8, ls=":", label="1 (energy conservation limit)")
    ax.set_xlabel("θi (deg)")
    ax.set_ylabel("DHR (dimensionless)")
    ax.set_title("directional–hemispherical reflectance of the fitted models", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------ html
def _verdict_html(points: BRDFPoints, res: AnalysisResult,
                  point_labels: Sequence[str] | None) -> str:
    """The goodness-of-fit gate at the top of the page (ADR 0051): the verdict, χ²/dof
    with its expected spread, the uncertainty rule and the points that disagree."""
    gof = res.chosen_goodness
    colour = "#2e7d32" if gof.adequate else "#c62828"
    text = (f"<b>{html.escape(res.chosen)}: {html.escape(gof.verdict())}.</b>")
    if not gof.adequate:
        text += (f"<br>The parameters below are the best approximation this model allows; "
                 f"their standard errors are inflated ×{gof.birge_ratio:.3g} (the Birge "
                 f"ratio √(χ²/dof)) and are not an uncertainty of the sample's properties. "
                 f"Rule: {html.escape(UNCERTAINTY_RULE)}.")
    pts = res.disagreeing_points()
    table = ""
    if pts:
        deg = np.degrees
        f, u = points.plain_brdf()
        caption = ("Points that disagree with the model (|r| > 3, largest first):"
                   if not gof.adequate else
                   f"Points with |r| > 3 (about {0.0027 * gof.dof:.1g} expected by chance "
                   "for a correct model):")
        table = f"<p>{caption}</p>" + _table(
            ("point", "θi (deg)", "φi (deg)", "θr (deg)", "φr (deg)", "BRDF (1/sr)", "σ",
             "(data − model)/σ"),
            [(point_labels[k] if point_labels is not None else f"point {k}",
              float(deg(points.theta_i[k])), float(deg(points.phi_i[k])),
              float(deg(points.theta_r[k])), float(deg(points.phi_r[k])), float(f[k]),
              float(u[k]), float(r)) for k, r in pts[:25]])
    return (f'<div style="border:2px solid {colour};padding:0.5em;margin:0.5em 0">'
            f"{text}{table}</div>")


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
    point_labels: Sequence[str] | None = None,
    warnings: Sequence[str] = (),
    scale_unknown: bool = False,
) -> Path:
    """Write the PNG figures and ``index.html`` into ``out_dir``; returns the HTML path.

    ``point_labels`` (e.g. "point 12" per reduced point) names the disagreeing points
    (default: their position in ``points``). ``warnings`` (assumptions that change the
    result) head the page; ``scale_unknown`` says that the common scale uncertainty is not
    known, so the parameter σ leave it out.
    """
    import matplotlib

    matplotlib.use("Agg", force=True)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    curves = _curves(points)
    figures: dict[str, tuple[str, Callable[[BRDFPoints, AnalysisResult, Path], str | None]]] = {
        "inplane.png": ("In-plane BRDF per θi with fits (chosen model ±1σ band)",
                        partial(_plot_inplane, curves=curves)),
        "polar.png": ("Polar plot of the chosen model and the data",
                      partial(_plot_polar, curves=curves)),
        "residuals.png": ("Normalised residuals of the chosen model", _plot_residuals),
    }
    captions = {name: fn(points, res, out / name) for name, (_, fn) in figures.items()}
    _plot_dhr(res, out / "dhr.png")
    fit = res.chosen_fit
    factor = res.inflation.get(res.chosen, 1.0)
    specs = {ps.name: ps for ps in res.models[res.chosen].params}
    sigma_head = ("σ (common scale unknown, not included)" if scale_unknown
                  else "σ (incl. common scale)")
    if factor != 1.0:
        sigma_head += f", INFLATED ×{factor:.3g} (model rejected)"
    head = ("parameter", "meaning", "value", sigma_head, "unit", "at bound")
    rows = [(n, specs[n].description if n in specs else "", float(v), float(e),
             unit_text(unit) or "dimensionless", "yes" if b else "")
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
    comp = _table(("model", "k", "χ²", "χ²/dof", "p", "AIC", "AICc", "BIC", "CV score",
                   "CV σ", "plausible", "converged"),
                  [(r.name, r.n_params, r.chi2, res.goodness[r.name].reduced_chi2,
                    res.goodness[r.name].p_value, r.aic, r.aicc, r.bic, r.cv_score,
                    r.cv_stderr, "yes" if r.name in res.plausible else "", r.converged)
                   for r in res.selection.table])
    verdict = _verdict_html(points, res, point_labels)
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
                   + (f"<p>{html.escape(cast(str, captions[name]))}</p>" if captions[name]
                      else "")
                   for name, (cap, _) in figures.items())
    warn_html = ("<h2>Warnings (assumptions that change the result)</h2><ul>"
                 + "".join(f"<li>{html.escape(w)}</li>" for w in warnings) + "</ul>"
                 if warnings else "")
    if scale_unknown:
        known = (f"; the known part, {points.u_scale_rel:.3%}, is included below"
                 if points.u_scale_rel > 0 else "; it is left out of the parameter "
                 "uncertainties below")
        scale_html = ("Common (correlated) scale uncertainty: <b>unknown</b> (see the "
                      f"warnings){known}.")
    else:
        scale_html = (f"Common (correlated) relative scale uncertainty "
                      f"{points.u_scale_rel:.3%}, added to the parameter uncertainties below.")
    kind = "cosine-corrected BRDF f·cosθr" if points.cosine_corrected else "BRDF f"
    page = f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:960px;margin:auto}}
table{{border-collapse:collapse;margin:0.5em 0}}td,th{{border:1px solid #bbb;padding:2px 6px;
font-size:13px;text-align:right}}img{{max-width:100%}}</style></head><body>
<h1>{html.escape(title)}</h1>
{verdict}
<p>{points.n} points, {html.escape(points.method)} method, stored as the {kind}.
{scale_html} Chosen model: <b>{html.escape(res.chosen)}</b>
({html.escape(res.selection.rule)}).</p>
{warn_html}
<h2>Parameters of {html.escape(res.chosen)}</h2>{params}
<h3>Correlations</h3>{corr}
<h2>Model comparison</h2>{comp}
<p>k: number of parameters; χ²: sum of squared normalised residuals (about the number of
points minus k for a model that fits within the uncertainties); AIC, AICc, BIC: information
criteria (lower is better; a difference above 10 is strong evidence); CV score: mean squared
normalised residual at held-out incidence angles (about 1 for a model that predicts within
the uncertainties), with its standard error.</p>
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
