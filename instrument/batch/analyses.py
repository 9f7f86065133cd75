"""The four analyses as plain functions: a run path and plain options → a summary row.

``scatterlab batch`` runs each analysis of each run as one call of one of these adapters,
in whatever process Dask chose, so what crosses processes is plain data: the options come
in as JSON-able dictionaries (built from the command line by the single-run commands' own
option functions, :func:`instrument.cli.fit.fit_options` and its siblings), and an adapter
returns an :class:`Analysed` — the run's line of the summary table. Each adapter opens the
run file itself, by path.

The ``*_arguments`` functions turn the plain options into the pipelines' keyword arguments;
the single-run commands use them too, so a run analysed in a batch and on its own is
analysed with the same arguments.

Each adapter lets its pipeline write the results file, exactly as the single-run command
does (ADR 0013: ``results.h5`` in ``folder``, normally ``DIR/RUN/<pipeline>/``; the raw
run file is only read; ``locate`` reads the reconstruction from the light-field results
file and makes one first when it holds none). One writer per file: a run analysed alone
and in a batch has the same results file. Reports and figures go to ``folder`` too when
``report`` is true.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from instrument.pipelines.brdf.reduce import ReductionOptions

__all__ = [
    "ANALYSES",
    "Analysed",
    "Analysis",
    "AnalysisFailed",
    "analyse_fit",
    "analyse_locate",
    "analyse_reconstruct",
    "analyse_spheres",
    "fit_arguments",
    "get_analysis",
    "locate_arguments",
    "reconstruct_arguments",
    "reduction_defaults",
]


class AnalysisFailed(RuntimeError):
    """The analysis ran to its end but its answer is not usable (e.g. the chosen model's
    fit did not converge). ``row`` is what it found, for the summary table."""

    def __init__(self, message: str, row: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.row = row


@dataclass(frozen=True)
class Analysed:
    """What an adapter returns.

    Attributes
    ----------
    result : str
        The answer in one line of words and numbers (the table's "result" column).
    values : dict str → str, int, float or bool
        The same as named columns (parameters and their σ, located objects, errors).
    flags : list of str
        What a reader must know before trusting the result (notes of the analysis).
    details : dict
        The analysis's plain-data results, stored in the results file.
    """

    result: str
    values: dict[str, Any]
    flags: list[str] = field(default_factory=list)
    details: dict[str, Any] = field(default_factory=dict)

    def row(self) -> dict[str, Any]:
        return {"result": self.result, "values": dict(self.values), "flags": list(self.flags)}


#: The adapter signature: run path, plain options; keywords ``folder`` (results, report and
#: figures) and ``report`` (draw the report and figures).
Adapter = Callable[..., Analysed]


@dataclass(frozen=True)
class Analysis:
    """One analysis a batch can run.

    Attributes
    ----------
    name : str
        As on the command line (``scatterlab batch NAME``).
    pipeline : str
        Its folder next to the run (:data:`instrument.run.results.PIPELINES`).
    kinds : tuple of str
        The plan kinds it analyses; runs of other kinds are not applicable.
    program : str
        Recorded in the results file.
    adapter : callable
    """

    name: str
    pipeline: str
    kinds: tuple[str, ...]
    program: str
    adapter: Adapter


def _num(x: Any) -> Any:
    """A plain Python scalar (NaN and ±inf stay floats)."""
    if isinstance(x, np.generic):
        return x.item()
    return x


# ------------------------------------------------------------------------------ fit
def reduction_defaults() -> dict[str, Any]:
    """The reduction options of ``scatterlab fit`` as plain data (every field)."""
    return asdict(ReductionOptions())


def fit_arguments(options: Mapping[str, Any]) -> dict[str, Any]:
    """Keyword arguments of :func:`instrument.pipelines.brdf.pipeline.fit_run` from the
    plain options of :func:`instrument.cli.fit.fit_options`."""
    return {
        "options": ReductionOptions(**options["reduction"]),
        "models": tuple(options["models"]),
        "criterion": options["criterion"],
        "run_cv": bool(options["run_cv"]),
        "n_bootstrap": int(options["n_bootstrap"]),
    }


def _param_text(name: str, value: float, err: float, unit: str) -> str:
    u = f" {unit}" if unit and unit != "1" else ""
    return f"{name} = {value:.5g} ± {err:.2g}{u}"


def analyse_fit(path: str | Path, options: Mapping[str, Any], *,
                folder: str | Path, report: bool = True) -> Analysed:
    """Reduce, fit and select (``scatterlab fit``); results (and the report) in ``folder``.

    Raises
    ------
    AnalysisFailed
        The chosen model's fit did not converge.
    """
    from instrument.pipelines.brdf.pipeline import fit_run

    done = fit_run(path, **fit_arguments(options), report_dir=folder, report=report,
                   write=True)
    res = done.result
    fit = res.chosen_fit
    pts = done.reduced.points
    values: dict[str, Any] = {"model": res.chosen, "method": pts.method, "n_points": int(pts.n),
                              "chi2": float(fit.chi2), "dof": int(fit.dof)}
    for name, value, err, _unit in fit.table():
        values[name] = value
        values[f"{name}_sigma"] = err
    flags = list(res.notes)
    bound = [n for n, b in zip(fit.param_names, fit.at_bound, strict=True) if b]
    if bound:
        flags.append(f"{res.chosen}: {', '.join(bound)} at a bound (σ unreliable)")
    text = f"{res.chosen}: " + ", ".join(_param_text(*r) for r in fit.table())
    out = Analysed(text, values, flags, {"analysis": res.to_dict(),
                                          "provenance": done.reduced.provenance})
    if not fit.converged:
        raise AnalysisFailed(f"the fit of the chosen model {res.chosen} did not converge "
                             f"({fit.message})", out.row())
    return out


# ------------------------------------------------------------------------------ light fields
def reconstruct_arguments(options: Mapping[str, Any]) -> dict[str, Any]:
    """Keyword arguments of :func:`instrument.pipelines.lightfield.reconstruct.
    reconstruct_run` from the plain options of :func:`instrument.cli.reconstruct.
    reconstruction_options` (geometry file path, BRDF text, domain in degrees)."""
    from instrument.pipelines.lightfield.geometry import load_geometry, parse_brdf

    domain = options.get("domain_deg")
    return {
        "geometry": load_geometry(options["geometry"]) if options.get("geometry") else None,
        "brdf": parse_brdf(options["brdf"]) if options.get("brdf") else None,
        "domain_rad": None if domain is None else (math.radians(domain[0]),
                                                   math.radians(domain[1])),
        "n_theta": int(options["n_theta"]),
        "method": options["method"],
    }


def analyse_reconstruct(path: str | Path, options: Mapping[str, Any], *,
                        folder: str | Path, report: bool = True) -> Analysed:
    """The hidden object's light field at the wall (``scatterlab reconstruct``)."""
    from instrument.pipelines.lightfield.reconstruct import reconstruct_run

    r = reconstruct_run(path, write=True, out_dir=folder,
                        figures_dir=folder if report else None,
                        **reconstruct_arguments(options))
    rec = r.reconstruction
    reg = rec.regularization
    noise = rec.diagnostics.noise
    values = {
        "recoverable": bool(rec.recoverable),
        "highest_order": float(r.p_hat),
        "wall_points": int(rec.incident_field.shape[0]),
        "angles": int(r.measured.field.shape[1]),
        "regularisation": reg.method,
        "parameter": _num(reg.parameter),
        "noise_per_sample": float(noise.sigma_per_sample),
        "noise_from_rows": float(r.measured.sigma_rows),
    }
    flags = list(r.notes)
    if not rec.recoverable:
        flags.append(f"no object information recovered: {rec.message}")
    text = (f"{rec.message}; highest recovered angular order {r.p_hat:.3g} on "
            f"{values['wall_points']} wall points")
    details = {"values": values, "message": rec.message, "notes": list(r.notes),
               "geometry": r.geometry.as_dict(), "brdf": r.brdf.name or "custom"}
    return Analysed(text, values, flags, details)


def locate_arguments(options: Mapping[str, Any]) -> dict[str, Any]:
    """Keyword arguments of :func:`instrument.pipelines.lightfield.locate.locate_run` from
    the plain options of :func:`instrument.cli.locate.locate_options` (``reconstruct``:
    reconstruction options, or None to use the reconstruction the run holds)."""
    y = options.get("y_range_mm")
    kw: dict[str, Any] = {
        "y_range_mm": None if y is None else (float(y[0]), float(y[1])),
        "z_range_mm": tuple(float(z) for z in options["z_range_mm"]),
        "threshold_rel": float(options["threshold_rel"]),
    }
    if options.get("reconstruct") is not None:
        kw.update(reconstruct_arguments(options["reconstruct"]))
    return kw


def analyse_locate(path: str | Path, options: Mapping[str, Any], *,
                   folder: str | Path, report: bool = True) -> Analysed:
    """The hidden objects' positions, brightness and resolution (``scatterlab locate``)."""
    from instrument.pipelines.lightfield.locate import locate_run

    r = locate_run(path, write=True, out_dir=folder, figures_dir=folder if report else None,
                   **locate_arguments(options))
    det = r.detection
    values: dict[str, Any] = {"objects": int(det.count), "highest_order": float(r.p_hat)}
    parts, flags = [], []
    for k in range(det.count):
        y, z = (float(v) for v in det.positions_mm[k])
        res = det.resolutions[k]
        q = det.quality[k]
        values.update({f"object{k}_y_mm": y, f"object{k}_z_mm": z,
                       f"object{k}_blur_y_mm": float(res.transverse_mm),
                       f"object{k}_blur_z_mm": float(res.depth_mm),
                       f"object{k}_quality": q,
                       f"object{k}_brightness": float(det.brightness_rp[k])})
        depth = f"z {z:.1f} ± {res.depth_mm:.1f} mm" if q != "unresolved" else "z unresolved"
        parts.append(f"y {y:.1f} ± {res.transverse_mm:.1f} mm, {depth} [{q}]")
        if q == "unresolved":
            flags.append(f"object {k}: depth not resolved (best guess z = {z:.1f} mm)")
    if not r.recoverable:
        flags.append(r.message)
    text = f"{det.count} object(s)" + (": " + "; ".join(parts) if parts else f" ({r.message})")
    details = {"values": values, "message": r.message,
               "positions_mm": np.asarray(det.positions_mm).tolist(),
               "depth_interval_mm": np.asarray(det.depth_interval_mm).tolist(),
               "quality": list(det.quality)}
    return Analysed(text, values, flags, details)


# ------------------------------------------------------------------------------ spheres
def analyse_spheres(path: str | Path, options: Mapping[str, Any], *,
                    folder: str | Path, report: bool = True) -> Analysed:
    """Spherical-harmonic analysis, relighting and consistency (``scatterlab spheres``);
    ``options`` are :func:`instrument.pipelines.spheres.analyse.analyse_capture`'s."""
    from instrument.pipelines.spheres.pipeline import analyse_run
    from instrument.pipelines.spheres.results import summary

    figure = Path(folder) / "relighting.png" if report else None
    capture, res = analyse_run(path, write=True, out_dir=folder, figure=figure,
                               **dict(options))
    rep = res.consistency
    values = {
        "relighting_error": float(res.relight_l1),
        "consistency_statistic": float(rep.statistic),
        "consistency_threshold": float(rep.threshold),
        "inconsistent": bool(rep.inconsistent),
        "objects": len(capture.objects),
        "lightings": len(capture.lighting_deg),
        "lmax": int(res.lmax),
    }
    verdict = "INCONSISTENT" if rep.inconsistent else "consistent"
    flags = []
    if rep.inconsistent:
        flags.append(f"the capture fails the consistency check (T = {rep.statistic:.3g} > "
                     f"{rep.threshold:.3g} at α = {rep.false_alarm:g})")
    text = (f"relighting error {100 * res.relight_l1:.2f} % (L1); {verdict} "
            f"(T = {rep.statistic:.3g}, threshold {rep.threshold:.3g})")
    return Analysed(text, values, flags, summary(capture, res))


# ------------------------------------------------------------------------------ registry
ANALYSES: dict[str, Analysis] = {
    a.name: a for a in (
        Analysis("fit", "fit", ("brdf_in_plane", "brdf_hemisphere", "reference"),
                 "scatterlab fit", analyse_fit),
        Analysis("reconstruct", "lightfield", ("lightfield",), "scatterlab reconstruct",
                 analyse_reconstruct),
        Analysis("locate", "lightfield", ("lightfield",), "scatterlab locate",
                 analyse_locate),
        Analysis("spheres", "spheres", ("sphere_capture",), "scatterlab spheres",
                 analyse_spheres),
    )
}


def get_analysis(name: str) -> Analysis:
    """The analysis called ``name`` (ValueError naming the choices otherwise)."""
    try:
        return ANALYSES[name]
    except KeyError:
        raise ValueError(f"unknown analysis {name!r}; one of {', '.join(ANALYSES)}") from None
