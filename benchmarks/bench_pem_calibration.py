"""The PEM polarimeter's calibration over seeds (ADR 0113): per seed, ``scatterlab
calibrate polarimeter`` on ``sim-polarimetric-pem`` (hidden: modulator amplitude 3 % high,
its axis 0.4° off, polarisers ±0.3°, analyser retarder −0.4°, extinction 1e-5), then one
engine run per sample fitted with the calibration and without, through the validation
matrix of ADR 0108 (tests/instrument/pipelines/polarimetry/validation.py, ``pem=True``).

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_pem_calibration.py --seeds 3
    python benchmarks/bench_pem_calibration.py --seeds 1 --samples "air,polariser 30°"

Prints the calibration's parameters against the hidden ones (Mahalanobis² per seed), the
validation report per sample and a table of the pooled pulls. Its cheap one-seed twin in
the default test run: tests/instrument/pipelines/polarimetry/test_pem_calibration.py.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.instrument.pipelines.polarimetry.test_pem_calibration import HIDDEN  # noqa: E402
from tests.instrument.pipelines.polarimetry.validation import (  # noqa: E402
    calibrate,
    measure,
    report,
    sample,
)

DEFAULT_SAMPLES = "air,polariser 30°,polariser 45°,quarter-wave plate,dielectric 50°"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--samples", default=DEFAULT_SAMPLES)
    args = ap.parse_args()
    names = [n.strip() for n in args.samples.split(",") if n.strip()]
    outcomes = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, args.seeds + 1):
            folder = Path(tmp) / f"s{seed}"
            _, file = calibrate(folder, seed, pem=True)
            data = json.loads(file.read_text(encoding="utf-8"))
            d = np.array(data["params"]) - HIDDEN
            d2 = float(d @ np.linalg.solve(np.array(data["covariance"]), d))
            print(f"seed {seed}: {data['quality']}, Mahalanobis² to the hidden train "
                  f"{d2:.1f} (χ²(5): 95 % below 11.1)", flush=True)
            for name in names:
                outcomes.append(measure(sample(name), seed, folder / name, file, pem=True))
    print(report(outcomes))
    c = np.concatenate([o.calibrated for o in outcomes])
    n = np.concatenate([o.nominal for o in outcomes])
    print(f"all ({len(outcomes)} sample-seeds, {c.size} pulls): calibrated "
          f"{np.mean(np.abs(c) < 2):.1%} within 2σ, spread {np.std(c):.2f}, max "
          f"{np.max(np.abs(c)):.1f}; uncalibrated {np.mean(np.abs(n) < 2):.1%} within 2σ, "
          f"max {np.max(np.abs(n)):.0f}")


if __name__ == "__main__":
    main()
