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
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from instrument.pipelines.lightfield.results import ReconstructionResult

HELP = "reconstruct the hidden object's light field from a light-field run"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("reconstruct", help=HELP)
    p.add_argument("run", help="run file (.h5) of a lightfield plan")
    add_reconstruction_options(p)
    add_figure_options(p)
    p.set_defaults(func=run)


def add_reconstruction_options(p: argparse.ArgumentParser) -> None:
    """The reconstruction options, shared with ``scatterlab locate`` and ``scatterlab
    batch reconstruct|locate``."""
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


def add_figure_options(p: argparse.ArgumentParser) -> None:
    """Where one run's outputs go (``reconstruct`` and ``locate``; a batch puts them next
    to each run)."""
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


def reconstruction_options(args: argparse.Namespace) -> dict[str, Any]:
    """The reconstruction options as plain data (geometry file as an absolute path, BRDF
    text, domain in degrees), the form :func:`instrument.batch.analyses.
    reconstruct_arguments` takes and a results file records.

    Raises
    ------
    ValueError
        ``--domain`` not inside (−90°, 90°), or a ``--geometry``/``--brdf`` that does not
        load (named).
    """
    from instrument.pipelines.lightfield.geometry import load_geometry, parse_brdf

    domain = None
    if args.domain is not None:
        a, b = args.domain
        if not -90.0 < a < b < 90.0:
            raise ValueError(f"--domain {a:g} {b:g}: the angle domain in degrees must satisfy "
                             f"-90 < A < B < 90")
        domain = [float(a), float(b)]
    geometry = None
    if args.geometry:
        load_geometry(args.geometry)  # refused here, not once per run of a batch
        geometry = str(Path(args.geometry).resolve())
    if args.brdf:
        parse_brdf(args.brdf)
    return {"geometry": geometry, "brdf": args.brdf or None, "domain_deg": domain,
            "n_theta": int(args.n_theta), "method": args.method}


def out_dir(args: argparse.Namespace) -> Path:
    """``--out``, or ``RUN/lightfield/`` next to the run file."""
    from instrument.run.paths import results_dir

    return Path(args.out) if args.out else results_dir(args.run, "lightfield")


def figures_dir(args: argparse.Namespace) -> Path | None:
    return None if args.no_figures else out_dir(args)


def reconstruction_summary(r: ReconstructionResult, *, brdf_given: bool) -> list[str]:
    """The reconstruction's figures of merit in words: what each number is, its unit, and
    how to judge it (the symbols γ, SNR_eff and p̂_max of the figures in brackets; Sasaki
    2020, PhD thesis, Univ. of Minnesota, eqs. 2-37 and 2-38)."""
    rec = r.reconstruction
    diag = rec.diagnostics
    reg = rec.regularization
    gamma = float(diag.gamma.mean())
    snr = float(diag.snr_eff.mean())
    where = "--brdf" if brdf_given else "the bench profile's simulated wall"
    lines = [
        f"geometry: from the {r.geometry.source} (--geometry for another)",
        f"wall BRDF: {r.brdf.name or 'custom'} (from {where})",
        f"  degree of specularity (γ) {gamma:.3f}: the specular share of the wall's "
        "response, 1 mirror-like, 0 purely diffuse (a diffuse wall carries no object "
        "information)",
        f"  effective signal-to-noise ratio (SNR_eff) {snr:.3g}: γ × signal/noise per angle "
        f"sample; an angular order is recoverable where the wall passes more than "
        f"1/SNR_eff = {1.0 / snr if snr > 0 else float('inf'):.2g} of it (relative to order "
        "0)",
        f"reconstruction at {rec.incident_field.shape[0]} wall points, {reg.method} filter: "
        f"{reg.effective_dof:.1f} angular terms kept (effective degrees of freedom); the "
        f"filter removed {reg.residual_ratio:.2f} × the noise power (about 1: it removed "
        "the noise; well above 1: it removed signal too)",
    ]
    if rec.recoverable:
        a, b = rec.incident_field.domain_rad
        detail = math.degrees((b - a) / (2.0 * max(r.p_hat, 0.0) + 1.0))
        lines.append(f"  highest recovered angular order (p̂_max) {r.p_hat:g}: the finest "
                     f"angular detail is {detail:.2g} deg; higher is better, it sets the "
                     "resolution of 'scatterlab locate'")
    else:
        lines.append(f"  nothing recoverable: {rec.message}")
    return lines


def run(args: argparse.Namespace) -> int:
    from instrument.batch.analyses import keep_row, reconstruct_arguments, reconstruct_row
    from instrument.cli._writing import writing_outputs
    from instrument.pipelines.lightfield.figures import RADIANCE_UNIT
    from instrument.pipelines.lightfield.reconstruct import reconstruct_run
    from instrument.run.paths import RESULTS_NAME

    try:
        options = reconstruction_options(args)
        with writing_outputs(args.run, "reconstruct", "lightfield", args.out):
            r = reconstruct_run(args.run, figures_dir=figures_dir(args), out_dir=args.out,
                                into_run=args.into_run, **reconstruct_arguments(options))
            keep_row(args.run, "reconstruct", lambda: reconstruct_row(r),
                     report=not args.no_figures, folder=args.out)
    except (ValueError, OSError, RuntimeError) as err:
        print(f"error: {err}")
        return 2
    rec = r.reconstruction
    lf = r.measured.field
    diag = rec.diagnostics
    a, b = lf.domain_rad
    print(f"measured light field: {lf.shape[0]} camera positions y_m from {lf.y_mm[0]:.1f} to "
          f"{lf.y_mm[-1]:.1f} mm × {lf.shape[1]} ray angles from {math.degrees(a):.1f} to "
          f"{math.degrees(b):.1f} deg; camera {r.geometry.d2_mm:g} mm from the wall")
    for line in reconstruction_summary(r, brdf_given=args.brdf is not None):
        print(line)
    print(f"  noise per angle sample {diag.noise.sigma_per_sample:.3g} {RADIANCE_UNIT} "
          f"({diag.noise.method}); the sensor rows predict {r.measured.sigma_rows:.3g} (the "
          "two agree within about 10 % when the angle grid resolves the signal)")
    for note in r.notes:
        print(f"note: {note}")
    if r.figures:
        print(f"figures: {', '.join(str(p) for p in r.figures)}")
    print(f"results: {out_dir(args) / RESULTS_NAME}")
    if args.into_run:
        print(f"results also written into {args.run} (/entry/analysis/lightfield)")
    return 0 if rec.recoverable else 1
