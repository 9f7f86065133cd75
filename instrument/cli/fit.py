"""``scatterlab fit RUN``: reduce a BRDF run, fit and select models, write results and a report.

Everything goes next to the run file ``DIR/RUN.h5``, into ``DIR/RUN/fit/`` (ADR 0013): the
report (``index.html`` and PNG figures) and ``results.h5``; ``--out`` names another folder.
The run file is only read, unless ``--into-run`` asks for the results in it as well.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any, cast

HELP = "BRDF of a run: reduce, fit models, select, report"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from instrument.pipelines.brdf.analyse import DEFAULT_MODELS

    p = sub.add_parser("fit", help=HELP)
    p.add_argument("run", help="run file (.h5) of a brdf_in_plane or brdf_hemisphere plan")
    add_fit_options(p, DEFAULT_MODELS)
    p.add_argument("--out", default=None,
                   help="folder for the report, figures and results.h5 (default: RUN/fit/ "
                   "next to the run file RUN.h5)")
    p.add_argument("--no-write", action="store_true",
                   help="write no results file (report only)")
    p.add_argument("--into-run", action="store_true",
                   help="also write the results into the run file (/entry/analysis), for "
                   "tools that expect one file; by default the run file is only read")
    p.set_defaults(func=run)


def add_fit_options(p: argparse.ArgumentParser,
                    default_models: tuple[str, ...] | None = None) -> None:
    """The analysis options of ``scatterlab fit``, shared with ``scatterlab batch fit``."""
    if default_models is None:
        from instrument.pipelines.brdf.analyse import DEFAULT_MODELS as default_models
    assert default_models is not None
    p.add_argument("--models", default=",".join(default_models),
                   help="comma-separated candidates, '+' for sums "
                   f"(default: {','.join(default_models)})")
    p.add_argument("--criterion", default="bic", choices=("bic", "aic", "aicc", "cv"),
                   help="model-selection rule (default: bic)")
    p.add_argument("--method", default="absolute", choices=("absolute", "relative"))
    p.add_argument("--detector", default=None, choices=("camera", "power_meter", "lockin"),
                   help="detector to reduce (default: camera; a spectral run: the plan's, "
                   "lock-in when it lists one)")
    p.add_argument("--per-wavelength", default="auto", choices=("auto", "yes", "no"),
                   help="reduce and fit each filter's wavelength separately and plot the "
                   "parameters against λ (default auto: when the run has a wavelength axis)")
    p.add_argument("--route", default="absolute", choices=("absolute", "ratio"),
                   help="lock-in: through the photodiode responsivity and the incident power, "
                   "or the ratio to a direct-beam reading (responsivity cancels)")
    p.add_argument("--reference", default=None,
                   help="reference-standard run at the same geometry (relative method)")
    p.add_argument("--reference-table", default=None,
                   help="CSV theta_i_deg,theta_r_deg,brdf,u_rel of the standard's BRDF")
    p.add_argument("--flat", default=None,
                   help="flat_field run for the PRNU correction (default: calibration.flat)")
    p.add_argument("--signature", default=None, help="instrument-signature run to subtract")
    p.add_argument("--nd-calibration", default=None, metavar="RUN",
                   help="ND calibration run for the transmissions of the neutral-density "
                        "filters the camera read the peak through (default: calibration.nd, "
                        "else the profile's values)")
    p.add_argument("--incident-power-w", type=float, default=None,
                   help="incident power on the sample (absolute method)")
    p.add_argument("--incident-power-u", type=float, default=None,
                   help="relative standard uncertainty of the incident power")
    p.add_argument("--distance-mm", type=float, default=None,
                   help="sample-to-receiver distance (default: profile + camera_z read-back)")
    p.add_argument("--distance-u-mm", type=float, default=None,
                   help="standard uncertainty of that distance in mm (default: unknown; "
                        "it enters the common scale uncertainty)")
    p.add_argument("--camera-calibration", default=None,
                   help="JSON with the camera's K, η, read noise, saturation and pupil")
    p.add_argument("--sigma-theta-deg", type=float, default=None,
                   help="angular standard uncertainty (default: stage tolerance/√3)")
    p.add_argument("--beam-radius-mm", type=float, default=None,
                   help="1/e² radius of the incident beam (default: the run's calibration or "
                        "geometry, or the simulated profile's); sets the illuminated footprint")
    p.add_argument("--point-receiver", action="store_true",
                   help="treat every point as a point sample: no footprint/aperture receiver "
                        "model (not recommended near specular)")
    p.add_argument("--cosine-corrected", action="store_true",
                   help="store f·cosθr (Stover's cosine-corrected BRDF) instead of f")
    p.add_argument("--bootstrap", type=int, default=0, metavar="N",
                   help="also refit the chosen model to N case-resampled copies of the data "
                        "and report the bootstrap σ and 95 %% interval (default: 0, off)")
    p.add_argument("--no-cv", action="store_true",
                   help="skip the cross-validation columns of the comparison")
    add_polarimetric_options(p)


def add_polarimetric_options(p: argparse.ArgumentParser) -> None:
    """The options of the polarimetric fit (runs with an optical train; scalar runs do not
    take them), shared by ``scatterlab fit`` and ``scatterlab batch fit``."""
    pol = p.add_argument_group("polarimetric runs (a run with an optical train; scalar runs "
                               "ignore these)")
    pol.add_argument("--calibration", default=None, action="append",
                     metavar="[drr=|pem=]NAME|FILE|none",
                     help="polarimeter calibration (scatterlab calibrate polarimeter) to "
                     "reduce with: a file, the NAME of a file in calibrations/ beside each "
                     "run, or 'none' for the nominal optics (default: the newest valid "
                     "calibration of the run's bench and mode in calibrations/ beside the "
                     "run). It applies to runs of its own mode; a run of the other mode is "
                     "refused. Give one per mode with drr=... and pem=... (the option "
                     "twice); a mode not given keeps the default")
    pol.add_argument("--pbrdf-start", default=None,
                     metavar="N,K,ALPHA,ALBEDO[,FRAME] | NAME=VALUE,...",
                     help="start values of the pBRDF fit: four or five numbers, or "
                     "name=value pairs changing only those (e.g. alpha=0.3,albedo=0.05); "
                     "default 1.5,0,0.2,0.1,0: a rough dielectric in the polarimeter's "
                     "nominal frame, degrees")
    pol.add_argument("--pbrdf-fixed", default=None, metavar="NAMES",
                     help="comma-separated pBRDF parameters held at their start value, "
                     "one model (e.g. k for a dielectric; '' fits all five); default: "
                     "the variant the data need, by BIC and the goodness-of-fit gate")
    pol.add_argument("--distribution", default="beckmann", choices=("beckmann", "ggx"),
                     help="facet-slope distribution of the pBRDF (default: beckmann)")


#: Companion files of the fit options that are not runs, by option name and attribute (a
#: companion run is checked by the pipeline, in the words every command uses for runs).
_COMPANIONS = (("--reference-table", "reference_table"),
               ("--camera-calibration", "camera_calibration"))


def fit_options(args: argparse.Namespace) -> dict[str, Any]:
    """The fit options as plain data (companion files as absolute paths), the form
    :func:`instrument.batch.analyses.fit_arguments` takes and a batch records.

    Raises
    ------
    ValueError
        An option out of range or a companion file that does not exist (named).
    """
    from instrument.batch.analyses import reduction_defaults
    from instrument.batch.polarimetric_options import options_from_arguments

    if args.bootstrap < 0:
        raise ValueError(f"--bootstrap must be ≥ 0 (number of resamples), got {args.bootstrap}")
    missing = [f"{opt} {getattr(args, attr)}" for opt, attr in _COMPANIONS
               if getattr(args, attr) is not None and not Path(getattr(args, attr)).exists()]
    if missing:
        raise ValueError(f"no such file: {'; '.join(missing)}")

    def path(attr: str) -> str | None:
        v = getattr(args, attr)
        return None if v is None else str(Path(v).resolve())

    reduction = {
        **reduction_defaults(),
        "method": args.method, "detector": args.detector or "camera",
        "cosine_corrected": args.cosine_corrected, "incident_power_w": args.incident_power_w,
        "u_incident_power_rel": args.incident_power_u, "sigma_theta_deg": args.sigma_theta_deg,
        "receiver_distance_mm": args.distance_mm, "u_distance_mm": args.distance_u_mm,
        "camera_calibration": path("camera_calibration"), "flat_run": path("flat"),
        "reference_run": path("reference"), "signature_run": path("signature"),
        "reference_table": path("reference_table"), "beam_radius_mm": args.beam_radius_mm,
        "nd_calibration": path("nd_calibration"),
        "receiver_geometry": not args.point_receiver,
    }
    return {
        "reduction": reduction,
        "models": [m.strip() for m in args.models.split(",") if m.strip()],
        "criterion": args.criterion,
        "run_cv": not args.no_cv,
        "n_bootstrap": int(args.bootstrap),
        "polarimetric": options_from_arguments(args),
    }


def run(args: argparse.Namespace) -> int:
    from instrument.batch.analyses import fit_arguments, fit_row, keep_row
    from instrument.cli._writing import writing_outputs
    from instrument.pipelines.brdf.pipeline import fit_run
    from instrument.pipelines.brdf.report import unit_text
    from instrument.run.results import RunBusy

    if _polarimetric(args.run):
        from instrument.cli._fit_polarimetric import run_polarimetric

        return run_polarimetric(args)
    spectral = _spectral_wanted(args)
    if spectral is None:
        return 2
    if spectral:
        return _run_spectral(args)
    if args.detector == "lockin":  # one wavelength: the lock-in's per-wavelength path
        return _run_spectral(args)
    try:
        options = fit_options(args)
    except ValueError as err:
        print(f"error: {err}")
        return 2
    try:
        with writing_outputs(args.run, "fit", "fit", args.out):
            done = fit_run(args.run, **fit_arguments(options), report_dir=args.out,
                           write=not args.no_write, into_run=args.into_run)
            if not args.no_write:  # the summary row, as `scatterlab batch fit` keeps it
                keep_row(args.run, "fit", lambda: fit_row(done), report=True,
                         folder=args.out)
    except KeyError as err:
        print(f"error: {err.args[0] if err.args else err}")
        return 2
    except (ValueError, RunBusy) as err:
        print(f"error: {err}")
        return 2
    except OSError as err:  # a companion file (table, calibration) that cannot be read
        print(f"error: {err.strerror or err}"
              + (f": {err.filename}" if getattr(err, "filename", None) else ""))
        return 2
    reduced, result, page = done.reduced, done.result, done.report
    fit = result.chosen_fit
    n = reduced.points.n
    print(f"{n} points ({reduced.points.method} method); chosen model "
          f"{result.chosen} ({result.selection.rule})")
    # the goodness-of-fit gate (docs/decisions/0051)
    print(f"  {result.verdict}")
    for warning in reduced.warnings:
        print(f"warning: {warning}")
    scale = ("common scale unknown, not included" if reduced.scale_unknown
             else f"common scale {reduced.points.u_scale_rel:.2%} included")
    factor = result.inflation.get(result.chosen, 1.0)
    inflated = ("" if factor == 1.0
                else f"; σ inflated ×{factor:.3g} because the model is rejected")
    print(f"parameters of {result.chosen} (value ± standard uncertainty from noise, angles "
          f"and pixel response; {scale}{inflated}):")
    specs = {ps.name: ps for ps in result.models[result.chosen].params}
    for name, value, err, unit in fit.table():
        what = specs[name].description if name in specs else ""
        print(f"  {name:<16} {value:12.6g} ± {err:<9.3g} {unit_text(unit) or '':<6} {what}")
    for k, r in (result.disagreeing_points()[:10] if not result.adequate else []):
        p = reduced.points
        print(f"  disagrees: {reduced.point_label(k)} (θi={math.degrees(p.theta_i[k]):.1f}°, "
              f"θr={math.degrees(p.theta_r[k]):.1f}°) r = {r:+.1f}σ")
    if fit.bootstrap is not None:
        b = fit.bootstrap
        print(f"  bootstrap check ({b.samples.shape[0]} resamples, noise only): σ of "
              + ", ".join(f"{name} {v:.3g}" for name, v
                          in zip(fit.param_names, b.stderr, strict=True)))
    print("model comparison (χ²/dof ≈ 1: the model fits within the uncertainties; "
          f"lower {result.selection.criterion.upper()} is better):")
    best = min(row.score(result.selection.criterion) for row in result.selection.table)
    width = max(len(row.name) for row in result.selection.table)
    n_fitted = int(result.fitted_index.size)  # clipped readings were left out of the fits
    for row in result.selection.table:
        dof = max(n_fitted - row.n_params, 1)
        delta = row.score(result.selection.criterion) - best
        print(f"  {row.name:<{width}} {row.n_params} parameter(s)  χ²/dof "
              f"{row.chi2 / dof:10.4g}  Δ{result.selection.criterion.upper()} {delta:10.4g}")
    for note in result.notes:
        print(f"  note: {note}")
    print(f"report: {page}")
    if done.results is not None:
        print(f"results: {done.results}")
    if args.into_run:
        print(f"results also written into {args.run} (/entry/analysis)")
    return 0


def _polarimetric(path: str) -> bool:
    """Whether the run records an optical train (a polarimetric run, ADR 0103)."""
    from instrument.pipelines.polarimetry.readings import is_polarimetric

    try:
        return is_polarimetric(path)
    except (OSError, KeyError, ValueError):
        return False  # the ordinary path reports the run file's problem in its words


def _spectral_wanted(args: argparse.Namespace) -> bool | None:
    """Whether to fit per wavelength (None: an error was printed)."""
    if args.per_wavelength != "auto":
        return cast(bool | None, args.per_wavelength == "yes")
    from instrument.pipelines.brdf.spectral import has_wavelength_axis
    from instrument.run.runfile import RunFileError, read_run

    try:
        return has_wavelength_axis(read_run(args.run))
    except (RunFileError, OSError, KeyError):
        return False  # the ordinary path reports the run file's problem in its words


def _run_spectral(args: argparse.Namespace) -> int:
    from instrument.pipelines.brdf.reduce import ReductionOptions
    from instrument.pipelines.brdf.spectral import SpectralOptions, fit_spectral

    models = tuple(m.strip() for m in args.models.split(",") if m.strip())
    if args.models == p_default_models():
        from instrument.pipelines.brdf.spectral import DEFAULT_SPECTRAL_MODELS

        models = DEFAULT_SPECTRAL_MODELS
    detector = None if args.detector in (None, "power_meter") else args.detector
    opts = SpectralOptions(
        detector=detector, route=args.route, u_incident_power_rel=args.incident_power_u,
        receiver_distance_mm=args.distance_mm, sigma_theta_deg=args.sigma_theta_deg,
        models=models,
        reduction=ReductionOptions(camera_calibration=args.camera_calibration,
                                   flat_run=args.flat, beam_radius_mm=args.beam_radius_mm,
                                   receiver_geometry=not args.point_receiver))
    from instrument.cli._writing import writing_outputs
    from instrument.run.results import RunBusy

    try:
        with writing_outputs(args.run, "fit", "fit", args.out):
            done = fit_spectral(args.run, opts, report_dir=args.out, write=not args.no_write,
                                criterion=args.criterion)
    except (KeyError, ValueError, RunBusy) as err:
        print(f"error: {err.args[0] if err.args else err}")
        return 2
    names = done.parameter_names()
    print(f"{len(done.fits)} wavelengths ({done.detector}); chosen model per wavelength, "
          "parameters ± standard uncertainty:")
    print("  " + f"{'λ (nm)':>8}  {'model':<22}" + "".join(f"{n:>20}" for n in names))
    for wf in done.fits:
        cells = []
        for n in names:
            val, err = done.parameter(n)
            k = done.fits.index(wf)
            cells.append(f"{val[k]:11.5g} ± {err[k]:<6.2g}")
        print(f"  {wf.group.wavelength_nm:8.1f}  {wf.result.chosen:<22}" + "".join(cells))
        for warning in wf.reduced.warnings:
            print(f"    warning: {warning}")
        if not wf.result.adequate:
            print(f"    {wf.result.verdict}")
    print(f"report: {done.report}")
    if done.results is not None:
        print(f"results: {done.results}")
    return 0


def p_default_models() -> str:
    """The --models default (the general candidate set); a spectral fit replaces it with
    the Fresnel model whose index is a parameter."""
    from instrument.pipelines.brdf.analyse import DEFAULT_MODELS

    return ",".join(DEFAULT_MODELS)
