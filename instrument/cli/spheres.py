"""``scatterlab spheres RUN``: analyse a sphere capture (relighting and consistency report).

Merges each point's HDR brackets into a radiance image, fits spherical harmonics, tests the
spherical-harmonic identities of Mahajan, Ramamoorthi & Curless (ECCV 2006, eqs. 10, 16, 19,
21 and 25), renders the last image from the other three corner images by BRDF transfer and
checks the capture's consistency against the noise level
(:mod:`instrument.pipelines.spheres`). Results (``results.h5``) and the figure
(``relighting.png``) go into ``DIR/RUN/spheres/`` next to the run file ``DIR/RUN.h5`` (ADR
0013); ``--out`` names another folder. The run file is only read, unless ``--into-run``
asks for the results in it as well.

Exit status: 0 consistent, 1 the consistency check flags the capture, 2 on errors.
The check's false-alarm rate is calibrated against noise only; on the simulated bench
it is above the one asked for (``CONSISTENCY_LIMIT``, printed with the verdict).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from analysis.sh.consistency import ConsistencyReport
    from instrument.pipelines.spheres.capture import SphereCapture

HELP = "relight and check a sphere capture (SH analysis)"


def unit_words(units: str) -> str:
    """A stored unit string as printed (``W m-2 sr-1`` → ``W m⁻² sr⁻¹``)."""
    return units.replace("m-2", "m⁻²").replace("sr-1", "sr⁻¹").replace("DN/us", "DN/µs")


def identity_words(name: str, capture: SphereCapture) -> tuple[str, str]:
    """(what an identity of :func:`analyse_run` tests, in words; its equation number in
    Mahajan, Ramamoorthi & Curless 2006) for the result keys ``"M16 lighting 0"`` …"""
    tag, _, rest = name.partition(" ")
    role = capture.lighting_role

    def lighting(k: str) -> str:
        return f"{role} = {capture.lighting_deg[int(k)]:g} deg"

    if tag == "M16":
        return f"two objects, one lighting ({lighting(rest.split()[-1])})", "16"
    if tag == "M21":
        return "two objects × two lightings (corner images)", "21"
    if tag == "M25":
        return "all images: one lighting and one BRDF each", "25"
    if tag == "M10":
        k, j = rest.split(",")
        return f"{capture.objects[int(j)]} in the estimated lighting ({lighting(k)})", "10"
    if tag == "M19":
        return f"{rest}, two lightings", "19"
    return name, tag.lstrip("M")


def verdict_words(rep: ConsistencyReport) -> str:
    """The consistency verdict as printed: inconsistent, consistent, or no test possible
    (with the reason: then neither of the other two may be claimed)."""
    if not rep.testable:
        return f"{rep.verdict.upper()} ({rep.no_test_reason})"
    if rep.inconsistent:
        return ("INCONSISTENT: the images are not one set of objects under one set of "
                "lightings")
    return "consistent within the noise"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("spheres", help=HELP)
    p.add_argument("run", help="run file (.h5) of a sphere_capture plan")
    add_sphere_options(p)
    p.add_argument("--out", default=None,
                   help="folder for results.h5 and the figure (default: RUN/spheres/ next "
                   "to the run file RUN.h5)")
    p.add_argument("--no-figures", action="store_true", help="draw no figure")
    p.add_argument("--no-write", action="store_true", help="write no results file")
    p.add_argument("--into-run", action="store_true",
                   help="also write the results into the run file (/entry/analysis); by "
                   "default the run file is only read")
    p.set_defaults(func=run)


def add_sphere_options(p: argparse.ArgumentParser) -> None:
    """The analysis options of ``scatterlab spheres``, shared with ``scatterlab batch
    spheres``."""
    p.add_argument("--lmax", type=int, default=20, help="SH order of the fits (default 20)")
    p.add_argument("--lmax-check", type=int, default=12,
                   help="SH orders 0..N used by the consistency check (default 12)")
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


def sphere_options(args: argparse.Namespace) -> dict[str, Any]:
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
    import numpy as np

    from instrument.batch.analyses import SPHERE_FIGURE, keep_row, spheres_row
    from instrument.cli._writing import writing_outputs
    from instrument.pipelines.spheres.analyse import CONSISTENCY_LIMIT
    from instrument.pipelines.spheres.pipeline import analyse_run
    from instrument.run.paths import RESULTS_NAME, results_dir
    from instrument.run.results import RunBusy

    try:
        options = sphere_options(args)
    except ValueError as err:
        print(f"error: {err}")
        return 2
    folder = Path(args.out) if args.out else results_dir(args.run, "spheres")
    fig = None if args.no_figures else folder / SPHERE_FIGURE
    try:
        with writing_outputs(args.run, "spheres", "spheres", args.out):
            capture, res = analyse_run(args.run, write=not args.no_write, figure=fig,
                                       into_run=args.into_run, out_dir=args.out, **options)
            if not args.no_write:  # the batch summary row, as `scatterlab batch` keeps
                keep_row(args.run, "spheres", lambda: spheres_row(capture, res),
                         report=fig is not None, folder=args.out)
    except (ValueError, OSError, KeyError, RunBusy) as err:
        print(f"error: {err}")
        return 2
    r, s = capture.radiance.shape[:2]
    role = capture.lighting_role
    print(f"sphere capture: {s} objects ({', '.join(capture.objects)}) × {r} lightings "
          f"({role} = {', '.join(f'{x:g}' for x in capture.lighting_deg)} deg)")
    print(f"  sphere image: centre ({res.center[0]:.2f}, {res.center[1]:.2f}) px, radius "
          f"{res.radius:.2f} px; {int(res.observed.sum())} observed pixels; spherical "
          f"harmonics up to order {res.lmax}; radiance in {unit_words(capture.units)}")
    print("  identity checks: median over SH orders of the normalised error "
          "|X − Y|/(|X| + |Y|), 0 exact, 1 unrelated; the consistency test below judges "
          "them against the noise [equation of Mahajan, Ramamoorthi & Curless 2006]:")
    for name, e in res.identities.items():
        ok = e.error[e.defined]
        if ok.size:
            what, eq = identity_words(name, capture)
            print(f"    {what:<56s} {float(np.median(ok)):.3g} (orders {int(e.orders[0])}"
                  f"..{int(e.orders[-1])}) [eq. {eq}]")
    if res.lighting_object is not None:
        print(f"  lighting estimated from {res.lighting_object!r}, whose BRDF the plan gives "
              "(Wiener deconvolution, Mahajan et al. 2006 eq. 7)")
    print(f"  relighting: {capture.objects[-1]} at {role} = {capture.lighting_deg[-1]:g} deg "
          f"rendered from the other three images (BRDF transfer): L1 error "
          f"{100 * res.relight_l1:.2f} % (Σ|rendered − measured| / Σ|measured|; Mahajan et "
          "al. report 6.5 % and 9.5 % on real spheres)")
    rep = res.consistency
    print(f"  consistency test (two objects × two lightings, eq. 21, SH orders "
          f"0..{int(rep.orders[-1])}): statistic {rep.statistic:.3g} against the threshold "
          f"{rep.threshold:.3g} at a false-alarm rate of {rep.false_alarm:g}: "
          f"{verdict_words(rep)}")
    if res.threshold_scale == 1.0:
        print(f"  note: {CONSISTENCY_LIMIT}")
    else:
        print(f"  threshold = {res.threshold_scale:g} × the bootstrap's (--threshold-scale, "
              "calibrated on consistent captures of the bench)")
    if fig is not None:
        print(f"figure: {fig}")
    if not args.no_write:
        print(f"results: {folder / RESULTS_NAME}")
    if args.into_run:
        print(f"results also written into {args.run} (/entry/analysis)")
    return 1 if rep.inconsistent else 0
