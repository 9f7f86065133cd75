"""The localisation's two ways of taking the candidates' models give the same objects.

``detect_objects(sample_plan=True)`` (the default) sums each candidate's point-response
stacks through the sample plan laid out once per detection (sparse products,
:class:`analysis.lightfield.wall_samples.SamplePlan`); ``sample_plan=False`` sums them over
the rays' runs, the path before it.  On the validation matrix's cheap cells
(``bench_lightfield_validation.py``'s renders, noise, reconstruction and widened search:
matte, glossy and brushed walls × one object and two objects a blur apart, and the
ratio-100 pair) at a few seeds, both paths run on the same reconstruction and are compared:
the same count, flags and notes, positions within 0.25 blur, significance within 0.1σ (the
criterion), and the largest differences seen (rounding: the sums differ only in the order
of their additions).  CPU of each path per scan is printed too.

Run: ``python benchmarks/bench_locate_paths.py`` (``--seeds N``, ``--walls``, ``--scenes``,
``--cache DIR`` for the renders).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from bench_lightfield_validation import (
    D2,
    NOISE,
    WALL_POINTS,
    Y_GRID,
    Z_GRID,
    render,
    scenes,
    wall_blur,
    walls,
)

from analysis.lightfield import detect_widening, effective_p_max, reconstruct

WALLS = ("coated_paper_matte", "coated_paper_glossy", "brushed_metal")
SCENES = ("one", "pair_1blur", "ratio_100")


def both_paths(lf, brdf, seed: int):
    """The detections of one seeded scan by the plan and by the runs, and their CPU s."""
    rng = np.random.default_rng(seed)
    noisy = lf.with_radiance(lf.radiance + rng.normal(0.0, NOISE, lf.shape))
    rec = reconstruct(noisy, brdf, d2_mm=D2, points_mm=WALL_POINTS)
    opts = dict(z_mm=Z_GRID, y_mm=Y_GRID,
                p_max=effective_p_max(rec.regularization.filter_factors, rec.orders),
                solvable_domain_rad=rec.solvable_domain_rad,
                filter_factors=rec.regularization.filter_factors,
                noise_power=rec.regularization.noise_power, min_measure_fraction=0.1)
    out = []
    for plan in (True, False):
        t0 = time.process_time()
        det, _ = detect_widening(rec.incident_field, sample_plan=plan, **opts)
        out.append((det, time.process_time() - t0))
    return out


def compare(new, old) -> tuple[bool, float, float]:
    """Same objects by the criterion (count, flags, candidates below, positions within
    0.25 blur, significance within 0.1σ); the largest position difference (in blurs) and
    significance difference (σ), objects and candidates below together.  The notes are
    compared apart (:func:`main`): their wording can follow a tie that rounding decides."""
    same = (new.count == old.count and new.quality == old.quality
            and new.below_significance.size == old.below_significance.size)
    if not same:
        return False, float("inf"), float("inf")
    blur = np.asarray([r.transverse_mm for r in new.resolutions])
    d_pos = np.abs(new.positions_mm - old.positions_mm).max(axis=1) / blur if new.count else []
    d_below = np.abs(new.below_positions_mm - old.below_positions_mm)
    pos = float(max(np.max(d_pos, initial=0.0), np.max(d_below, initial=0.0) / blur.min()
                    if blur.size else 0.0))
    sig = float(max(np.max(np.abs(new.significance - old.significance), initial=0.0),
                    np.max(np.abs(new.below_significance - old.below_significance),
                           initial=0.0)))
    return same and pos <= 0.25 and sig <= 0.1, pos, sig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--walls", nargs="*", default=list(WALLS))
    ap.add_argument("--scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--cache", type=Path, default=None, help="folder for the renders")
    args = ap.parse_args()
    all_walls = walls()
    agree = total = 0
    cpu = [0.0, 0.0]
    print("wall | scene | seed | objects | below | same objects | same notes | Δpos (blur) | Δσ "
          "| CPU plan/runs s")
    for wname in args.walls:
        brdf = all_walls[wname]
        cells = scenes(wall_blur(brdf, args.cache, wname))
        for sname in args.scenes:
            lf = render(brdf, cells[sname], args.cache, f"{wname}__{sname}")
            for seed in range(1, args.seeds + 1):
                (new, t_new), (old, t_old) = both_paths(lf, brdf, seed)
                ok, pos, sig = compare(new, old)
                agree += ok
                total += 1
                cpu[0] += t_new
                cpu[1] += t_old
                print(f"{wname} | {sname} | {seed} | {new.count}/{old.count} | "
                      f"{new.below_significance.size}/{old.below_significance.size} | "
                      f"{'yes' if ok else 'NO'} | "
                      f"{'yes' if new.notes == old.notes else 'NO'} | {pos:.1e} | {sig:.1e} | "
                      f"{t_new:.1f}/{t_old:.1f}", flush=True)
    print(f"same objects in {agree} of {total} scans; CPU plan {cpu[0]:.1f} s, runs "
          f"{cpu[1]:.1f} s")


if __name__ == "__main__":
    main()
