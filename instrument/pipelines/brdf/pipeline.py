"""A BRDF run file → reduced points, model fits and selection, the report and stored results.

:func:`fit_run` is what ``scatterlab fit`` does, callable from scripts, the GUI and batch
analyses: check the run (:func:`instrument.run.runfile.check_run_file`), reduce
(:mod:`~instrument.pipelines.brdf.reduce`), fit and select
(:mod:`~instrument.pipelines.brdf.analyse`), draw the report
(:mod:`~instrument.pipelines.brdf.report`) and write the results
(:mod:`~instrument.pipelines.brdf.results`). Everything goes under ``DIR/RUN/fit/`` next to the run
file ``DIR/RUN.h5`` (ADR 0013): ``index.html``, the figures and ``results.h5``; the run file
is only read, unless ``into_run`` asks for the results in it as well.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from analysis.brdf import get_model
from instrument.pipelines.brdf.analyse import DEFAULT_MODELS, AnalysisResult, analyse
from instrument.pipelines.brdf.reduce import Reduced, ReductionOptions, reduce_run
from instrument.pipelines.brdf.report import write_report
from instrument.pipelines.brdf.results import write_analysis, write_fit_results
from instrument.run.paths import results_dir
from instrument.run.runfile import RunData, RunFileError, check_run_file, open_run, read_run

__all__ = ["FitRun", "default_report_dir", "fit_options", "fit_run"]

#: The companion runs a reduction may name, the option that names each, and its kinds.
COMPANIONS = (("flat_run", "--flat", ("flat_field",)),
              ("reference_run", "--reference", ("reference", "brdf_in_plane",
                                                "brdf_hemisphere")),
              ("signature_run", "--signature", ("signature",)))


@dataclass(frozen=True)
class FitRun:
    """What :func:`fit_run` produced: the run read, its reduction, the analysis, where the
    report went and where the results file went (``None`` when not asked for)."""

    run: RunData
    reduced: Reduced
    result: AnalysisResult
    report: Path | None
    results: Path | None = None


def default_report_dir(run_path: str | Path) -> Path:
    """``DIR/RUN/fit/`` for the run file ``DIR/RUN.h5`` (ADR 0013)."""
    return results_dir(run_path, "fit")


def fit_options(options: ReductionOptions | None = None,
                models: Sequence[str] = DEFAULT_MODELS, *, criterion: str = "bic",
                run_cv: bool = True, n_bootstrap: int = 0) -> dict[str, Any]:
    """Every option of :func:`fit_run` that changes its results, as recorded in the
    results file (and compared by :func:`instrument.run.results.already_done`)."""
    return {"reduction": asdict(options or ReductionOptions()), "models": list(models),
            "criterion": criterion, "cross_validation": run_cv, "bootstrap": n_bootstrap}


def refuse_polarimetric(path: str | Path) -> None:
    """A polarimetric run (its file records an optical train, ADR 0103) holds K retarder
    steps per geometry: the scalar reduction would treat them as repeated points of one
    BRDF and mix the analyser's states. Its reduction is the Mueller-matrix pipeline
    (:mod:`instrument.pipelines.polarimetry`), which ``scatterlab fit`` chooses for it."""
    with open_run(path) as f:
        polarimetric = "optical_train" in f["entry/instrument"]
    if polarimetric:
        raise RunFileError(
            f"{path} is a polarimetric run (dual-rotating-retarder steps at every "
            "geometry): the scalar BRDF fit would mix the analyser's states; reduce it to "
            "Mueller matrices with `scatterlab fit` (or "
            "instrument.pipelines.polarimetry.pipeline.fit_polarimetric_run)")


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
    into_run: bool = False,
) -> FitRun:
    """Reduce, fit, select; write the report and, with ``write``, ``results.h5``.

    ``report_dir`` (default :func:`default_report_dir`) receives the report and the
    results file. ``into_run`` also writes the results into the run file's
    ``/entry/analysis`` (for tools that expect one file).

    Raises
    ------
    RunFileError
        The run (or a companion run) is missing, unreadable or of another kind (checked
        first, with the same words as every command).
    KeyError
        An unknown model name (checked before the reduction, which is the slow part).
    ValueError
        Missing calibration, reference or dark data, or no scattering points.
    """
    check_run_file(path, "fit")
    refuse_polarimetric(path)
    opts = options or ReductionOptions()
    for attr, option, kinds in COMPANIONS:
        if getattr(opts, attr) is not None:
            check_run_file(getattr(opts, attr), kinds=kinds, role=option)
    for name in models:
        get_model(name)
    reduced = reduce_run(path, options)
    run = read_run(path)
    wavelength = run.profile().get("simulation", {}).get("source", {}).get("wavelength_nm")
    result = analyse(reduced.points, models, criterion=criterion, run_cv=run_cv,
                     n_bootstrap=n_bootstrap,
                     wavelength_nm=None if wavelength is None else float(wavelength))
    folder = Path(report_dir) if report_dir is not None else default_report_dir(path)
    page = None
    if report:
        page = write_report(folder, reduced.points, result,
                            title=f"BRDF of {run.sample_name or run.run_id} "
                            f"(run {run.run_id})", provenance=reduced.provenance,
                            point_labels=[reduced.point_label(k)
                                          for k in range(reduced.points.n)],
                            warnings=reduced.warnings,
                            scale_unknown=bool(reduced.scale_unknown))
    saved = None
    if write:
        saved = write_fit_results(
            path, reduced, result.to_dict(), run_id=run.run_id, folder=folder,
            options=fit_options(options, models, criterion=criterion, run_cv=run_cv,
                                n_bootstrap=n_bootstrap))
    if into_run:
        write_analysis(path, reduced, result.to_dict())
    return FitRun(run, reduced, result, page, saved)
