"""The four analyses as plain functions: a run path and plain options → a summary row.

``scatterlab batch`` runs each analysis of each run as one call of one of these adapters,
in whatever process Dask chose, so what crosses processes is plain data: the options come
in as JSON-able dictionaries (built from the command line by the single-run commands' own
option functions, :func:`instrument.cli.fit.fit_options` and its siblings), and an adapter
returns an :class:`Analysed` — the run's line of the summary table. Each adapter opens the
run file itself, by path.

An adapter calls its pipeline exactly as the single-run command does — the same keyword
arguments (the ``*_arguments`` functions, which the single-run commands use too), and
``write=True``: the pipeline writes ``DIR/RUN/<pipeline>/results.h5`` (ADR 0013) and, when
asked, its report or figures into the same folder. So a run's results file is the same
whether it was analysed alone or in a batch, with one writer, the pipeline. The raw run
file is only read. The ``*_record`` functions give the options dict the pipeline records
in that file (its fingerprint decides whether a run is already done), computed from the
plain options without running anything.

The ``*_row`` functions turn a pipeline's result into the summary row; :func:`keep_row`
stores that row next to the results file (:func:`instrument.run.results.write_record`), so
a later batch that skips the run still has its line of the table. The single-run commands
keep the row too, which is what lets a batch skip a run analysed by ``scatterlab fit``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from instrument.pipelines.brdf.reduce import ReductionOptions
from instrument.run.results import write_record
from instrument.run.runfile import read_summary

if TYPE_CHECKING:
    from instrument.pipelines.brdf.pipeline import FitRun
    from instrument.pipelines.lightfield.results import LocalisationResult, ReconstructionResult
    from instrument.pipelines.polarimetry.pipeline import PolarimetricFit
    from instrument.pipelines.spheres.analyse import SphereAnalysis
    from instrument.pipelines.spheres.capture import SphereCapture

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
    "fit_record",
    "fit_row",
    "get_analysis",
    "keep_row",
    "locate_arguments",
    "locate_record",
    "locate_row",
    "polarimetric_row",
    "reconstruct_arguments",
    "reconstruct_record",
    "reconstruct_row",
    "reduction_defaults",
    "sphere_record",
    "spheres_row",
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
    """

    result: str
    values: dict[str, Any]
    flags: list[str] = field(default_factory=list)

    def row(self) -> dict[str, Any]:
        return {"result": self.result, "values": dict(self.values), "flags": list(self.flags)}


#: The adapter signature: ``(run path, plain options, *, folder, report) → Analysed``;
#: ``folder`` is where the pipeline writes (None: ``DIR/RUN/<pipeline>/``), ``report``
#: whether it also draws its report or figures there.
Adapter = Callable[..., Analysed]
#: The record signature: ``(run path, plain options) → the options dict the pipeline
#: records in its results file``.
Record = Callable[[str | Path, Mapping[str, Any]], dict[str, Any]]


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
        The single-run command (its pipeline records it in the results file).
    adapter : callable
        Runs the pipeline, writing its results file; returns the summary row.
    record : callable
        The options the pipeline records, to compare with a results file's
        (:func:`instrument.run.results.already_done`).
    """

    name: str
    pipeline: str
    kinds: tuple[str, ...]
    program: str
    adapter: Adapter
    record: Record


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


def fit_record(path: str | Path, options: Mapping[str, Any]) -> dict[str, Any]:
    """What :func:`instrument.pipelines.brdf.pipeline.fit_run` records for these options
    (for a polarimetric run, what its pipeline records with the options under
    ``"polarimetric"``)."""
    from instrument.pipelines.brdf.pipeline import fit_options
    from instrument.pipelines.polarimetry.readings import is_polarimetric

    if is_polarimetric(path):
        from instrument.batch.polarimetric_options import fit_keywords, run_mode
        from instrument.pipelines.polarimetry.pipeline import (
            choose_calibration,
            polarimetric_options,
        )
        from instrument.run.runfile import read_run

        kw = fit_keywords(path, options.get("polarimetric"))
        bench = str(read_run(path).profile().get("bench", {}).get("name", ""))
        # as the pipeline chooses: the calibration of the run's own mode
        cal = choose_calibration(path, bench, kw["calibration"], run_mode(path))
        return polarimetric_options(cal, kw["start"], kw["fixed"], kw["distribution"])
    return fit_options(**fit_arguments(options))


def analyse_fit(path: str | Path, options: Mapping[str, Any], *,
                folder: str | Path | None = None, report: bool = True) -> Analysed:
    """Reduce, fit and select (``scatterlab fit``): ``results.h5`` and, with ``report``,
    the report go to ``folder`` (default ``DIR/RUN/fit/``).

    Raises
    ------
    AnalysisFailed
        The chosen model's fit did not converge (the results file is written, as by
        ``scatterlab fit``).

    A polarimetric run (one with an optical train, ADR 0103) goes through its own
    pipeline, as ``scatterlab fit`` sends it: Mueller matrices, decompositions and the pBRDF
    fit, with the options under ``"polarimetric"``
    (:func:`instrument.batch.polarimetric_options.fit_keywords`: the calibration chosen,
    by default the newest valid one of its bench beside the run; the pBRDF start values,
    parameters held and distribution); the scalar options do not apply to it, nor the
    polarimetric ones to a scalar run.
    """
    from instrument.pipelines.brdf.pipeline import fit_run
    from instrument.pipelines.polarimetry.readings import is_polarimetric

    if is_polarimetric(path):
        from instrument.batch.polarimetric_options import fit_keywords
        from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run

        return polarimetric_row(fit_polarimetric_run(
            path, **fit_keywords(path, options.get("polarimetric")), report_dir=folder,
            report=report, write=True))
    return fit_row(fit_run(path, **fit_arguments(options), report_dir=folder, report=report,
                           write=True))


def polarimetric_row(done: PolarimetricFit) -> Analysed:
    """The summary row of a polarimetric fit: the geometries, the chosen pBRDF variant,
    its gate and every free parameter with its σ; uncalibrated, unrealizable matrices and
    a failed gate are flagged.

    Raises
    ------
    AnalysisFailed
        No pBRDF fit (only straight-through groups) or one whose parameters are not finite.
    """
    s = done.summary
    values: dict[str, Any] = {"n_geometries": len(done.points),
                              "calibrated": bool(s["calibrated"])}
    flags = [str(n) for n in s["notes"] if "not physically realizable" in str(n)]
    if not s["calibrated"]:
        flags.append(str(s["calibration_text"]))
    fit = s["pbrdf"]
    if fit is None:
        raise AnalysisFailed("no pBRDF fit: no reflection geometry with a valid matrix",
                             Analysed("no pBRDF fit", values, flags).row())
    values.update({"model": fit["variant"], "chi2": float(fit["chi2"]),
                   "dof": int(fit["dof"]), "adequate": bool(fit["adequate"])})
    free = [(n, v, e) for n, v, e in zip(fit["param_names"], fit["params"], fit["stderr"],
                                         strict=True) if n not in fit["fixed"]]
    for name, value, err in free:
        values[name] = float(value)
        values[f"{name}_sigma"] = float(err)
    if not fit["adequate"]:
        flags.append(f"pBRDF {fit['variant']}: {fit['verdict']}")
    text = f"pBRDF {fit['variant']}: " + ", ".join(
        _param_text(n, v, e, "deg" if n == "frame_deg" else "") for n, v, e in free)
    out = Analysed(text, values, flags)
    if not all(math.isfinite(v) for _n, v, _e in free):
        raise AnalysisFailed(f"the pBRDF fit of {fit['variant']} gave non-finite "
                             "parameters", out.row())
    return out


def fit_row(done: FitRun) -> Analysed:
    """The summary row of a fit: the chosen model, χ², dof, every parameter and its σ.

    Raises
    ------
    AnalysisFailed
        The chosen model's fit did not converge (``row``: what it found).
    """
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
    out = Analysed(text, values, flags)
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


def reconstruct_record(path: str | Path, options: Mapping[str, Any]) -> dict[str, Any]:
    """What :func:`instrument.pipelines.lightfield.reconstruct.reconstruct_run` records
    for these options."""
    from instrument.pipelines.lightfield.reconstruct import reconstruct_options

    return {"reconstruct": reconstruct_options(**reconstruct_arguments(options))}


def analyse_reconstruct(path: str | Path, options: Mapping[str, Any], *,
                        folder: str | Path | None = None, report: bool = True) -> Analysed:
    """The hidden object's light field at the wall (``scatterlab reconstruct``):
    ``results.h5`` and, with ``report``, the figures go to ``folder`` (default
    ``DIR/RUN/lightfield/``)."""
    from instrument.pipelines.lightfield.reconstruct import reconstruct_run
    from instrument.run.paths import results_dir

    figures = (Path(folder) if folder is not None else results_dir(path, "lightfield")
               ) if report else None
    return reconstruct_row(reconstruct_run(path, write=True, out_dir=folder,
                                           figures_dir=figures,
                                           **reconstruct_arguments(options)))


def reconstruct_row(r: ReconstructionResult) -> Analysed:
    """The summary row of a reconstruction: recoverable, highest order, noise."""
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
    return Analysed(text, values, flags)


def locate_arguments(options: Mapping[str, Any]) -> dict[str, Any]:
    """Keyword arguments of :func:`instrument.pipelines.lightfield.locate.locate_run` from
    the plain options of :func:`instrument.cli.locate.locate_options` (``reconstruct``:
    reconstruction options, or None to use the reconstruction the run holds)."""
    y = options.get("y_range_mm")
    kw: dict[str, Any] = {
        "y_range_mm": None if y is None else (float(y[0]), float(y[1])),
        "z_range_mm": tuple(float(z) for z in options["z_range_mm"]),
        "false_alarm": float(options["false_alarm"]),
    }
    if options.get("reconstruct") is not None:
        kw.update(reconstruct_arguments(options["reconstruct"]))
    return kw


def locate_record(path: str | Path, options: Mapping[str, Any]) -> dict[str, Any]:
    """What :func:`instrument.pipelines.lightfield.locate.locate_run` records for these
    options: its own, and those of the reconstruction it uses — the one it makes when
    ``reconstruct`` is given, else the one the run's results file holds, else the
    default one it would make."""
    from instrument.pipelines.lightfield.locate import locate_options
    from instrument.pipelines.lightfield.reconstruct import reconstruct_options
    from instrument.pipelines.lightfield.results import stored_options
    from instrument.run.paths import results_path

    kw = locate_arguments(options)
    own = locate_options(y_range_mm=kw["y_range_mm"], z_range_mm=kw["z_range_mm"],
                         false_alarm=kw["false_alarm"])
    if options.get("reconstruct") is not None:
        rec = reconstruct_options(**reconstruct_arguments(options["reconstruct"]))
    else:
        rec = (stored_options(results_path(path, "lightfield")).get("reconstruct")
               or reconstruct_options())
    return {"reconstruct": rec, "locate": own}


def analyse_locate(path: str | Path, options: Mapping[str, Any], *,
                   folder: str | Path | None = None, report: bool = True) -> Analysed:
    """The hidden objects' positions, brightness and resolution (``scatterlab locate``):
    ``results.h5`` and, with ``report``, the figures go to ``folder`` (default
    ``DIR/RUN/lightfield/``, where the reconstruction is read from)."""
    from instrument.pipelines.lightfield.locate import locate_run
    from instrument.run.paths import results_dir

    figures = (Path(folder) if folder is not None else results_dir(path, "lightfield")
               ) if report else None
    return locate_row(locate_run(path, write=True, out_dir=folder, figures_dir=figures,
                                 **locate_arguments(options)))


def locate_row(r: LocalisationResult) -> Analysed:
    """The summary row of a localisation: each object's position, blur, depth quality,
    brightness and significance."""
    from instrument.pipelines.lightfield.results import saturated_points

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
                       f"object{k}_brightness": float(det.brightness_rp[k]),
                       f"object{k}_significance": float(det.significance[k])})
        depth = f"z {z:.1f} ± {res.depth_mm:.1f} mm" if q != "unresolved" else "z unresolved"
        parts.append(f"y {y:.1f} ± {res.transverse_mm:.1f} mm, {depth} [{q}]")
        if det.depth_open[k].any():
            flags.append(f"object {k}: the depth interval runs out of the searched range "
                         f"(the object may lie beyond it; widen the z range)")
        elif q == "unresolved":
            flags.append(f"object {k}: depth not resolved (best guess z = {z:.1f} mm)")
    if det.below_significance.size:
        values["candidates_below_threshold"] = int(det.below_significance.size)
    n_sat = saturated_points(det.notes)
    if n_sat:
        flags.append(f"{n_sat} scan point(s) saturated in every exposure: brightness is "
                     f"underestimated")
    flags.extend(n for n in det.notes if "residual" in n)
    if not r.recoverable:
        flags.append(r.message)
    text = f"{det.count} object(s)" + (": " + "; ".join(parts) if parts else f" ({r.message})")
    return Analysed(text, values, flags)


# ------------------------------------------------------------------------------ spheres
#: The sphere analysis's figure in its folder (as ``scatterlab spheres`` names it).
SPHERE_FIGURE = "relighting.png"


def sphere_record(path: str | Path, options: Mapping[str, Any]) -> dict[str, Any]:
    """What :func:`instrument.pipelines.spheres.pipeline.analyse_run` records for these
    options."""
    from instrument.pipelines.spheres.pipeline import sphere_options

    return sphere_options(**dict(options))


def analyse_spheres(path: str | Path, options: Mapping[str, Any], *,
                    folder: str | Path | None = None, report: bool = True) -> Analysed:
    """Spherical-harmonic analysis, relighting and consistency (``scatterlab spheres``);
    ``options`` are :func:`instrument.pipelines.spheres.analyse.analyse_capture`'s.
    ``results.h5`` and, with ``report``, ``relighting.png`` go to ``folder`` (default
    ``DIR/RUN/spheres/``)."""
    from instrument.pipelines.spheres.pipeline import analyse_run
    from instrument.run.paths import results_dir

    where = Path(folder) if folder is not None else results_dir(path, "spheres")
    capture, res = analyse_run(path, write=True, out_dir=folder,
                               figure=where / SPHERE_FIGURE if report else None,
                               **dict(options))
    return spheres_row(capture, res)


def spheres_row(capture: SphereCapture, res: SphereAnalysis) -> Analysed:
    """The summary row of a sphere analysis: relighting error and the consistency check."""
    rep = res.consistency
    values = {
        "relighting_error": float(res.relight_l1),
        "consistency_statistic": float(rep.statistic),
        "consistency_threshold": float(rep.threshold),
        "inconsistent": bool(rep.inconsistent),
        "consistency_verdict": rep.verdict,
        "objects": len(capture.objects),
        "lightings": len(capture.lighting_deg),
        "lmax": int(res.lmax),
    }
    verdict = "INCONSISTENT" if rep.inconsistent else rep.verdict
    flags = []
    if not rep.testable:
        flags.append(f"no consistency test possible at this L: {rep.no_test_reason}")
    if rep.inconsistent:
        flags.append(f"the capture fails the consistency check (T = {rep.statistic:.3g} > "
                     f"{rep.threshold:.3g} at α = {rep.false_alarm:g})")
    text = (f"relighting error {100 * res.relight_l1:.2f} % (L1); {verdict} "
            f"(T = {rep.statistic:.3g}, threshold {rep.threshold:.3g})")
    return Analysed(text, values, flags)


# ------------------------------------------------------------------------------ the row kept
def keep_row(run_path: str | Path, analysis: str, make: Callable[[], Analysed], *,
             report: bool, folder: str | Path | None = None) -> dict[str, Any]:
    """Make the run's summary row (``make``: one of the ``*_row`` functions on the result
    the pipeline just wrote) and keep it next to the results file
    (:func:`instrument.run.results.write_record`); returns what was kept.

    Call it holding the run's lock, right after the pipeline wrote ``results.h5``. The
    record holds the analysis, ``status`` (``"analysed"``, or ``"failed"`` with ``cause``
    when the answer is not usable), the row (``result``, ``values``, ``flags``, with a flag
    for a run that did not finish) and whether the report was made.
    """
    try:
        row, status, cause = make().row(), "analysed", ""
    except AnalysisFailed as err:
        row, status, cause = dict(err.row or {}), "failed", f"not usable: {err}"
    flags = list(row.get("flags", ()))
    run_status = read_summary(run_path).status
    if run_status != "finished":
        flags.append(f"run status {run_status!r}: not every planned point was measured")
    kept = {"analysis": analysis, "status": status, "cause": cause,
            "result": row.get("result", ""), "values": dict(row.get("values") or {}),
            "flags": flags, "report": bool(report)}
    write_record(run_path, get_analysis(analysis).pipeline, kept, folder=folder)
    return kept


# ------------------------------------------------------------------------------ registry
ANALYSES: dict[str, Analysis] = {
    a.name: a for a in (
        Analysis("fit", "fit", ("brdf_in_plane", "brdf_hemisphere", "reference"),
                 "scatterlab fit", analyse_fit, fit_record),
        Analysis("reconstruct", "lightfield", ("lightfield",), "scatterlab reconstruct",
                 analyse_reconstruct, reconstruct_record),
        Analysis("locate", "lightfield", ("lightfield",), "scatterlab locate",
                 analyse_locate, locate_record),
        Analysis("spheres", "spheres", ("sphere_capture",), "scatterlab spheres",
                 analyse_spheres, sphere_record),
    )
}


def get_analysis(name: str) -> Analysis:
    """The analysis called ``name`` (ValueError naming the choices otherwise)."""
    try:
        return ANALYSES[name]
    except KeyError:
        raise ValueError(f"unknown analysis {name!r}; one of {', '.join(ANALYSES)}") from None
