"""The example light-field scan's auto-exposure on the built-in walls, and its estimate.

For each wall — the four thesis materials (``analysis.lightfield.MATERIALS``) and near-mirror
walls of specular width 0.3°, 0.1°, 0.01° and 0.001° (ρ_s = 0.6, ρ_d = 0.08) — the built-in
``sim-lightfield`` bench with that wall runs ``examples/lightfield_scan.toml`` as written
(auto-exposure; a dark frame at the start and one at each other exposure chosen) and, for
comparison, the same plan at its fixed 5000 µs.  Reported: ``scatterlab plan``'s estimate
and the run's wall time (their ratio), the lit frames stored and how many of them are
saturated, the exposures chosen, and ``locate``'s object nearest the disc (position, blur,
brightness) against the truth (−8, −200) mm.

Run: ``python benchmarks/bench_lightfield_exposure.py`` (``--walls brushed_metal 0.01`` for
some; ``--no-fixed`` leaves out the fixed-exposure runs).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from bench_lightfield_scan import timed_run  # sibling benchmark module

from drivers.transport import add_url_handler_package
from hw_mocks import registry
from hw_mocks.sim.world import reset_worlds
from instrument.bench.profile import load_profile
from instrument.pipelines.lightfield.locate import locate_run
from instrument.plans import build_plan, load_plan
from instrument.run.runfile import read_run

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "instrument" / "bench" / "profiles" / "sim-lightfield.toml"
PLAN = ROOT / "examples" / "lightfield_scan.toml"
TRUTH = (-8.0, -200.0)
MATERIAL_WALLS = ("brushed_metal", "coated_paper_glossy", "coated_paper_matte",
                  "pearl_paint_glass")
MIRROR_WIDTHS_DEG = (0.3, 0.1, 0.01, 0.001)


def wall_profile(wall: str, folder: Path) -> Path:
    """The sim-lightfield profile with ``wall``: a material name or a width in degrees."""
    text = PROFILE.read_text()
    if wall in MATERIAL_WALLS:
        text = text.replace('material = "brushed_metal"', f'material = "{wall}"')
    else:
        text = text.replace('material = "brushed_metal"',
                            "brdf = { specular_reflectance = 0.6, specular_width_deg = "
                            f"{float(wall)}, diffuse_reflectance = 0.08 }}")
    out = folder / f"sim-lightfield-{wall}.toml"
    out.write_text(text)
    return out


def fixed_plan(folder: Path) -> Path:
    """The example plan at its fixed exposure (the plan before auto-exposure)."""
    text = PLAN.read_text().replace('mode = "auto"', 'mode = "fixed"')
    out = folder / "lightfield_scan_fixed.toml"
    out.write_text(text)
    return out


def estimate_s(plan: Path, profile: Path) -> float:
    """``scatterlab plan``'s estimate of the run's wall time (seconds)."""
    return build_plan(load_plan(plan), load_profile(profile)).estimate().total_s


def one(wall: str, plan: Path, folder: Path, tag: str) -> dict:
    registry.reset()
    reset_worlds()
    profile = wall_profile(wall, folder)
    est = estimate_s(plan, profile)
    run_path, wall_s = timed_run(plan, profile, folder / f"runs-{tag}-{wall}")
    run = read_run(run_path)
    lit = run.frame_light.astype(bool)
    loc = locate_run(run_path)
    det = loc.detection
    row = {"wall": wall, "tag": tag, "estimate_s": est, "run_s": wall_s,
           "lit": int(lit.sum()), "saturated": int(np.sum(run.frame_saturated[lit] > 0)),
           "exposures": sorted({float(e) for e in run.frame_exposure_us[lit]}),
           "count": det.count}
    if det.count:
        k = int(np.argmin(np.hypot(det.positions_mm[:, 0] - TRUTH[0],
                                   det.positions_mm[:, 1] - TRUTH[1])))
        r = det.resolutions[k]
        row.update(y=float(det.positions_mm[k, 0]), z=float(det.positions_mm[k, 1]),
                   res_y=r.transverse_mm, res_z=r.depth_mm,
                   brightness=float(det.brightness_rp[k]),
                   significance=float(det.significance[k]), quality=det.quality[k])
    return row


def header() -> None:
    print("| wall | plan | estimate s | run s | run/estimate | lit frames | saturated "
          "| exposures µs | disc (y, z) mm | blur δy / δz mm | brightness (σ) | quality |")
    print("|---|---|---:|---:|---:|---:|---:|---|---|---|---|---|", flush=True)


def report(rows: list[dict]) -> None:
    for r in rows:
        exps = ", ".join(f"{e:g}" for e in r["exposures"][:4])
        if len(r["exposures"]) > 4:
            exps += ", …"
        disc = (f"({r['y']:.1f}, {r['z']:.1f}) | {r['res_y']:.1f} / {r['res_z']:.1f} | "
                f"{r['brightness']:.4g} ({r['significance']:.0f}) | {r['quality']}"
                if "y" in r else "none | — | — | —")
        print(f"| {r['wall']} | {r['tag']} | {r['estimate_s']:.1f} | {r['run_s']:.1f} | "
              f"{r['run_s'] / r['estimate_s']:.2f} | {r['lit']} | {r['saturated']} | {exps} "
              f"| {disc} |", flush=True)


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walls", nargs="*",
                    default=[*MATERIAL_WALLS, *(f"{w:g}" for w in MIRROR_WIDTHS_DEG)])
    ap.add_argument("--no-fixed", action="store_true")
    args = ap.parse_args()
    add_url_handler_package("hw_mocks.urlhandler")
    header()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        fixed = fixed_plan(folder)
        for wall in args.walls:
            report([one(wall, PLAN, folder, "auto")])
            if not args.no_fixed:
                report([one(wall, fixed, folder, "fixed")])


if __name__ == "__main__":
    main_()
