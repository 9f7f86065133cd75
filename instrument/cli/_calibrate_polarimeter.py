"""``scatterlab calibrate polarimeter --bench BENCH``: reference scans → the polarimeter
calibration that ``scatterlab fit`` uses for polarimetric runs.

Runs one dual-rotating-retarder scan per reference sample with the detector arm in the
straight-through beam (detector_theta 180°): air (no sample), a linear polariser at each
``--polariser-deg`` azimuth and a retarder at ``--retarder-deg``; then fits the five
instrument parameters (:mod:`instrument.pipelines.polarimetry.references`) and writes the
calibration JSON into ``OUT/calibrations/`` (:mod:`instrument.pipelines.polarimetry.
calibration`), where ``fit`` finds it for runs in ``OUT``.

On a simulated bench the reference is put in the beam by the bench's simulation: each
scan uses the profile with its ``[simulation.scene]`` replaced by the reference, and the
emulated detector-arm controller's software limit opened to reach 180°. A real bench needs
an operator to place each reference; this version automates the simulated benches only.

On a PEM bench (a ``kind = "pem"`` element in the source arm) each reference is a PEM
run (``[polarimetry] mode = "pem"``, the lock-in read at its 2 × 4 settings) and the fit is
the PEM train's (ADR 0113); the simulated straight-through beam is attenuated to 1 µW, as
a calibration stand's neutral density keeps the photodiode within the lock-in's range.

Exit status: 0 written (valid), 1 written but failing its quality gate, 2 on errors.
"""

from __future__ import annotations

import argparse
import re
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from instrument.bench.profile import BenchProfile

HELP_POLARIMETER = ("polarimeter calibration from straight-through reference scans (air, "
                    "polarisers, a retarder) on a polarimetric bench")

#: The base plan of a reference scan: one position, then moved straight through.
_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "polarimeter reference: {name}"
order = "raster"

[sample]
name = "{name}"

[scan]
theta_i = [10.0]
theta_r = [10.0]

[acquisition]
detectors = ["power_meter"]
dark = "per_point"

[polarimetry]
mode = "drr"
steps = {steps}
"""

#: ... on a PEM bench: the lock-in at the default settings.
_PEM_POLARIMETRY = """
[acquisition]
detectors = ["lockin"]

[polarimetry]
mode = "pem"
"""

#: The simulated source power of a PEM reference scan (W): 1 mW straight through would
#: read 400 V at the photodiode's 0.4 A/W × 1 MΩ; 1 µW reads 0.4 V.
PEM_REFERENCE_POWER_W = 1e-6


def is_pem_bench(profile: BenchProfile) -> bool:
    """Whether the bench's polarimeter is a PEM's (a modulator in its source arm)."""
    return profile.optics is not None and any(e.kind == "pem" for e in profile.optics.source)


def register_polarimeter(what: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    c = what.add_parser("polarimeter", help=HELP_POLARIMETER)
    c.add_argument("--bench", required=True,
                   help="polarimetric bench profile (name or file), e.g. sim-polarimetric")
    c.add_argument("--out", default="runs",
                   help="folder of the reference runs; the calibration goes into "
                   "OUT/calibrations/ (default: runs)")
    c.add_argument("--steps", type=int, default=36,
                   help="retarder steps per reference scan (25 or more; default 36; a PEM "
                   "bench takes its 2 × 4 settings)")
    c.add_argument("--polariser-deg", default="0,45",
                   help="azimuths of the linear-polariser references (default 0,45)")
    c.add_argument("--retarder-deg", type=float, default=30.0,
                   help="fast-axis azimuth of the quarter-wave retarder reference "
                   "(default 30)")
    c.add_argument("--no-fsync", action="store_true",
                   help="do not fsync the reference runs (tests, throw-away runs)")
    c.set_defaults(func=run_polarimeter)


def _simulated_reference(profile_text: str, kind: str, angle: float, pem: bool = False
                         ) -> str:
    """The profile with its scene replaced by a reference and the detector arm's emulated
    controller opened to the straight-through position."""
    cut = re.search(r"^\[simulation\.scene(\.[^\]]*)?\]", profile_text, re.MULTILINE)
    body = profile_text if cut is None else profile_text[:cut.start()]
    # any later [simulation.*] tables after the scene's (kept)
    if cut is not None:
        rest = profile_text[cut.start():]
        later = [m.start() for m in re.finditer(r"^\[(?!simulation\.scene)[^\]]+\]", rest,
                                                re.MULTILINE)]
        if later:
            body += rest[later[0]:] + "\n"
    # an ideal reference polariser: the calibration models it so (a leak of 1e-5 is tens
    # of σ at the crossed steps of a straight-through scan, whose dynamic range is 1e7)
    table = {"air": "", "polariser": f"orientation_deg = {angle}\n",
             "retarder": f"orientation_deg = {angle}\nretardance_deg = 90.0\n"}[kind]
    body = re.sub(r"(simsmc://detector_theta)\?", r"\1_straight?sr=181&", body)
    body = re.sub(r'(\[devices\.detector_theta\][^\[]*?limits = \[)([-\d.]+), [-\d.]+\]',
                  r"\1\2, 181.0]", body, flags=re.DOTALL)
    if pem:
        body = re.sub(r"(\[simulation\.source\][^\[]*?power_w = )[-+.\deE]+",
                      rf"\g<1>{PEM_REFERENCE_POWER_W:g}", body, flags=re.DOTALL)
    scene = f'\n[simulation.scene]\nkind = "polarimetric"\nsample = "{kind}"\n'
    if table:
        scene += f"\n[simulation.scene.{kind}]\n{table}"
    return body + scene


def _reference_run(profile: BenchProfile, kind: str, angle: float, args: argparse.Namespace
                   ) -> Path:
    from instrument.bench.devices import open_bench
    from instrument.bench.profile import load_profile
    from instrument.cli.run import drive
    from instrument.plans import build_plan
    from instrument.plans.planfile import parse_plan
    from instrument.run.runner import start_run

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    name = kind if kind == "air" else f"{kind} {angle:g}°"
    ref_profile = out / f".{profile.name}-{kind}-{angle:g}.toml"
    pem = is_pem_bench(profile)
    ref_profile.write_text(_simulated_reference(profile.source_text, kind, angle, pem),
                           encoding="utf-8")
    prof = load_profile(ref_profile)
    text = _PLAN.format(name=name, steps=args.steps)
    if pem:
        text = text[:text.index("[acquisition]")] + _PEM_POLARIMETRY
    plan = build_plan(parse_plan(text), prof)
    straight = {"detector_theta": 180.0, "sample_theta": 0.0}
    plan = replace(plan, points=tuple(
        replace(p, targets=tuple((r, straight.get(r, v)) for r, v in p.targets))
        for p in plan.points))
    with open_bench(prof) as bench:
        engine = start_run(plan, bench, runs_dir=out, fsync=not args.no_fsync)
        if drive(engine, True) != 0:
            raise RuntimeError(f"the {name} reference scan did not finish: "
                               f"{engine.store.path}")
        return Path(engine.store.path)


def run_polarimeter(args: argparse.Namespace) -> int:
    from instrument.bench.profile import load_profile
    from instrument.pipelines.polarimetry.calibration import (
        calibration_folder,
        save_calibration,
    )
    from instrument.pipelines.polarimetry.references import ReferenceRun, calibrate_from_runs

    try:
        profile = load_profile(args.bench)
        polarisers = [float(v) for v in str(args.polariser_deg).split(",") if v.strip()]
    except ValueError as err:
        print(f"error: {err}")
        return 2
    if args.steps < 25 and not is_pem_bench(profile):
        print(f"error: --steps must be ≥ 25 (fewer equal steps alias), got {args.steps}")
        return 2
    simulated = re.search(r"^\[simulation\.scene\]", profile.source_text, re.MULTILINE)
    if profile.optics is None or simulated is None:
        print(f"error: bench {profile.name!r} is not a simulated polarimetric bench (an "
              "[optics] train and a [simulation.scene]): the reference scans are automated "
              "on simulated benches only (a real bench needs each reference placed by hand)")
        return 2
    refs = [("air", 0.0), *(("polariser", a) for a in polarisers),
            ("retarder", float(args.retarder_deg))]
    runs = []
    try:
        for kind, angle in refs:
            print(f"reference scan: {kind}" + ("" if kind == "air" else f" at {angle:g}°"))
            path = _reference_run(profile, kind, angle, args)
            runs.append(ReferenceRun(path, kind, angle, 90.0))
        cal = calibrate_from_runs(runs, bench=profile.name)
    except (ValueError, RuntimeError) as err:
        print(f"error: {err}")
        return 2
    path = save_calibration(cal, calibration_folder(args.out))
    cal = replace(cal, path=path)
    print(f"polarimeter calibration of {profile.name}: {cal.describe()}")
    verdict = "valid" if cal.valid else "NOT valid: fit will not pick it up"
    print(f"  quality: {cal.quality} ({verdict})")
    print(f"calibration: {path}")
    return 0 if cal.valid else 1
