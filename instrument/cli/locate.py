"""``scatterlab locate RUN``: find the hidden objects of a light-field run.

Uses the reconstruction stored by ``scatterlab reconstruct`` in ``DIR/RUN/lightfield/
results.h5`` (or makes it, with the same options), refocuses it over a (y, z) grid and
detects the objects with their theoretical resolution
(:func:`instrument.pipelines.lightfield.locate.locate_run`). Results go into the same
results file under ``/entry/analysis/lightfield/localisation``; figures ((y, z) map, focal
stack, z-profiles) into the same folder (ADR 0013).
"""

from __future__ import annotations

import argparse
from typing import Any

from instrument.cli.reconstruct import (
    add_figure_options,
    add_reconstruction_options,
    figures_dir,
    out_dir,
    reconstruction_options,
)

HELP = "locate the hidden objects of a light-field run"

#: The depth-quality flags of :data:`analysis.lightfield.QUALITY_FLAGS`, in words.
QUALITY_WORDS = {
    "resolved": "resolved (the three depth estimates agree)",
    "two_estimates_agree": "likely (two of the three depth estimates agree)",
    "unresolved": "unresolved (the data support only an interval)",
    "extended": "of an extended object (larger than the blur)",
}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("locate", help=HELP)
    p.add_argument("run", help="run file (.h5) of a lightfield plan")
    add_locate_options(p)
    add_figure_options(p)
    p.set_defaults(func=run)


def add_locate_options(p: argparse.ArgumentParser) -> None:
    """The localisation options (with the reconstruction's), shared with ``scatterlab
    batch locate``."""
    p.add_argument("--y-range", type=float, nargs=2, metavar=("Y0", "Y1"), default=None,
                   help="trial y range in mm (default: the wall points ± 60 mm)")
    p.add_argument("--z-range", type=float, nargs=2, metavar=("Z0", "Z1"),
                   default=(-400.0, -60.0), help="trial z range in mm, < 0 (default -400 -60)")
    p.add_argument("--false-alarm", type=float, default=0.01,
                   help="probability per scan that noise alone yields a reported object "
                        "(default 0.01); weaker candidates are counted, not reported")
    p.add_argument("--again", action="store_true",
                   help="reconstruct again even if the results file holds a reconstruction")
    add_reconstruction_options(p)


def locate_options(args: argparse.Namespace) -> dict[str, Any]:
    """The localisation options as plain data, the form :func:`instrument.batch.analyses.
    locate_arguments` takes: ``reconstruct`` holds the reconstruction options when the
    run must be reconstructed again (``--again`` or any reconstruction option other than
    its default), None to use the reconstruction the run holds.

    Raises
    ------
    ValueError
        An option that cannot be used (named).
    """
    given = (args.geometry, args.brdf, args.domain)
    again = (args.again or any(v is not None for v in given) or args.n_theta != 128
             or args.method != "wiener")
    return {"y_range_mm": None if args.y_range is None else [float(v) for v in args.y_range],
            "z_range_mm": [float(v) for v in args.z_range],
            "false_alarm": float(args.false_alarm),
            "reconstruct": reconstruction_options(args) if again else None}


def depth_text(z: float, interval: object, open_ends: object, quality: str) -> str:
    """A detection's depth in words: an open end of its interval is the search range's
    edge, not a measured bound, and is said so."""
    # interval and open_ends are pairs (typed object: the detections' own types vary)
    far, near = (float(v) for v in interval)  # type: ignore[attr-defined]
    open_far, open_near = (bool(v) for v in open_ends)  # type: ignore[attr-defined]
    if open_far:
        return (f"z beyond {far:.1f} mm (nearer than {near:.1f} mm; the object may lie past "
                f"the searched range: widen --z-range)")
    if open_near:
        return (f"z between {far:.1f} mm and the near end of the searched range "
                f"({near:.1f} mm; widen --z-range)")
    if quality == "unresolved":
        return f"z between {far:.1f} and {near:.1f} mm (best guess {z:.1f} mm)"
    return f"z = {z:.2f} mm (interval {far:.1f} to {near:.1f} mm)"


def run(args: argparse.Namespace) -> int:
    from instrument.batch.analyses import keep_row, locate_arguments, locate_row
    from instrument.cli._writing import writing_outputs
    from instrument.pipelines.lightfield.figures import RADIANCE_UNIT
    from instrument.pipelines.lightfield.locate import locate_run
    from instrument.run.paths import RESULTS_NAME

    try:
        options = locate_options(args)
        with writing_outputs(args.run, "locate", "lightfield", args.out):
            r = locate_run(args.run, figures_dir=figures_dir(args), out_dir=args.out,
                           into_run=args.into_run, **locate_arguments(options))
            keep_row(args.run, "locate", lambda: locate_row(r),
                     report=not args.no_figures, folder=args.out)
    except (ValueError, OSError, RuntimeError) as err:
        print(f"error: {err}")
        return 2
    print(r.message)
    det = r.detection
    for k in range(det.count):
        y, z = det.positions_mm[k]
        res = det.resolutions[k]
        quality = det.quality[k]
        depth = depth_text(float(z), det.depth_interval_mm[k], det.depth_open[k], quality)
        print(f"  object {k} ({det.significance[k]:.1f}σ, false-alarm probability "
              f"{det.false_alarm[k]:.2g} per scan), depth "
              f"{QUALITY_WORDS.get(quality, quality)}: y = {y:.2f} mm, {depth}")
        if quality == "extended":
            across, deep = det.extent_mm[k]
            print(f"    one extended object, not {len(det.components_mm[k])} points: size "
                  f"{across:.1f} ± {res.transverse_mm:.1f} mm across, {deep:.1f} ± "
                  f"{res.depth_mm:.1f} mm in depth")
        print(f"    theoretical blur ±{res.transverse_mm:.1f} mm across, ±{res.depth_mm:.1f} "
              f"mm in depth; brightness {det.brightness_rp[k]:.4g} {RADIANCE_UNIT} "
              f"(radiance-preserving refocusing; conventional refocusing gives "
              f"{det.brightness_conventional[k]:.4g}, lower the farther the object sits)")
    if r.figures:
        print(f"figures: {', '.join(str(p) for p in r.figures)}")
    print(f"results: {out_dir(args) / RESULTS_NAME}")
    if args.into_run:
        print(f"results also written into {args.run} (/entry/analysis/lightfield)")
    return 0 if r.recoverable else 1
