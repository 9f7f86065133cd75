"""``scatterlab calibrate camera RUN``: a photon-transfer run → the camera calibration.

Evaluates a ``photon_transfer`` run (pairs of frames of a uniform target over an exposure
sweep, dark pairs at the same exposures) after EMVA 1288 Release 4.0 Linear
(:mod:`analysis.emva1288`) and writes the camera-calibration JSON that ``scatterlab fit
--camera-calibration`` reads, with every EMVA number and its standard uncertainty under
``"emva1288"``, and the report figure (photon transfer and linearity). By default both go
into ``DIR/RUN/camera/`` next to the run file ``DIR/RUN.h5``; ``-o`` names the JSON file
(the figure goes beside it). The run file is only read.

The quantum efficiency needs the sweep's photon count per pixel, which only a calibrated
photodiode in the sensor plane gives (``--photons-per-pixel-s``); otherwise give the data
sheet's η with ``--quantum-efficiency``. For a simulated camera the lens and wavelength
default to the simulator's; for a real one ``--wavelength-nm`` and ``--pupil-diameter-mm``
are needed.

Exit status: 0 written, 2 on errors.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from instrument.run.runfile import RunData

HELP = "camera characterization (EMVA 1288) from a photon-transfer run"

#: File names in the output folder.
CALIBRATION_NAME = "camera_calibration.json"
FIGURE_NAME = "emva1288.png"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("calibrate", help=HELP)
    what = p.add_subparsers(dest="target", metavar="TARGET")
    what.required = True
    c = what.add_parser("camera", help="EMVA 1288 camera calibration from a photon_transfer "
                        "run (examples/calibration_ptc.toml)")
    c.add_argument("run", help="run file (.h5) of a photon_transfer plan")
    c.add_argument("-o", "--output", default=None,
                   help="calibration JSON to write (default: RUN/camera/"
                   f"{CALIBRATION_NAME} next to the run file RUN.h5)")
    c.add_argument("--no-figure", action="store_true", help="draw no report figure")
    c.add_argument("--photons-per-pixel-s", type=float, default=None,
                   help="photons per second reaching one pixel during the sweep (a "
                   "calibrated photodiode in the sensor plane): measures η")
    c.add_argument("--photons-u", type=float, default=0.0,
                   help="relative standard uncertainty of --photons-per-pixel-s")
    c.add_argument("--quantum-efficiency", type=float, default=None,
                   help="η from the data sheet, when the photon count is unknown")
    c.add_argument("--quantum-efficiency-u", type=float, default=None,
                   help="standard uncertainty of --quantum-efficiency (absolute)")
    c.add_argument("--wavelength-nm", type=float, default=None,
                   help="wavelength of the sweep's light (default for a simulated camera: "
                   "the simulated source's)")
    c.add_argument("--pupil-diameter-mm", type=float, default=None,
                   help="entrance-pupil diameter of the lens used for BRDF runs")
    c.add_argument("--pixel-pitch-um", type=float, default=None, help="pixel pitch (µm)")
    c.add_argument("--focal-length-mm", type=float, default=None, help="focal length (mm)")
    c.add_argument("--bootstrap", type=int, default=400,
                   help="parametric bootstrap draws for the uncertainties (default 400)")
    c.set_defaults(func=run)
    from instrument.cli._calibrate_polarimeter import register_polarimeter

    register_polarimeter(what)


def _option_error(args: argparse.Namespace) -> str | None:
    checks = (("--photons-per-pixel-s", args.photons_per_pixel_s, False),
              ("--quantum-efficiency", args.quantum_efficiency, False),
              ("--wavelength-nm", args.wavelength_nm, False),
              ("--pupil-diameter-mm", args.pupil_diameter_mm, False),
              ("--pixel-pitch-um", args.pixel_pitch_um, False),
              ("--focal-length-mm", args.focal_length_mm, False),
              ("--photons-u", args.photons_u, True),
              ("--quantum-efficiency-u", args.quantum_efficiency_u, True))
    for name, value, zero_ok in checks:
        if value is not None and not (value >= 0 if zero_ok else value > 0):
            return f"{name} must be {'≥' if zero_ok else '>'} 0 (got {value:g})"
    if args.quantum_efficiency is not None and args.quantum_efficiency > 1:
        return f"--quantum-efficiency must lie in (0, 1] (got {args.quantum_efficiency:g})"
    if args.bootstrap < 50:
        return f"--bootstrap must be ≥ 50 (got {args.bootstrap})"
    return None


def _settings(data: RunData) -> dict[str, Any]:
    """The camera's gain and pixel format during the sweep as the run recorded them (None:
    not recorded; the calibration holds for these settings only), and its identity."""
    cam = data.identities.get("camera", {})
    return {"gain_db": data.camera_gain(), "pixel_format": cam.get("pixel_format"),
            "camera": " ".join(str(cam[k]) for k in ("vendor", "model", "serial") if k in cam)}


def run(args: argparse.Namespace) -> int:
    from instrument.pipelines.camera.characterize import (
        calibration_json,
        characterize_run,
        optics_for,
        write_calibration,
    )
    from instrument.pipelines.camera.report import characterization_figure
    from instrument.run.paths import run_folder
    from instrument.run.runfile import check_run_file, read_run

    problem = _option_error(args)
    if problem:
        print(f"error: {problem}")
        return 2
    try:
        check_run_file(args.run, kinds=("photon_transfer",))
        data = read_run(args.run)
        res = characterize_run(data, photons_per_pixel_per_s=args.photons_per_pixel_s,
                               u_photons_rel=args.photons_u, n_bootstrap=args.bootstrap)
        optics = optics_for(data, wavelength_nm=args.wavelength_nm,
                            pupil_diameter_mm=args.pupil_diameter_mm,
                            pixel_pitch_um=args.pixel_pitch_um,
                            focal_length_mm=args.focal_length_mm)
        content = calibration_json(res, optics, quantum_efficiency=args.quantum_efficiency,
                                   u_quantum_efficiency=args.quantum_efficiency_u,
                                   source=f"scatterlab calibrate camera {data.path.name}",
                                   settings=_settings(data))
        out = (Path(args.output) if args.output
               else run_folder(args.run) / "camera" / CALIBRATION_NAME)
        written = write_calibration(content, out)
        fig = None if args.no_figure else characterization_figure(
            res, out.with_name(out.stem + "_" + FIGURE_NAME) if args.output
            else out.with_name(FIGURE_NAME), title=f"{data.run_id}: EMVA 1288")
    except (ValueError, OSError, KeyError) as err:
        print(f"error: {err}")
        return 2
    e = content["emva1288"]

    def line(name: str, key: str, unit: str, scale: float = 1.0) -> str:
        v, u = e[key]
        return f"  {name:<28} {v * scale:.5g} ± {u * scale:.2g} {unit}"

    print(f"{data.run_id}: EMVA 1288 R4.0 evaluation of {e['exposures']} exposures, "
          f"{e['pixels']} pixels (standard uncertainties, k = 1)")
    print(line("system gain K", "system_gain_dn_per_e", "DN/e⁻"))
    print(line("dark noise σ_d", "dark_noise_e", "e⁻") + f" ({e['dark_noise_dn']:.3g} DN)")
    print(line("saturation μ_y.sat", "saturation_dn", "DN"))
    print(line("saturation capacity μ_e.sat", "saturation_capacity_e", "e⁻"))
    print(line("linearity error LE", "linearity_error_percent", "%")
          + f" (less its noise floor: {e['linearity_error_unbiased_percent']:.2g} %)")
    print(line("dark current", "dark_current_e_per_s", "e⁻/s"))
    print(line("DSNU", "dsnu_e", "e⁻"))
    print(line("PRNU", "prnu_rel", "%", 100.0))
    qe, u_qe = e["quantum_efficiency"]
    print(f"  {'quantum efficiency η':<28} {qe:.5g}"
          + (f" ± {u_qe:.2g}" if u_qe is not None else "") + f", {e['quantum_efficiency_from']}")
    for w in e["warnings"]:
        print(f"warning: {w}")
    print(f"calibration: {written}")
    if fig is not None:
        print(f"report: {fig}")
    return 0
