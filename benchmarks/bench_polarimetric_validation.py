"""The polarimetric validation matrix over seeds: every sample's 15 normalised Mueller
elements against the hidden truth, with the calibration ``scatterlab calibrate
polarimeter`` measures and with the nominal optics.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_polarimetric_validation.py --seeds 10
    python benchmarks/bench_polarimetric_validation.py --seeds 1 --samples "air,rough metal"

Per seed (the power meter's noise seed of ``sim-polarimetric``, mounts 100× faster): the
calibration's four reference scans, then one 25-step engine run per sample
(tests/instrument/pipelines/polarimetry/validation.py: air, a polariser at 0°, 30°, 45°, a
quarter-wave plate, the dielectric at θi 20°, 50°, 70°, the rough metal, the diffuser),
each fitted with the calibration and without. Prints per sample the fraction of the
elements within 2σ, the pull spread and the largest |pull| (calibrated, uncalibrated), the
validation report's verdicts, and the dielectric's m01/m00 against Fresnel's
(Rs − Rp)/(Rs + Rp) of a flat facet, which is 1 at Brewster's angle (56.3°). ``--save``
writes the pulls (npz) after every seed, so that a run cut short keeps its numbers.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis.polarimetry.pbrdf import fresnel_mueller  # noqa: E402
from tests.instrument.pipelines.polarimetry.validation import (  # noqa: E402
    BREWSTER_DEG,
    SAMPLES,
    Outcome,
    calibrate,
    measure,
    report,
    sample,
)


def _table(outcomes: list[Outcome]) -> None:
    print("| sample | seeds | within 2σ | pull spread | max \\|pull\\| | uncalibrated: within 2σ "
          "| pull spread | max \\|pull\\| |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for s in SAMPLES:
        mine = [o for o in outcomes if o.sample == s]
        if not mine:
            continue
        c = np.concatenate([o.calibrated for o in mine])
        n = np.concatenate([o.nominal for o in mine])
        print(f"| {s.name} | {len(mine)} | {np.mean(np.abs(c) < 2):.0%} | {np.std(c):.2f} | "
              f"{np.max(np.abs(c)):.1f} | {np.mean(np.abs(n) < 2):.0%} | {np.std(n):.1f} | "
              f"{np.max(np.abs(n)):.0f} |")
    c = np.concatenate([o.calibrated for o in outcomes])
    print(f"| all | | {np.mean(np.abs(c) < 2):.1%} | {np.std(c):.2f} | "
          f"{np.max(np.abs(c)):.1f} | | | |")


def _brewster(outcomes: list[Outcome]) -> None:
    rows = [o for o in outcomes if o.sample.name.startswith("dielectric")]
    if not rows:
        return
    print("dielectric (n = 1.5): −m01/m00 measured (mean ± spread over seeds), the world's "
          "aperture-averaged truth, and a flat facet's (Rs − Rp)/(Rs + Rp):")
    for ti in sorted({o.sample.theta_i for o in rows}):
        mine = [o for o in rows if o.sample.theta_i == ti]
        m = np.array([-o.m_normalised[0, 1] for o in mine])
        truth = np.mean([-o.truth[0, 1] for o in mine])
        f = fresnel_mueller(math.cos(math.radians(ti)), 1.5)
        print(f"  θi {ti:4.1f}°: {m.mean():.4f} ± {m.std():.4f}   truth {truth:.4f}   "
              f"flat facet {f[0, 1] / f[0, 0]:.4f}")
    f = fresnel_mueller(math.cos(math.radians(BREWSTER_DEG)), 1.5)
    print(f"  Brewster {BREWSTER_DEG:.1f}°: flat facet {f[0, 1] / f[0, 0]:.4f} "
          f"(Rp = {f[0, 0] - f[0, 1]:.1e})")


def _load(paths: list[str]) -> list[Outcome]:
    """The outcomes saved by ``--save`` runs (matrices absent in older files: NaN)."""
    out = []
    for p in paths:
        z = np.load(p.strip())
        nan = np.full((len(z["names"]), 4, 4), np.nan)
        m = z.get("m_normalised", nan)
        t = z.get("truth", nan)
        out += [Outcome(sample(str(n)), int(s), c, u, mi, ti) for n, s, c, u, mi, ti in
                zip(z["names"], z["seeds"], z["calibrated"], z["nominal"], m, t,
                    strict=True)]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--samples", default=None,
                    help="comma-separated sample names (default: all ten)")
    ap.add_argument("--save", default=None, help="npz of the pulls, rewritten every seed")
    ap.add_argument("--load", default=None,
                    help="comma-separated npz files of earlier --save runs: print their "
                    "pooled table and report instead of running")
    args = ap.parse_args()
    if args.load:
        outcomes = _load(args.load.split(","))
        print(f"{len({o.seed for o in outcomes})} seed(s) from {args.load}")
        _table(outcomes)
        _brewster(outcomes)
        print(report(outcomes))
        return 0
    chosen = (SAMPLES if args.samples is None
              else tuple(sample(n.strip()) for n in args.samples.split(",")))
    outcomes: list[Outcome] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            t1 = time.perf_counter()
            folder = Path(tmp) / f"seed{seed}"
            _, cal = calibrate(folder / "calibration", seed)
            for k, s in enumerate(chosen):
                outcomes.append(measure(s, seed, folder / f"sample{k}", cal))
            print(f"seed {seed}: {len(chosen)} samples in {time.perf_counter() - t1:.0f} s",
                  flush=True)
            if args.save:
                np.savez(args.save, names=[o.sample.name for o in outcomes],
                         seeds=[o.seed for o in outcomes],
                         calibrated=np.array([o.calibrated for o in outcomes]),
                         nominal=np.array([o.nominal for o in outcomes]),
                         m_normalised=np.array([o.m_normalised for o in outcomes]),
                         truth=np.array([o.truth for o in outcomes]))
    print(f"{args.seeds} seed(s) × {len(chosen)} samples × 15 normalised elements, 25 steps "
          f"each ({time.perf_counter() - t0:.0f} s wall)")
    _table(outcomes)
    _brewster(outcomes)
    print(report(outcomes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
