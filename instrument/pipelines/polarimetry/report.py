"""The polarimetric fit's report: ``index.html`` and two figures (matplotlib, Agg).

* ``mueller_grid.png``: the 4×4 Mueller elements against θr, one curve per θi (and
  wavelength): m00 in 1/sr, the others normalised, m_ij/m00, each with its ±1σ error bar;
  the fitted pBRDF's curve where a fit was made.
* ``dop.png``: the degree of polarisation of the scattered light for unpolarised, H, V
  and ±45° incident light, and the depolarisation index (Gil & Bernabeu 1985), against θr.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from instrument.pipelines.polarimetry.reduce import MuellerPoint, dop

__all__ = ["DOP_FIGURE", "GRID_FIGURE", "series", "write_report"]

GRID_FIGURE = "mueller_grid.png"
DOP_FIGURE = "dop.png"


def series(points: Sequence[MuellerPoint]) -> dict[str, list[MuellerPoint]]:
    """The points by θi (and λ), each series sorted by θr: the curves of the figures."""
    out: dict[str, list[MuellerPoint]] = {}
    for p in points:
        g = p.group
        name = "straight through" if g.transmitted else f"θi {g.theta_i:.0f}°"
        if math.isfinite(g.wavelength_nm):
            name += f", {g.wavelength_nm:.0f} nm"
        out.setdefault(name, []).append(p)
    for v in out.values():
        v.sort(key=lambda p: p.group.theta_r)
    return out


def _grid(path: Path, points: Sequence[MuellerPoint],
          model: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 4, figsize=(12, 10), sharex=True)
    for label, pts in series(points).items():
        tr = np.array([p.group.theta_r for p in pts])
        m = np.array([p.brdf.m for p in pts])
        mn = np.array([p.brdf.m_normalised for p in pts])
        sn = np.array([p.brdf.sigma_normalised for p in pts])
        s = np.array([p.brdf.sigma for p in pts])
        for i in range(4):
            for j in range(4):
                ax = axes[i, j]
                if i == j == 0:
                    line = ax.errorbar(tr, m[:, 0, 0], yerr=s[:, 0, 0], fmt="o", ms=4,
                                       capsize=2, label=label)
                else:
                    line = ax.errorbar(tr, mn[:, i, j], yerr=sn[:, i, j], fmt="o", ms=4,
                                       capsize=2)
                if label in model:
                    x, f = model[label]
                    y = f[:, 0, 0] if i == j == 0 else f[:, i, j] / f[:, 0, 0]
                    ax.plot(x, y, "-", lw=1, color=line[0].get_color())
    for i in range(4):
        for j in range(4):
            ax = axes[i, j]
            if i == j == 0:
                ax.set_ylabel("m00 (1/sr)")
                ax.set_yscale("log")
            else:
                ax.set_ylabel(f"m{i}{j} / m00")
                ax.set_ylim(-1.1, 1.1)
                ax.axhline(0.0, color="0.8", lw=0.5)
            if i == 3:
                ax.set_xlabel("θr (deg)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Mueller-matrix BRDF against θr (points ±1σ; lines: pBRDF fit)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _dop(path: Path, points: Sequence[MuellerPoint]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = series(points)
    cols = min(len(groups), 4)
    rows = math.ceil(len(groups) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.6 * rows), sharey=True,
                             squeeze=False)
    markers = {"unpolarised": "o", "H": ">", "V": "^", "+45°": "s", "−45°": "D",
               "depolarisation index": "x"}
    for ax, (label, pts) in zip(axes.ravel(), groups.items(), strict=False):
        tr = np.array([p.group.theta_r for p in pts])
        values = [dop(p.brdf.m) for p in pts]
        for k, (name, mk) in enumerate(markers.items()):
            ax.plot(tr, [v[name] for v in values], marker=mk, color=f"C{k}",
                    ls="-" if name == "depolarisation index" else ":", label=name)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("θr (deg)")
        ax.set_ylim(0.0, 1.05)
    for ax in axes[:, 0]:
        ax.set_ylabel("degree of polarisation (1)")
    for ax in axes.ravel()[len(groups):]:
        ax.set_visible(False)
    axes[0, 0].legend(fontsize=7, title="incident light", title_fontsize=7)
    fig.suptitle("Degree of polarisation of the scattered light, by incident state; "
                 "depolarisation index (Gil & Bernabeu 1985)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _fmt(v: float, s: float | None = None, digits: int = 4) -> str:
    if s is None or not math.isfinite(s):
        return f"{v:.{digits}g}"
    return f"{v:.{digits}g} ± {s:.2g}"


def _selection_html(fit: Mapping[str, Any]) -> str:
    """The variants' comparison table (empty when one model was named)."""
    sel = fit.get("selection")
    if not sel:
        return ""
    e = html.escape
    crit = str(sel["criterion"])
    rows = "".join(f"<tr><td>{e(r['name'])}{' (chosen)' if r['name'] == fit['variant'] else ''}"
                   f"</td><td>{r['n_params']}</td><td>{r['chi2']:.1f}</td>"
                   f"<td>{r[crit]:.1f}</td></tr>" for r in sel["table"])
    return (f"<p>Variant chosen by {e(str(sel['rule']))}.</p><table><tr><th>variant</th>"
            f"<th>parameters</th><th>χ²</th><th>{e(crit.upper())}</th></tr>{rows}</table>")


def write_report(folder: Path, points: Sequence[MuellerPoint], *, title: str,
                 summary: dict[str, Any],
                 model: dict[str, tuple[np.ndarray, np.ndarray]] | None = None) -> Path:
    """Draw the figures and write ``index.html`` into ``folder``; returns the page."""
    folder.mkdir(parents=True, exist_ok=True)
    _grid(folder / GRID_FIGURE, points, model or {})
    _dop(folder / DOP_FIGURE, points)
    e = html.escape
    rows = []
    for p in points:
        d = p.decomposition
        if d is not None and d.sigma is not None:
            dcells = "".join(f"<td>{_fmt(v, s)}</td>" for v, s in
                             zip(d.params[1:], d.sigma[1:], strict=True))
        else:
            dcells = f"<td colspan=4>{e(p.decomposition_note or '—')}</td>"
        r = p.realizability
        flag = "<b>not realizable</b>" if r.flagged else "realizable"
        rows.append(
            f"<tr><td>{e(p.group.label())}</td><td>{p.group.rows.size}</td>"
            f"<td>{p.condition:.3g}</td><td>{_fmt(p.brdf.m[0, 0], p.brdf.sigma[0, 0])}</td>"
            f"{dcells}<td>{flag} (p = {r.p_value:.3g})</td></tr>")
    notes = "".join(f"<li>{e(str(n))}</li>" for n in summary.get("notes", []))
    fit = summary.get("pbrdf")
    fit_html = "<p>No pBRDF fit.</p>"
    if fit is not None:
        cells = "".join(
            f"<tr><td>{e(n)}</td><td>{_fmt(v, s)}</td><td>{'fixed' if n in fit['fixed'] else ''}"
            "</td></tr>" for n, v, s in zip(fit["param_names"], fit["params"], fit["stderr"],
                                             strict=True))
        fit_html = (f"<p>{e(fit['distribution'])} microfacet Fresnel pBRDF (Priest &amp; "
                    f"Germer 2000), variant {e(str(fit.get('variant', '')))}: "
                    f"{e(fit['verdict'])}</p><table><tr><th>parameter</th><th>value ± σ"
                    f"</th><th></th></tr>{cells}</table>{_selection_html(fit)}")
    page = folder / "index.html"
    page.write_text(
        f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title>"
        "<style>body{font-family:sans-serif;max-width:70em}td,th{padding:2px 8px;"
        "border-bottom:1px solid #ddd}</style></head><body>"
        f"<h1>{e(title)}</h1><p><b>Calibration:</b> {e(summary['calibration_text'])}</p>"
        f"<ul>{notes}</ul>"
        "<h2>Mueller matrices and their decomposition</h2>"
        "<table><tr><th>geometry</th><th>steps</th><th>κ</th><th>m00 (1/sr)</th>"
        "<th>diattenuation D</th><th>retardance R (rad)</th><th>retardance axis (deg)</th>"
        "<th>depolarisation Δ</th><th>realizability</th></tr>"
        f"{''.join(rows)}</table>"
        f"<h2>pBRDF fit</h2>{fit_html}"
        f"<h2>Figures</h2><p><img src='{GRID_FIGURE}' width='100%'></p>"
        f"<p><img src='{DOP_FIGURE}'></p></body></html>", encoding="utf-8")
    return page
