"""Localisation validation matrix: detection, false alarms, position errors, confident errors.

Scenes rendered by the continuous renderer (``hw_mocks.sim.lightfield_scene``: exact disc
geometry, quadrature over the BRDF) behind 200 mm of wall at d2 = 100 mm, with seeded
Gaussian noise of a fixed level (2·10⁻⁴, the brightest object's measured radiance is
≈ 0.1–0.4), reconstructed (Wiener, noise from the data) and located with the reconstruction's
noise model at the default false-alarm probability (0.01 per scan), the depth range widened
while an object sits at its far edge (:func:`analysis.lightfield.detect_widening`).

Matrix: walls (the thesis materials plus narrower lobes of the brushed metal) × scenes:
one object inside the default range (−400 … −60 mm); one beyond it (−600 mm); two at
0.5, 1 and 2 transverse blurs apart at equal brightness; two 40 mm apart at brightness
ratios 10, 100 and 1000.  Each scene × wall × seed is scored:

* detected — a true object with a reported object within δy across whose depth interval
  holds it;
* phantom — a reported object that explains no true object;
* position within blur — a detected object within δy across and δz in depth;
* confidently wrong — a reported object marked "resolved" that is a phantom, a split (more
  reported objects explaining the true ones than there are), or with a brightness ≤ 0 (an
  interval excluding the truth makes the object a phantom or undetected);
* false alarm per scan — a scan with at least one phantom.

Run: ``python benchmarks/bench_lightfield_validation.py`` (reduced: 2 seeds, 3 walls);
``--seeds N --walls all`` for more.  Its failure cases (a phantom at a lowered threshold, a
dim object beside a bright one, an object beyond the range) run in CI as
``tests/analysis/lightfield/test_localize_significance.py``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np

from analysis.lightfield import (
    FlatlandBRDF,
    detect_widening,
    effective_p_max,
    material,
    reconstruct,
    theoretical_resolution,
)
from hw_mocks.sim.lightfield_scene import HiddenScene, PointObject, Wall

DOMAIN = (-0.6, 0.6)
NOISE = 2e-4
WALL_POINTS = np.arange(-100.0, 100.1, 1.0)
Y_GRID = np.arange(-90.0, 90.1, 2.0)
Z_GRID = np.arange(-400.0, -59.0, 4.0)


def walls(which: str) -> dict[str, FlatlandBRDF]:
    """The walls of the matrix: reduced (brushed metal, 0.5° lobe, glossy paper) or all."""
    base = material("brushed_metal")
    narrow = FlatlandBRDF(base.specular_reflectance, np.deg2rad(0.5), base.diffuse_reflectance,
                          0.0, "brushed_metal_0.5deg")
    out = {"brushed_metal": base, "brushed_metal_0.5deg": narrow,
           "coated_paper_glossy": material("coated_paper_glossy")}
    if which == "all":
        out["coated_paper_matte"] = material("coated_paper_matte")
    return out


def scenes(brdf: FlatlandBRDF) -> dict[str, list[PointObject]]:
    """The scenes; pair separations in units of the transverse blur at −200 mm (p̂ ≈ 16)."""
    blur = theoretical_resolution(16, domain_rad=DOMAIN, distance_mm=200.0,
                                  aperture_mm=200.0).transverse_mm
    out = {"one": [PointObject(0.0, -200.0, 1.5, 1.0)],
           "beyond": [PointObject(10.0, -600.0, 1.5, 1.0)]}
    for f in (0.5, 1.0, 2.0):
        out[f"pair_{f:g}blur"] = [PointObject(-0.5 * f * blur, -200.0, 1.5, 1.0),
                                  PointObject(0.5 * f * blur, -200.0, 1.5, 1.0)]
    for ratio in (10, 100, 1000):
        out[f"ratio_{ratio}"] = [PointObject(-20.0, -200.0, 1.5, 1.0),
                                 PointObject(20.0, -220.0, 1.5, 1.0 / ratio)]
    return out


@dataclass
class Score:
    truths: int = 0
    detected: int = 0
    within_blur: int = 0
    phantoms: int = 0
    scans_with_phantom: int = 0
    confidently_wrong: int = 0
    scans: int = 0
    seconds: float = 0.0


def score(det, objects, s: Score) -> None:
    """Add one scan's outcome to ``s`` (module doc)."""
    explains = np.zeros((det.count, len(objects)), dtype=bool)
    for k in range(det.count):
        r = det.resolutions[k]
        far, near = det.depth_interval_mm[k]
        extent = det.extent_mm[k, 0] if det.extent_mm.size else 0.0
        for j, o in enumerate(objects):
            explains[k, j] = (abs(det.positions_mm[k, 0] - o.y_mm) < r.transverse_mm + extent
                              and far <= o.z_mm <= near)
    s.scans += 1
    s.truths += len(objects)
    for j, o in enumerate(objects):
        hits = np.nonzero(explains[:, j])[0]
        if hits.size:
            s.detected += 1
            k = int(hits[0])
            r = det.resolutions[k]
            if (abs(det.positions_mm[k, 0] - o.y_mm) < r.transverse_mm
                    and abs(det.positions_mm[k, 1] - o.z_mm) < r.depth_mm):
                s.within_blur += 1
    # a split: more reported objects explain the true ones than there are, marked resolved
    explaining = np.nonzero(explains.any(axis=1))[0]
    extra = explaining.size - len(objects)
    if extra > 0:
        s.confidently_wrong += min(extra, sum(det.quality[k] == "resolved" for k in explaining))
    phantom = ~explains.any(axis=1)
    s.phantoms += int(phantom.sum())
    s.scans_with_phantom += int(phantom.any())
    for k in range(det.count):
        if det.quality[k] != "resolved":
            continue
        if phantom[k] or det.brightness_rp[k] <= 0:
            s.confidently_wrong += 1


def run_one(brdf: FlatlandBRDF, objects: list[PointObject], seed: int):
    scene = HiddenScene(tuple(objects), Wall(-150.0, 150.0, brdf), d2_mm=100.0)
    lf = scene.measured_field(np.linspace(-180.0, 180.0, 361), DOMAIN, 128)
    rng = np.random.default_rng(seed)
    noisy = lf.with_radiance(lf.radiance + rng.normal(0.0, NOISE, lf.shape))
    rec = reconstruct(noisy, brdf, d2_mm=100.0, points_mm=WALL_POINTS)
    det, _ = detect_widening(
        rec.incident_field, z_mm=Z_GRID, y_mm=Y_GRID,
        p_max=effective_p_max(rec.regularization.filter_factors, rec.orders),
        solvable_domain_rad=rec.solvable_domain_rad,
        filter_factors=rec.regularization.filter_factors,
        noise_power=rec.regularization.noise_power, min_measure_fraction=0.1)
    return det


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--walls", choices=("reduced", "all"), default="reduced")
    ap.add_argument("--scenes", nargs="*", default=None, help="scene names (default all)")
    ap.add_argument("--only-walls", nargs="*", default=None,
                    help="wall names of the chosen set to run (default all of them)")
    args = ap.parse_args()
    total = Score()
    print("| wall | scene | truths | detected | within blur | phantoms | scans w/ phantom "
          "| confidently wrong | s/scan |")
    print("|---|---|---|---|---|---|---|---|---|")
    for wname, brdf in walls(args.walls).items():
        if args.only_walls and wname not in args.only_walls:
            continue
        for sname, objects in scenes(brdf).items():
            if args.scenes and sname not in args.scenes:
                continue
            s = Score()
            for seed in range(1, args.seeds + 1):
                t0 = time.process_time()
                det = run_one(brdf, objects, seed)
                s.seconds += time.process_time() - t0
                score(det, objects, s)
            for f in ("truths", "detected", "within_blur", "phantoms", "scans_with_phantom",
                      "confidently_wrong", "scans", "seconds"):
                setattr(total, f, getattr(total, f) + getattr(s, f))
            print(f"| {wname} | {sname} | {s.truths} | {s.detected} | {s.within_blur} | "
                  f"{s.phantoms} | {s.scans_with_phantom}/{s.scans} | {s.confidently_wrong} | "
                  f"{s.seconds / s.scans:.1f} |", flush=True)
    print(f"\ntotal: {total.detected}/{total.truths} detected, {total.within_blur} within the "
          f"blur, {total.phantoms} phantoms in {total.scans_with_phantom}/{total.scans} scans, "
          f"{total.confidently_wrong} confidently wrong; CPU {total.seconds:.0f} s")


if __name__ == "__main__":
    main()
