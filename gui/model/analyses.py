"""The run browser's logic without Qt: what a run holds, and running its analyses.

:func:`run_details` reads a run file through :mod:`instrument.run.runfile` — provenance,
plan, devices, the fault log. :func:`analyses_for` says which pipelines apply to a plan
kind and :func:`run_analysis` runs one (the same entry points as ``scatterlab fit``,
``reconstruct``, ``locate`` and ``spheres``) and returns an :class:`AnalysisOutcome`: the
tables the GUI shows (fitted parameters, model selection, detected objects, identities),
the figures written, the HTML report and the notes and warnings. It runs on a background
thread; nothing here touches Qt or a device.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from gui.model.remedies import for_gui
from instrument.run.paths import results_dir

__all__ = ["ANALYSES", "FIT_DETECTORS", "AnalysisOutcome", "FitSettings", "RunDetails", "Table",
           "analyses_for", "resume_refusal", "run_analysis", "run_details", "with_catalog"]

#: Plan kind → the analyses that apply, in the order an operator runs them.
ANALYSES: dict[str, tuple[str, ...]] = {
    "brdf_in_plane": ("fit",),
    "brdf_hemisphere": ("fit",),
    "lightfield": ("reconstruct", "locate"),
    "sphere_capture": ("spheres",),
}
#: Statuses from which a run can be continued in its own file.
RESUMABLE = ("paused", "aborted", "interrupted", "failed")


def analyses_for(plan_kind: str) -> tuple[str, ...]:
    return ANALYSES.get(plan_kind, ())


#: Detectors a fit can reduce from the GUI (the lock-in is reduced per wavelength, which
#: the command line's ``--per-wavelength`` does).
FIT_DETECTORS = ("camera", "power_meter")


@dataclass(frozen=True)
class FitSettings:
    """The fit's options set in the Analysis tab: the same values as ``scatterlab fit``'s
    ``--distance-mm``, ``--distance-u-mm``, ``--incident-power-u``, ``--models`` and
    ``--detector`` (``None``: the option not given, the pipeline's default)."""

    distance_mm: float | None = None
    distance_u_mm: float | None = None
    incident_power_u: float | None = None   # relative standard uncertainty
    models: tuple[str, ...] = ()            # empty: the default candidates
    detector: str = "camera"

    def options(self) -> dict[str, Any]:
        """The plain options :func:`instrument.batch.analyses.fit_arguments` takes, as
        :func:`instrument.cli.fit.fit_options` builds them from the command line.

        Raises
        ------
        ValueError
            A value out of range, named by its control in the Analysis tab.
        """
        from analysis.brdf.registry import default_candidates  # = the fit's DEFAULT_MODELS
        from instrument.batch.analyses import reduction_defaults

        for label, v in (("Distance (mm)", self.distance_mm),
                         ("Distance uncertainty (mm)", self.distance_u_mm),
                         ("Incident power uncertainty", self.incident_power_u)):
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ValueError(f"{label} must be > 0 (or left empty for the default), "
                                 f"got {v}")
        if self.detector not in FIT_DETECTORS:
            raise ValueError(f"Detector must be one of {', '.join(FIT_DETECTORS)}, got "
                             f"{self.detector!r}")
        reduction = {**reduction_defaults(), "method": "absolute", "detector": self.detector,
                     "receiver_distance_mm": self.distance_mm,
                     "u_distance_mm": self.distance_u_mm,
                     "u_incident_power_rel": self.incident_power_u}
        from instrument.batch.polarimetric_options import polarimetric_fit_options

        # a polarimetric run is fitted with fit's defaults (newest calibration beside it)
        return {"reduction": reduction, "models": list(self.models or default_candidates()),
                "criterion": "bic", "run_cv": True, "n_bootstrap": 0,
                "polarimetric": polarimetric_fit_options()}


@dataclass(frozen=True)
class Table:
    title: str
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]


@dataclass(frozen=True)
class AnalysisOutcome:
    name: str
    path: Path
    summary: str
    tables: tuple[Table, ...] = ()
    figures: tuple[Path, ...] = ()
    report: Path | None = None
    notes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class RunDetails:
    path: Path
    provenance: dict[str, str]
    plan_text: str
    profile_text: str
    devices: dict[str, dict[str, str]]
    faults: tuple[dict[str, Any], ...]
    events: tuple[dict[str, Any], ...]
    n_points: int
    n_planned: int
    plan_kind: str
    status: str
    bench_name: str
    analyses: tuple[str, ...] = field(default=())


def run_details(path: str | Path) -> RunDetails:
    """Everything the browser shows of one run file (read-only, plain h5py)."""
    from instrument.run.runfile import read_attributes, read_events, read_run

    path = Path(path)
    data = read_run(path)
    attrs = read_attributes(path)
    events = read_events(path)
    profile = data.profile()
    bench = str(profile.get("bench", {}).get("name", ""))
    prov = {
        "run id": data.run_id, "status": data.status, "plan": f"{data.plan_name} "
        f"({data.plan_kind})", "sample": data.sample_name, "bench": bench,
        "started": attrs.get("start_time", ""), "ended": attrs.get("end_time", ""),
        "software": attrs.get("software_version", ""),
        "durability": attrs.get("durability", ""),
        "points": f"{data.n_points} of {attrs.get('n_planned', '?')} planned",
        "frames": "none" if data.frame_shape is None else
        f"{int(data.frame_point.size)} of {data.frame_shape[1]}×{data.frame_shape[0]} px",
        "file": str(path),
    }
    for k, v in data.geometry.items():
        prov[f"geometry.{k}"] = f"{v:g}" if isinstance(v, float) else str(v)
    for k, v in data.calibration.items():
        prov[f"calibration.{k}"] = v
    n_planned = int(attrs.get("n_planned", data.n_points) or data.n_points)
    return RunDetails(path, prov, data.plan_text, data.profile_text, data.identities,
                      tuple(e for e in events if e.get("kind") == "fault"), tuple(events),
                      data.n_points, n_planned, data.plan_kind, data.status, bench,
                      analyses_for(data.plan_kind))


def with_catalog(d: RunDetails, row: Any) -> RunDetails:
    """The details as the catalog lists the run (``row``: a
    :class:`instrument.run.catalog.RunRow`, refreshed live).

    The file's own status attribute says ``running`` after a crash, and a view read
    before a resume keeps the old count; the catalog (refreshed from the journal by
    :meth:`~instrument.run.catalog.Catalog.refresh_live`) is what the list shows, so the
    details take their status and point count from it and never contradict the list.
    """
    status = str(row.status) if row.status else d.status
    n_points = int(row.n_points) if row.n_points is not None else d.n_points
    n_planned = int(row.n_planned) if row.n_planned else d.n_planned
    prov = dict(d.provenance)
    prov["status"] = status
    prov["points"] = f"{n_points} of {n_planned} planned"
    return replace(d, provenance=prov, status=status, n_points=n_points,
                   n_planned=n_planned)


def resume_refusal(d: RunDetails) -> str | None:
    """Why the run cannot be continued, or ``None`` when it can (paused, aborted,
    interrupted or failed, with points still to measure)."""
    if d.status not in RESUMABLE:
        what = "finished: every point is measured" if d.status == "finished" else \
            f"{d.status}"
        return f"run {d.provenance.get('run id', d.path.stem)} is {what}; nothing to resume"
    if d.n_points >= d.n_planned:
        return (f"run {d.provenance.get('run id', d.path.stem)} has all {d.n_planned} "
                "points; nothing to resume")
    return None


def _figures(folder: Path, since: float) -> tuple[Path, ...]:
    if not folder.is_dir():
        return ()
    return tuple(sorted(p for p in folder.glob("*.png") if p.stat().st_mtime >= since - 1))


def _fmt(x: Any) -> str:
    if isinstance(x, float):
        return "—" if not math.isfinite(x) else f"{x:.6g}"
    return str(x)


def run_analysis(name: str, path: str | Path,
                 fit: FitSettings | None = None) -> AnalysisOutcome:
    """Run analysis ``name`` (:data:`ANALYSES`) on the run file ``path`` as the CLI does:
    its results file, figures and report go next to the run, into ``DIR/RUN/<pipeline>/``
    (ADR 0013); the run file is only read. Like the CLI it holds the run's lock while it
    analyses and writes (ADR 0070), so it waits for a batch analysing the same run.

    Raises
    ------
    ValueError, KeyError, OSError, RuntimeError
        As the pipeline raises them (their messages say what is missing); RunBusy (a
        RuntimeError) when another analysis held the run for the lock's whole wait.
    """
    from instrument.run.results import run_lock
    from instrument.run.runfile import check_run_file

    analyses = {"fit": _fit, "reconstruct": _reconstruct, "locate": _locate,
                "spheres": _spheres}
    if name not in analyses:
        raise ValueError(f"unknown analysis {name!r}; known: fit, reconstruct, locate, "
                         "spheres")
    path = Path(path)
    check_run_file(path, name)  # first, so a wrong path creates no folder for the lock
    if name == "fit":
        options = (fit or FitSettings()).options()  # before the lock: a bad value is quick
        analyses["fit"] = lambda p, t0: _fit(p, t0, options)
    with run_lock(path):
        out = analyses[name](path, time.time())
    # a remedy the pipeline words as a CLI option names the GUI's control instead
    return replace(out, notes=tuple(for_gui(n) for n in out.notes),
                   warnings=tuple(for_gui(w) for w in out.warnings))


def _fit(path: Path, t0: float, options: dict[str, Any]) -> AnalysisOutcome:
    from instrument.batch.analyses import fit_arguments
    from instrument.pipelines.brdf.pipeline import fit_run

    done = fit_run(path, **fit_arguments(options))
    result, reduced = done.result, done.reduced
    fit = result.chosen_fit
    params = Table(f"{result.chosen}: fitted parameters",
                   ("parameter", "value", "± σ", "unit"),
                   tuple((n, _fmt(v), _fmt(e), u) for n, v, e, u in fit.table()))
    sel = Table(f"model selection ({result.selection.rule})",
                ("model", "k", "χ²", "BIC"),
                tuple((r.name, str(r.n_params), f"{r.chi2:.2f}", f"{r.bic:.2f}")
                      for r in result.selection.table))
    warnings = list(reduced.warnings)
    if not result.adequate:  # the goodness-of-fit gate (ADR 0051)
        warnings.append(f"{result.verdict}; the σ are inflated")
    folder = done.report.parent if done.report is not None else results_dir(path, "fit")
    return AnalysisOutcome(
        "fit", path, f"{reduced.points.n} points ({reduced.points.method}); chosen model "
        f"{result.chosen} ({result.selection.rule}); {result.verdict}", (params, sel),
        _figures(folder, t0), done.report, tuple(result.notes), tuple(warnings))


def _reconstruct(path: Path, t0: float) -> AnalysisOutcome:
    from instrument.pipelines.lightfield.reconstruct import reconstruct_run

    folder = results_dir(path, "lightfield")
    r = reconstruct_run(path, figures_dir=folder)
    rec = r.reconstruction
    lf = r.measured.field
    rows = (("positions y_m", str(lf.shape[0])), ("angles θ", str(lf.shape[1])),
            ("d2", f"{r.geometry.d2_mm:g} mm"), ("wall points", str(rec.incident_field.shape[0])),
            ("p̂_max", f"{r.p_hat:g}"), ("recoverable", str(rec.recoverable)))
    return AnalysisOutcome("reconstruct", path, rec.message,
                           (Table("reconstruction", ("quantity", "value"), rows),),
                           tuple(Path(p) for p in r.figures) or _figures(folder, t0),
                           None, tuple(r.notes),
                           () if rec.recoverable else ("the light field is not recoverable",))


def _locate(path: Path, t0: float) -> AnalysisOutcome:
    from instrument.pipelines.lightfield.locate import locate_run

    folder = results_dir(path, "lightfield")
    r = locate_run(path, figures_dir=folder)
    det = r.detection
    rows = []
    for k in range(det.count):
        y, z = det.positions_mm[k]
        res = det.resolutions[k]
        rows.append((str(k), det.quality[k], f"{y:.2f}", f"{z:.2f}",
                     f"±{res.transverse_mm:.1f}", f"±{res.depth_mm:.1f}",
                     f"{det.brightness_rp[k]:.4g}", f"{det.significance[k]:.1f}σ"))
    return AnalysisOutcome("locate", path, r.message,
                           (Table("objects", ("#", "quality", "y (mm)", "z (mm)",
                                              "across", "depth", "brightness", "significance"),
                                  tuple(rows)),),
                           tuple(Path(p) for p in r.figures) or _figures(folder, t0))


def _spheres(path: Path, t0: float) -> AnalysisOutcome:
    import numpy as np

    from instrument.pipelines.spheres.pipeline import analyse_run

    figure = results_dir(path, "spheres") / "relighting.png"
    figure.parent.mkdir(parents=True, exist_ok=True)
    capture, res = analyse_run(path, figure=figure)
    ident = []
    for name, e in res.identities.items():
        ok = e.error[e.defined]
        ident.append((name, f"{float(np.median(ok)):.3g}" if ok.size else "—"))
    rep = res.consistency
    verdict = "INCONSISTENT" if rep.inconsistent else "consistent"
    rows = (("objects", ", ".join(capture.objects)),
            ("relighting L1 error", f"{100 * res.relight_l1:.2f} %"),
            ("consistency T", f"{rep.statistic:.3g} (threshold {rep.threshold:.3g})"),
            ("verdict", verdict))
    return AnalysisOutcome(
        "spheres", path, f"{len(capture.objects)} objects × {capture.radiance.shape[0]} "
        f"lightings: {verdict}",
        (Table("summary", ("quantity", "value"), rows),
         Table("identities (median error)", ("identity", "error"), tuple(ident))),
        (figure,) if figure.exists() else (), None, (),
        ("the consistency check flags the capture",) if rep.inconsistent else ())
