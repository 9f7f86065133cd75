"""``scatterlab reconstruct RUN``: the hidden object's light field from a light-field run.

Assembles the measured light field from the run's frames, reconstructs the object light
field at the wall (:mod:`instrument.pipelines.lightfield.reconstruct`), stores both in the
run file under
``/entry/analysis/lightfield`` and writes the figures (measured and reconstructed light
fields, diagnostics) to ``<run>.lightfield/``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from instrument.batch.analyses import reconstruct_arguments
from instrument.pipelines.lightfield.geometry import load_geometry, parse_brdf
from instrument.pipelines.lightfield.reconstruct import reconstruct_run
from instrument.pipelines.lightfield.results import GROUP


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reconstruct",
                       help="reconstruct the hidden object's light field from a light-field run")
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
    """Where one run's figures go (``reconstruct`` and ``locate``)."""
    p.add_argument("--figures", default=None,
                   help="folder for the PNG figures (default: <run>.lightfield/)")
    p.add_argument("--no-figures", action="store_true", help="write no figures")


def _n_theta(text: str) -> int:
    n = int(text)
    if n < 2:
        raise argparse.ArgumentTypeError(f"{n} angle samples: need at least 2")
    return n


def reconstruction_options(args: argparse.Namespace) -> dict:
    """The reconstruction options as plain data (geometry file as an absolute path, BRDF
    text, domain in degrees), the form :func:`instrument.batch.analyses.
    reconstruct_arguments` takes and a results file records.

    Raises
    ------
    ValueError
        ``--domain`` not inside (−90°, 90°), or a ``--geometry``/``--brdf`` that does not
        load (named).
    """
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


def check_run_file(path: str) -> None:
    """Raise OSError naming the run file when it is missing or not an HDF5 file."""
    import h5py

    p = Path(path)
    if not p.is_file():
        raise OSError(f"run file {path} does not exist")
    if not h5py.is_hdf5(p):
        raise OSError(f"{path} is not an HDF5 run file: give the .h5 written by "
                      f"'scatterlab run' for a lightfield plan")


def figures_dir(args: argparse.Namespace) -> Path | None:
    if args.no_figures:
        return None
    return Path(args.figures) if args.figures else Path(args.run).with_suffix(".lightfield")


def run(args: argparse.Namespace) -> int:
    try:
        check_run_file(args.run)
        r = reconstruct_run(args.run, figures_dir=figures_dir(args),
                            **reconstruct_arguments(reconstruction_options(args)))
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
    print(f"stored in {args.run}:/{GROUP}")
    return 0 if rec.recoverable else 1
