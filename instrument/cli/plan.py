"""``scatterlab plan PLAN.toml``: dry run: points, travel, duration, coverage picture."""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from instrument.cli import _planner
from instrument.cli._format import fmt_s
from instrument.run.paths import DEFAULT_RUNS_DIR

if TYPE_CHECKING:
    from instrument.bench.profile import BenchProfile
    from instrument.plans.planfile import PlanSpec

HELP = "dry run of a plan: points, travel, duration, coverage PNG"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("plan", help=HELP)
    p.add_argument("plan", help="plan file (TOML)")
    p.add_argument("--bench", default="sim", help="bench profile name or path (default: sim)")
    p.add_argument("--out", default=str(DEFAULT_RUNS_DIR),
                   help="folder for the coverage picture <plan file name>_coverage.png "
                   f"(default: the runs folder, {DEFAULT_RUNS_DIR})")
    p.add_argument("--png", default=None,
                   help="the coverage picture's exact path (instead of --out)")
    _planner.add_arguments(p)
    p.set_defaults(func=run)


def _value(v: object) -> str:
    """A policy value as read in a sentence (lists joined, true/false as yes/no)."""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, list):
        return "+".join(str(x) for x in v)
    return f"{v:g}" if isinstance(v, float) else str(v)
def coverage_path(args: argparse.Namespace) -> Path:
    """``--png``, or ``<plan file name>_coverage.png`` in ``--out``."""
    if args.png:
        return Path(args.png)
    return Path(args.out) / f"{Path(args.plan).stem}_coverage.png"


def tradeoff_path(args: argparse.Namespace) -> Path:
    """The polarimetric trade's picture: the coverage picture's name with ``_tradeoff``."""
    cov = coverage_path(args)
    stem = cov.stem.removesuffix("_coverage")
    return cov.with_name(f"{stem}_tradeoff.png")


def run(args: argparse.Namespace) -> int:
    from instrument.bench.guard import GuardError
    from instrument.bench.profile import load_profile
    from instrument.plans import build_plan, load_plan
    from instrument.plans.lobe import lobe_of

    spec = load_plan(args.plan)
    profile = load_profile(args.bench)
    if getattr(args, "target_uncertainty", None) is not None:
        if not args.target_uncertainty > 0:
            print(f"error: --target-uncertainty must be a positive standard deviation, "
                  f"got {args.target_uncertainty}", file=sys.stderr)
            return 2
        try:
            return _planner.run_from_args(args, spec, profile)
        except (ValueError, KeyError) as err:  # their messages say what to change
            msg = err.args[0] if isinstance(err, KeyError) and err.args else err
            print(f"error: --target-uncertainty: {msg}", file=sys.stderr)
            return 2
    try:
        plan = build_plan(spec, profile)
    except GuardError as err:
        print(f"error: {err}")
        return 2
    est = plan.estimate()
    print(f"plan {spec.name!r} ({spec.kind}) on bench {profile.name!r}: "
          f"{est.n_points} points, order {spec.order}")
    if plan.dropped_in_beam:
        print(f"  {plan.dropped_in_beam} point(s) with the detector in the beam left out")
    lobe = lobe_of(spec)
    if lobe is not None:
        adds = (f"{lobe.points} polarimetric geometries (the same [polarimetry] at each)"
                if spec.polarimetry is not None else f"{lobe.points} points")
        print(f"  this is the first pass of a two-pass lobe plan: `scatterlab run` fits it "
              f"and adds {adds} placed by Fisher information (a second run)")
        from instrument.plans.lobe import reference_filter

        ref = reference_filter(spec, profile)
        if ref is not None:
            print(f"  the lobe is fitted at {ref.describe()}; the second pass reads every "
                  "filter")
    for role, dist in est.travel.items():
        unit = "mm" if role == "camera_z" else "deg"
        print(f"  travel {role:<15} {dist:10.1f} {unit}")
    homing = sum(est.homing_s.values())
    assert est.bench_motion_s is not None and est.bench_acquisition_s is not None  # estimate()
    print(f"  estimated duration on this bench {fmt_s(est.total_s)} (motion "
          f"{fmt_s(est.bench_motion_s)}, acquisition and storage "
          f"{fmt_s(est.bench_acquisition_s)})"
          + (f", and {fmt_s(homing)} before it to home axes not homed yet" if homing else ""))
    for what in est.assumed:
        print(f"  warning: {what}; set it in the bench profile for a true estimate")
    for what in est.predicted:
        print(f"  includes {what}")
    if est.speedup > 1.001:
        print(f"  its emulated stages run {est.speedup:.3g}× faster than real ones: on real "
              f"stages at the profile's speeds the motion alone takes {fmt_s(est.motion_s)}")
    if spec.order == "optimised" and plan.axes:
        raster = build_plan(replace(spec, order="raster"), profile).estimate()
        if raster.motion_s > 0:
            print(f"  naive raster order would need motion {fmt_s(raster.motion_s)} "
                  f"({est.motion_s / raster.motion_s:.0%} of it used here)")
    acq = json.loads(spec.acquisition.as_json())
    print("  acquisition: " + ", ".join(f"{k} {_value(v)}" for k, v in acq.items()))
    if spec.polarimetry is not None:
        _print_polarimetry(spec, profile)
        # the front sweeps the DRR's steps per geometry; a PEM plan has fixed settings
        if spec.polarimetry["mode"] != "pem" and _print_polarimetric_front(
                spec, profile, tradeoff_path(args)) != 0:
            return 2
    if any(p.angles is not None for p in plan.points):
        from instrument.plans.coverage import write_coverage_png

        png = coverage_path(args)
        try:
            png.parent.mkdir(parents=True, exist_ok=True)
            write_coverage_png(plan, png)
        except OSError as err:
            option = "--png" if args.png else "--out"
            print(f"error: {option}: cannot write {png} ({err.strerror or err})",
                  file=sys.stderr)
            return 2
        print(f"  coverage picture: {png}")
    else:  # light-field, sphere and calibration plans sample no scattering directions
        print("  coverage picture: none (this plan samples no scattering directions)")
    return 0


def _print_polarimetry(spec: PlanSpec, profile: BenchProfile) -> None:
    """The dual-rotating-retarder scan: its steps, and how well its instrument matrix is
    conditioned with the profile's nominal retardances (a warning far from the optimum)."""
    from instrument.plans.build import plan_filter_wavelengths
    from instrument.plans.polarimetry import FAR_FROM_OPTIMUM, conditioning, plan_wavelengths

    pol = spec.polarimetry
    assert pol is not None
    wavelengths = plan_wavelengths(profile, plan_filter_wavelengths(spec, profile))
    if pol["mode"] == "pem":
        from instrument.plans.polarimetry_pem import pem_conditioning

        n = len(pol["generator_deg"]) * len(pol["analyser_deg"])
        gen, ana = ("/".join(f"{x:g}" for x in pol[k]) for k in ("generator_deg",
                                                                   "analyser_deg"))
        print(f"  polarimetry: photoelastic modulator, {n} settings per geometry (source "
              f"polariser {gen}° × analyser retarder {ana}°), DC on Aux In 1, 1f and 2f after "
              f"{pol['time_constants']:g} τ, {pol['reads']} snapshots each")
        for pc in pem_conditioning(pol, profile, wavelengths):
            print(f"    {pc.describe()}")
        return
    print(f"  polarimetry: dual rotating retarder, {pol['steps']} steps per geometry, "
          f"ratio {pol['ratio']:g}")
    for c in conditioning(pol, profile, wavelengths):
        print(f"    {c.describe()}")
        if c.far_from_optimum:
            print(f"  warning: κ is more than {FAR_FROM_OPTIMUM:g}× the optimum's: the "
                  f"Mueller elements' σ grows with it; retarders of about "
                  f"{c.optimum_retardance_deg:g}° would do better")


def _print_polarimetric_front(spec: PlanSpec, profile: BenchProfile, png: Path) -> int:
    """The speed/accuracy trade of the steps per geometry (the Pareto front of the mean σ
    of the normalised elements against the duration) and its picture; 2 when the picture
    cannot be written."""
    from instrument.bench.meter_noise import meter_noise
    from instrument.plans.pareto_plot import write_polarimetric_tradeoff_png
    from instrument.plans.polarimetric_tradeoff import (
        TYPICAL_READING_W,
        plan_candidates,
        polarimetric_sweep,
    )
    from instrument.plans.tradeoff import pareto_front

    pol = spec.polarimetry
    assert pol is not None
    results = polarimetric_sweep(spec, profile, plan_candidates(spec))
    noise = meter_noise(tomllib.loads(profile.source_text) if profile.source_text else {})
    floor = "" if noise.floor_w is None else (
        f" and a floor of {noise.floor_w:.2g} W against {TYPICAL_READING_W:.0e} W readings")
    print(f"  speed against accuracy (σ of m_ij/m00 predicted for a non-depolarising "
          f"sample, readings' noise {noise.source}{floor}); the Pareto front:")
    print(f"    {'steps':>5}  {'points':>6}  {'duration':>9}  {'κ':>5}  {'σ mean':>8}  "
          f"{'σ worst':>8}")
    for r in pareto_front(results, "sigma_mean"):
        mine = "  ← this plan" if r.option.steps == int(pol["steps"]) else ""
        print(f"    {r.option.steps:5d}  {r.n_points:6d}  {fmt_s(r.duration_s):>9}  "
              f"{r.kappa:5.3g}  {r.sigma['sigma_mean']:8.2g}  {r.sigma['sigma_max']:8.2g}"
              f"{mine}")
    try:
        write_polarimetric_tradeoff_png(results, png, chosen=int(pol["steps"]), title=(
            f"{spec.name} on {profile.name}: dual rotating retarder, speed against "
            "accuracy"))
    except OSError as err:
        print(f"error: cannot write the trade-off picture {png} ({err})", file=sys.stderr)
        return 2
    print(f"  trade-off picture: {png}")
    return 0
