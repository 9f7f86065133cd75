"""``scatterlab fit RUN`` for a polarimetric run: Mueller matrices, decomposition, pBRDF
(:mod:`instrument.pipelines.polarimetry.pipeline`), with the console summary."""

from __future__ import annotations

import argparse


def run_polarimetric(args: argparse.Namespace) -> int:
    from analysis.polarimetry.validation import PolarimetryInputError
    from instrument.batch.polarimetric_options import fit_keywords, options_from_arguments
    from instrument.cli._writing import writing_outputs
    from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
    from instrument.run.results import RunBusy

    try:
        options = options_from_arguments(args)
        keywords = fit_keywords(args.run, options)  # another mode's file: refused by name
        with writing_outputs(args.run, "fit", "fit", args.out):
            done = fit_polarimetric_run(
                args.run, **keywords, report_dir=args.out, write=not args.no_write,
                into_run=bool(getattr(args, "into_run", False)))
    except (ValueError, RunBusy, PolarimetryInputError) as err:
        print(f"error: {err}")
        return 2
    except OSError as err:
        print(f"error: {err.strerror or err}"
              + (f": {err.filename}" if getattr(err, "filename", None) else ""))
        return 2
    s = done.summary
    if not s["calibrated"]:
        print(f"warning: {s['calibration_text']}")
    else:
        print(s["calibration_text"])
    n = len(done.points)
    print(f"{n} geometr{'y' if n == 1 else 'ies'}, Mueller-matrix BRDF (m00 in 1/sr, m_ij/m00 ± σ; "
          "D, R, Δ of the Lu–Chipman decomposition):")
    for p in done.points:
        d = p.decomposition
        dec = ("decomposition undefined: " + p.decomposition_note if d is None or
               d.sigma is None else
               f"D {d.params[1]:.3f} ± {d.sigma[1]:.2g}, R {d.params[2]:.3f} ± "
               f"{d.sigma[2]:.2g} rad, Δ {d.params[4]:.3f} ± {d.sigma[4]:.2g}")
        flag = "  NOT REALIZABLE within σ (kept, not projected)" if \
            p.realizability.flagged else ""
        unit = "" if p.group.transmitted else " 1/sr"
        print(f"  {p.group.label():<28} m00 {p.brdf.m[0, 0]:.4g} ± {p.brdf.sigma[0, 0]:.2g}"
              f"{unit}  κ {p.condition:.3g}  {dec}{flag}")
    fit = s["pbrdf"]
    if fit is not None:
        print(f"pBRDF {fit['variant']} ({fit['distribution']} facets): {fit['verdict']}")
        if fit.get("selection"):
            sel = fit["selection"]
            print(f"  chosen by {sel['rule']}: " + ", ".join(
                f"{r['name']} {sel['criterion'].upper()} {r[sel['criterion']]:.1f}"
                for r in sel["table"]))
        for name, v, e in zip(fit["param_names"], fit["params"], fit["stderr"],
                              strict=True):
            held = " (fixed)" if name in fit["fixed"] else ""
            print(f"  {name:<8} {v:12.6g} ± {e:.3g}{held}")
    for note in s["notes"]:
        print(f"  note: {note}")
    if done.report is not None:
        print(f"report: {done.report}")
    if done.results is not None:
        print(f"results: {done.results}")
    if getattr(args, "into_run", False):
        print(f"results also written into {args.run} (/entry/analysis)")
    return 0
