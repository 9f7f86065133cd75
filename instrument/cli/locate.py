"""``scatterlab locate RUN``: find the hidden objects of a light-field run.

Uses the reconstruction stored by ``scatterlab reconstruct`` (or makes it, with the same
options), refocuses it over a (y, z) grid and detects the objects with their theoretical
resolution (:func:`instrument.pipelines.lightfield.locate.locate_run`). Results go into
the run file under ``/entry/analysis/lightfield/localisation``; figures ((y, z) map, focal stack,
z-profiles) to ``<run>.lightfield/``.
"""

from __future__ import annotations

import argparse

from instrument.batch.analyses import locate_arguments
from instrument.cli.reconstruct import (
    add_figure_options,
    add_reconstruction_options,
    check_run_file,
    figures_dir,
    reconstruction_options,
)
from instrument.pipelines.lightfield.locate import locate_run
from instrument.pipelines.lightfield.results import GROUP


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("locate", help="locate the hidden objects of a light-field run")
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
    p.add_argument("--threshold", type=float, default=0.3,
                   help="drop detections weaker than this fraction of the strongest")
    p.add_argument("--again", action="store_true",
                   help="reconstruct again even if the run file holds a reconstruction")
    add_reconstruction_options(p)


def locate_options(args: argparse.Namespace) -> dict:
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
            "threshold_rel": float(args.threshold),
            "reconstruct": reconstruction_options(args) if again else None}


def run(args: argparse.Namespace) -> int:
    try:
        check_run_file(args.run)
        r = locate_run(args.run, figures_dir=figures_dir(args),
                       **locate_arguments(locate_options(args)))
    except (ValueError, OSError, RuntimeError) as err:
        print(f"error: {err}")
        return 2
    print(r.message)
    det = r.detection
    for k in range(det.count):
        y, z = det.positions_mm[k]
        res = det.resolutions[k]
        far, near = det.depth_interval_mm[k]
        quality = det.quality[k]
        depth = (f"z = {z:8.2f} mm" if quality != "unresolved"
                 else f"z unresolved, best guess {z:.1f} mm")
        print(f"  object {k} [{quality}]: y = {y:7.2f} mm, {depth}, z in [{far:.1f}, "
              f"{near:.1f}] mm  (blur ±{res.transverse_mm:.1f} mm across, ±{res.depth_mm:.1f} "
              f"mm in depth); brightness RP {det.brightness_rp[k]:.4g}, conventional "
              f"{det.brightness_conventional[k]:.4g}")
    if r.figures:
        print(f"figures: {', '.join(str(p) for p in r.figures)}")
    print(f"stored in {args.run}:/{GROUP}/localisation")
    return 0 if r.recoverable else 1
