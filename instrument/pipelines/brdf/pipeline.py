"""A BRDF run file → reduced points, model fits and selection, the report and stored results.

:func:`fit_run` is what ``scatterlab fit`` does, callable from scripts and the GUI:
reduce (:mod:`.reduce`), fit and select (:mod:`.analyse`), draw the report
(:mod:`.report`) and write the results into the run file (:mod:`.results`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from analysis.brdf import get_model
from instrument.pipelines.brdf.analyse import DEFAULT_MODELS, AnalysisResult, analyse
from instrument.pipelines.brdf.reduce import Reduced, ReductionOptions, reduce_run
from instrument.pipelines.brdf.report import write_report
from instrument.pipelines.brdf.results import write_analysis
from instrument.run.runfile import RunData, read_run

__all__ = ["FitRun", "default_report_dir", "fit_run"]


@dataclass(frozen=True)
class FitRun:
    """What :func:`fit_run` produced: the run read, its reduction, the analysis and where the
    report went (``None`` when none was asked for)."""

    run: RunData
    reduced: Reduced
    result: AnalysisResult
    report: Path | None


def default_report_dir(run_path: str | Path) -> Path:
    """``<run file stem>_report`` next to the run file."""
    p = Path(run_path)
    return p.with_name(p.stem + "_report")


def fit_run(
    path: str | Path,
    options: ReductionOptions | None = None,
    models: Sequence[str] = DEFAULT_MODELS,
    *,
    criterion: str = "bic",
    run_cv: bool = True,
    n_bootstrap: int = 0,
    report_dir: str | Path | None = None,
    report: bool = True,
    write: bool = True,
) -> FitRun:
    """Reduce, fit, select; write the report (``report_dir``, default
    :func:`default_report_dir`) and, with ``write``, the results into the run file.

    Raises
    ------
    KeyError
        An unknown model name (checked before the reduction, which is the slow part).
    ValueError
        Missing calibration, reference or dark data, or no scattering points.
    """
    for name in models:
        get_model(name)
    reduced = reduce_run(path, options)
    run = read_run(path)
    wavelength = run.profile().get("simulation", {}).get("source", {}).get("wavelength_nm")
    result = analyse(reduced.points, models, criterion=criterion, run_cv=run_cv,
                     n_bootstrap=n_bootstrap,
                     wavelength_nm=None if wavelength is None else float(wavelength))
    page = None
    if report:
        page = write_report(report_dir or default_report_dir(path), reduced.points, result,
                            title=f"BRDF of {run.sample_name or run.run_id} "
                            f"(run {run.run_id})", provenance=reduced.provenance,
                            point_labels=[reduced.point_label(k)
                                          for k in range(reduced.points.n)],
                            warnings=reduced.warnings,
                            scale_unknown=bool(reduced.scale_unknown))
    if write:
        write_analysis(path, reduced, result.to_dict())
    return FitRun(run, reduced, result, page)
