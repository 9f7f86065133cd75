"""``scatterlab spheres RUN``: analyse a sphere capture (relighting and consistency report).

Merges each point's HDR brackets into a radiance image, fits spherical harmonics, tests the
identities of physics.md §5 (M10/M16/M19/M21/M25), renders the last image from the other
three corner images by BRDF transfer and checks the capture's consistency against the noise
level (:mod:`instrument.pipelines.spheres`). Results go into ``/entry/analysis`` of the run file;
the figure to ``<run>.spheres.png`` (or ``--figure``).

Exit status: 0 consistent, 1 the consistency check flags the capture, 2 on errors.
The check's α is calibrated against noise only; on the simulated bench its false-alarm
rate is above α (``CONSISTENCY_LIMIT``, printed with the verdict).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from instrument.pipelines.spheres.analyse import CONSISTENCY_LIMIT
from instrument.pipelines.spheres.pipeline import analyse_run


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("spheres", help="relight and check a sphere capture (SH analysis)")
    p.add_argument("run", help="run file (.h5) of a sphere_capture plan")
    add_sphere_options(p)
    p.add_argument("--figure", default=None,
                   help="figure path (default <run>.spheres.png; 'none' for no figure)")
    p.add_argument("--no-write", action="store_true",
                   help="do not write the results into the run file")
    p.set_defaults(func=run)


def add_sphere_options(p: argparse.ArgumentParser) -> None:
    """The analysis options of ``scatterlab spheres``, shared with ``scatterlab batch
    spheres``."""
    p.add_argument("--lmax", type=int, default=20, help="SH order of the fits (default 20)")
    p.add_argument("--lmax-check", type=int, default=12,
                   help="orders 0..N of M21 used by the consistency check (default 12)")
    p.add_argument("--max-view-angle", type=float, default=85.0,
                   help="leave out pixels viewed more obliquely (deg, default 85)")
    p.add_argument("--check-view-angle", type=float, default=80.0,
                   help="grazing cut-off of the consistency check (deg, default 80)")
    p.add_argument("--false-alarm", type=float, default=0.01,
                   help="false-alarm rate of the consistency check (default 0.01)")
    p.add_argument("--threshold-scale", type=float, default=1.0,
                   help="multiply the bootstrap threshold by the bench's calibrated factor "
                        "(BENCHMARKS.md sphere_capture; default 1: noise-only threshold)")


def _option_error(args: argparse.Namespace) -> str | None:
    """The first out-of-range option, named as on the command line, or None."""
    if args.lmax < 1:
        return f"--lmax must be ≥ 1 (got {args.lmax})"
    if not 1 <= args.lmax_check <= args.lmax:
        return (f"--lmax-check must lie in [1, --lmax = {args.lmax}] "
                f"(got {args.lmax_check})")
    if not 0 < args.max_view_angle <= 90:
        return f"--max-view-angle must lie in (0, 90] deg (got {args.max_view_angle:g})"
    if not 0 < args.check_view_angle <= args.max_view_angle:
        return (f"--check-view-angle must lie in (0, --max-view-angle = "
                f"{args.max_view_angle:g}] deg (got {args.check_view_angle:g})")
    if not 0 < args.false_alarm < 1:
        return f"--false-alarm must lie in (0, 1) (got {args.false_alarm:g})"
    if not args.threshold_scale > 0:
        return f"--threshold-scale must be > 0 (got {args.threshold_scale:g})"
    return None


def sphere_options(args: argparse.Namespace) -> dict:
    """The analysis options as plain data: the keyword arguments of
    :func:`instrument.pipelines.spheres.analyse.analyse_capture`.

    Raises
    ------
    ValueError
        The first out-of-range option, named as on the command line.
    """
    bad = _option_error(args)
    if bad is not None:
        raise ValueError(bad)
    return {"lmax": int(args.lmax), "lmax_check": int(args.lmax_check),
            "max_view_angle_deg": float(args.max_view_angle),
            "check_view_angle_deg": float(args.check_view_angle),
            "false_alarm": float(args.false_alarm),
            "threshold_scale": float(args.threshold_scale)}


def run(args: argparse.Namespace) -> int:
    try:
        options = sphere_options(args)
    except ValueError as err:
        print(f"error: {err}")
        return 2
    fig = args.figure
    if fig is None:
        fig = str(Path(args.run).with_suffix("")) + ".spheres.png"
    elif fig.lower() == "none":
        fig = None
    try:
        capture, res = analyse_run(args.run, write=not args.no_write, figure=fig, **options)
    except (ValueError, OSError, KeyError) as err:
        print(f"error: {args.run}: {err} (is it the run file of a sphere_capture plan?)")
        return 2
    r, s = capture.radiance.shape[:2]
    print(f"sphere capture: {s} objects ({', '.join(capture.objects)}) × {r} lightings "
          f"({capture.lighting_role} = {', '.join(f'{x:g}' for x in capture.lighting_deg)} "
          "deg)")
    print(f"  sphere image: centre ({res.center[0]:.2f}, {res.center[1]:.2f}) px, radius "
          f"{res.radius:.2f} px; {int(res.observed.sum())} observed pixels; SH order "
          f"{res.lmax}; radiance in {capture.units}")
    for name, e in res.identities.items():
        ok = e.error[e.defined]
        if ok.size:
            print(f"  {name:<24s} median error {float(np.median(ok)):.3g}"
                  f" (orders {int(e.orders[0])}..{int(e.orders[-1])})")
    if res.lighting_object is not None:
        print(f"  lighting estimated from {res.lighting_object!r} (known BRDF, Wiener M7)")
    print(f"  relighting: {capture.objects[-1]} at {capture.lighting_role} = "
          f"{capture.lighting_deg[-1]:g} deg rendered from the other three (BRDF transfer): "
          f"L1 error {100 * res.relight_l1:.2f} %")
    rep = res.consistency
    verdict = "INCONSISTENT" if rep.inconsistent else "consistent"
    print(f"  consistency (M21, orders 0..{int(rep.orders[-1])} against the noise level): "
          f"T = {rep.statistic:.3g}, threshold {rep.threshold:.3g} at α = "
          f"{rep.false_alarm:g}: {verdict}")
    if res.threshold_scale == 1.0:
        print(f"  note: {CONSISTENCY_LIMIT}")
    else:
        print(f"  threshold = {res.threshold_scale:g} × the bootstrap's (--threshold-scale, "
              "calibrated on consistent captures of the bench)")
    if fig is not None:
        print(f"figure: {fig}")
    if not args.no_write:
        print(f"stored in {args.run}:/entry/analysis")
    return 1 if rep.inconsistent else 0
