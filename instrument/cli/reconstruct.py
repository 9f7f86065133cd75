"""``scatterlab reconstruct RUN``: the hidden object's light field from a light-field run.

Assembles the measured light field from the run's frames, reconstructs the object light
field at the wall (:mod:`instrument.pipelines.lightfield.reconstruct`) and writes both, with
the figures (measured and reconstructed light fields, diagnostics), into ``DIR/RUN/lightfield/``
next to the run file ``DIR/RUN.h5`` (``results.h5`` and PNGs; ADR 0013); ``--out`` names
another folder. The run file is only read, unless ``--into-run`` asks for the results in
it as well.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "reconstruct the hidden object's light field from a light-field run"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reconstruct", help=HELP)
    p.add_argument("run", help="run file (.h5) of a lightfield plan")
    add_reconstruction_options(p)
    p.set_defaults(func=run)


def add_reconstruction_options(p: argparse.ArgumentParser) -> None:
    """Options shared with ``scatterlab locate``."""
    p.add_argument("--geometry", default=None,
                   help="geometry file (TOML: [camera], [track]); default: the emulated "
                   "bench's own, from the profile stored in the run")
    p.add_argument("--brdf", default=None,
                   help="wall BRDF: a material name or 'rho_s,sigma_deg,rho_d'; default: "
                   "the emulated bench's wall")
    p.add_argument("--domain", type=float, nargs=2, metavar=("A", "B"), default=None,
                   help="angle domain [a, b] in degrees (default: what every pixel row covers)")
    p.add_argument("--n-theta", type=_n_theta, default=128,
                   help="angle samples, >= 2 (default 128)")
    p.add_argument("--method", default="wiener",
                   choices=("wiener", "truncation", "gcv", "discrepancy", "none"),
                   help="regularisation (default: wiener, from the pooled signal spectrum)")
    p.add_argument("--out", default=None,
                   help="folder for results.h5 and the figures (default: RUN/lightfield/ "
                   "next to the run file RUN.h5); locate reads the reconstruction there")
    p.add_argument("--no-figures", action="store_true", help="write no figures")
    p.add_argument("--into-run", action="store_true",
                   help="also write the results into the run file "
                   "(/entry/analysis/lightfield); by default the run file is only read")


def _n_theta(text: str) -> int:
    n = int(text)
    if n < 2:
        raise argparse.ArgumentTypeError(f"{n} angle samples: need at least 2")
    return n


def options(args: argparse.Namespace) -> dict:
    """Keyword arguments of :func:`instrument.pipelines.lightfield.reconstruct.reconstruct_run`.

    Raises ValueError naming the option when ``--domain`` is not inside (−90°, 90°).
    """
    import math

    from instrument.pipelines.lightfield.geometry import load_geometry, parse_brdf

    domain = None
    if args.domain is not None:
        a, b = args.domain
        if not -90.0 < a < b < 90.0:
            raise ValueError(f"--domain {a:g} {b:g}: the angle domain in degrees must satisfy "
                             f"-90 < A < B < 90")
        domain = (math.radians(a), math.radians(b))
    return {
        "geometry": load_geometry(args.geometry) if args.geometry else None,
        "brdf": parse_brdf(args.brdf) if args.brdf else None,
        "domain_rad": domain,
        "n_theta": args.n_theta,
        "method": args.method,
    }


def out_dir(args: argparse.Namespace) -> Path:
    """``--out``, or ``RUN/lightfield/`` next to the run file."""
    from instrument.run.paths import results_dir

    return Path(args.out) if args.out else results_dir(args.run, "lightfield")


def figures_dir(args: argparse.Namespace) -> Path | None:
    return None if args.no_figures else out_dir(args)


def run(args: argparse.Namespace) -> int:
    from instrument.pipelines.lightfield.reconstruct import reconstruct_run
    from instrument.run.paths import RESULTS_NAME

    try:
        r = reconstruct_run(args.run, figures_dir=figures_dir(args), out_dir=args.out,
                            into_run=args.into_run, **options(args))
    except (ValueError, OSError, RuntimeError) as err:
        print(f"error: {err}")
        return 2
    rec = r.reconstruction
    lf = r.measured.field
    a, b = lf.domain_rad
    print(f"measured light field: {lf.shape[0]} positions y_m ∈ [{lf.y_mm[0]:.1f}, "
          f"{lf.y_mm[-1]:.1f}] mm × {lf.shape[1]} angles θ ∈ [{a:.3f}, {b:.3f}] rad "
          f"(d2 = {r.geometry.d2_mm:g} mm)")
    print(f"wall BRDF: {r.brdf.name or 'custom'}; γ = {float(rec.diagnostics.gamma.mean()):.3f}, "
          f"SNR_eff ≈ {float(rec.diagnostics.snr_eff.mean()):.3g}")
    print(f"reconstruction on {rec.incident_field.shape[0]} wall points: {rec.message}")
    print(f"p̂_max = {r.p_hat:g}; noise σ per sample {rec.diagnostics.noise.sigma_per_sample:.3g} "
          f"({rec.diagnostics.noise.method}), from the sensor rows {r.measured.sigma_rows:.3g}")
    for note in r.notes:
        print(f"note: {note}")
    if r.figures:
        print(f"figures: {', '.join(str(p) for p in r.figures)}")
    print(f"results: {out_dir(args) / RESULTS_NAME}")
    if args.into_run:
        print(f"results also written into {args.run} (/entry/analysis/lightfield)")
    return 0 if rec.recoverable else 1
