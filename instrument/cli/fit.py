"""``scatterlab fit RUN``: reduce a BRDF run, fit and select models, write results and a report.

The results go into the run file (``/entry/analysis``) and the report (PNG figures and
``index.html``) into ``--out`` (default: ``<run file stem>_report`` next to the run file).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from instrument.batch.analyses import fit_arguments, reduction_defaults
from instrument.pipelines.brdf.analyse import DEFAULT_MODELS
from instrument.pipelines.brdf.pipeline import fit_run


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fit", help="BRDF of a run: reduce, fit models, select, report")
    p.add_argument("run", help="run file (.h5) of a brdf_in_plane or brdf_hemisphere plan")
    add_fit_options(p)
    p.add_argument("--out", default=None, help="report folder (default: <run>_report)")
    p.add_argument("--no-write", action="store_true",
                   help="leave the run file untouched (report only)")
    p.set_defaults(func=run)


def add_fit_options(p: argparse.ArgumentParser) -> None:
    """The analysis options of ``scatterlab fit``, shared with ``scatterlab batch fit``."""
    p.add_argument("--models", default=",".join(DEFAULT_MODELS),
                   help="comma-separated candidates, '+' for sums "
                   f"(default: {','.join(DEFAULT_MODELS)})")
    p.add_argument("--criterion", default="bic", choices=("bic", "aic", "aicc", "cv"),
                   help="model-selection rule (default: bic)")
    p.add_argument("--method", default="absolute", choices=("absolute", "relative"))
    p.add_argument("--detector", default="camera", choices=("camera", "power_meter"))
    p.add_argument("--reference", default=None,
                   help="reference-standard run at the same geometry (relative method)")
    p.add_argument("--reference-table", default=None,
                   help="CSV theta_i_deg,theta_r_deg,brdf,u_rel of the standard's BRDF")
    p.add_argument("--flat", default=None,
                   help="flat_field run for the PRNU correction (default: calibration.flat)")
    p.add_argument("--signature", default=None, help="instrument-signature run to subtract")
    p.add_argument("--incident-power-w", type=float, default=None,
                   help="incident power on the sample (absolute method)")
    p.add_argument("--incident-power-u", type=float, default=None,
                   help="relative standard uncertainty of the incident power")
    p.add_argument("--distance-mm", type=float, default=None,
                   help="sample-to-receiver distance (default: profile + camera_z read-back)")
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


#: Companion files of the fit options, by option name and attribute.
_COMPANIONS = (("--reference", "reference"), ("--flat", "flat"), ("--signature", "signature"),
               ("--reference-table", "reference_table"),
               ("--camera-calibration", "camera_calibration"))


def fit_options(args: argparse.Namespace) -> dict:
    """The fit options as plain data (companion files as absolute paths), the form
    :func:`instrument.batch.analyses.fit_arguments` takes and a results file records.

    Raises
    ------
    ValueError
        An option out of range or a companion file that does not exist (named).
    """
    if args.bootstrap < 0:
        raise ValueError(f"--bootstrap must be ≥ 0 (number of resamples), got {args.bootstrap}")
    missing = [f"{opt} {getattr(args, attr)}" for opt, attr in _COMPANIONS
               if getattr(args, attr) is not None and not Path(getattr(args, attr)).is_file()]
    if missing:
        raise ValueError(f"no such file: {'; '.join(missing)}")

    def path(attr: str) -> str | None:
        v = getattr(args, attr)
        return None if v is None else str(Path(v).resolve())

    reduction = {
        **reduction_defaults(),
        "method": args.method, "detector": args.detector,
        "cosine_corrected": args.cosine_corrected, "incident_power_w": args.incident_power_w,
        "u_incident_power_rel": args.incident_power_u, "sigma_theta_deg": args.sigma_theta_deg,
        "receiver_distance_mm": args.distance_mm,
        "camera_calibration": path("camera_calibration"), "flat_run": path("flat"),
        "reference_run": path("reference"), "signature_run": path("signature"),
        "reference_table": path("reference_table"), "beam_radius_mm": args.beam_radius_mm,
        "receiver_geometry": not args.point_receiver,
    }
    return {
        "reduction": reduction,
        "models": [m.strip() for m in args.models.split(",") if m.strip()],
        "criterion": args.criterion,
        "run_cv": not args.no_cv,
        "n_bootstrap": int(args.bootstrap),
    }


def run(args: argparse.Namespace) -> int:
    if not Path(args.run).is_file():
        print(f"error: no such file: run {args.run}")
        return 2
    try:
        options = fit_options(args)
    except ValueError as err:
        print(f"error: {err}")
        return 2
    try:
        done = fit_run(args.run, **fit_arguments(options), report_dir=args.out,
                       write=not args.no_write)
    except KeyError as err:
        print(f"error: {err.args[0] if err.args else err}")
        return 2
    except ValueError as err:
        print(f"error: {err}")
        return 2
    except OSError as err:
        # h5py raises OSError for a file that is not HDF5 (or is locked) and does not
        # always name it
        print(f"error: cannot read {args.run} or one of its companion runs as a "
              f"scatterlab run file (HDF5): {err}")
        return 2
    reduced, result, page = done.reduced, done.result, done.report
    fit = result.chosen_fit
    print(f"{reduced.points.n} points ({reduced.points.method}); chosen model "
          f"{result.chosen} ({result.selection.rule})")
    for name, value, err, unit in fit.table():
        print(f"  {name:<16} {value:12.6g} ± {err:.3g} {unit}")
    if fit.bootstrap is not None:
        b = fit.bootstrap
        print(f"  bootstrap ({b.samples.shape[0]} resamples, noise only): σ = "
              + ", ".join(f"{v:.3g}" for v in b.stderr))
    for row in result.selection.table:
        print(f"  {row.name:<22} k={row.n_params}  χ²={row.chi2:10.2f}  "
              f"BIC={row.bic:10.2f}")
    for note in result.notes:
        print(f"  note: {note}")
    print(f"report: {page}")
    if not args.no_write:
        print(f"results written to {args.run} (/entry/analysis)")
    return 0
