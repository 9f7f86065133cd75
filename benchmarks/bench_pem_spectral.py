"""PEM polarimetry over a wavelength axis: σ of the normalised Mueller elements per
wavelength against the planner's κ there, and the pulls against the world's truth.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_pem_spectral.py --seeds 3

Each seed is one engine run on ``sim-polarimetric-pem-spectral`` of a linear polariser at
30° straight through (the test's bench: mounts 10× faster, the lock-in's waits on its
emulated clock, 1 µW through each filter) with the 2 × 4 settings at 550 and 650 nm, the
modulator's drive fixed (A = 2.768 and 2.342 rad) and the lock-in's noise seed varied;
``scatterlab fit``'s reduction of each wavelength at its own amplitude and the analyser's
nominal retardance there. σ is the mean over the 15 normalised elements; the pulls are
(m_ij/m00 − truth)/σ.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from instrument.bench.profile import load_profile
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from instrument.plans.planfile import parse_plan
from instrument.plans.polarimetry_pem import pem_conditioning
from tests.instrument.pipelines.polarimetry.closed_loop import pulls, run_with_truth
from tests.instrument.run.test_pem_spectral import BENCH, PLAN, spectral_reference_bench


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    spec = parse_plan(PLAN)
    assert spec.polarimetry is not None
    kappa = {c.wavelength_nm: c for c in pem_conditioning(spec.polarimetry,
                                                         load_profile(BENCH), [550.0, 650.0])}
    sigma: dict[float, list[float]] = {550.0: [], 650.0: []}
    pull: dict[float, list[np.ndarray]] = {550.0: [], 650.0: []}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, args.seeds + 1):
            folder = Path(tmp) / f"s{seed}"
            folder.mkdir()
            bench = spectral_reference_bench(folder)
            bench.write_text(bench.read_text(encoding="utf-8").replace(
                "sleep=0&seed=5", f"sleep=0&seed={seed}"), encoding="utf-8")
            path, truths = run_with_truth(folder, bench, PLAN, steps=8, world_name=BENCH,
                                          frame_deg=0.0, straight_through=True)
            (truth,) = truths.values()
            for p in fit_polarimetric_run(path, report=False, write=False).points:
                lam = p.group.wavelength_nm
                sigma[lam].append(float(np.mean(p.brdf.sigma_normalised.ravel()[1:])))
                pull[lam].append(pulls(p, truth))
    print(f"{'λ nm':>6} {'A rad':>7} {'κ':>6} {'σ mean':>8} {'|pull| max':>10} "
          f"{'within 2σ':>9}")
    for lam in (550.0, 650.0):
        c = kappa[lam]
        allp = np.concatenate(pull[lam])
        print(f"{lam:6.0f} {c.amplitude_rad:7.3f} {c.kappa:6.3g} {np.mean(sigma[lam]):8.2e} "
              f"{np.max(np.abs(allp)):10.2f} {np.mean(np.abs(allp) < 2.0):9.0%}")


if __name__ == "__main__":
    main()
