"""A PEM run over the glass: m00 against the world's absolute truth, σ and pulls by column,
and the single-pass pBRDF gate (ADR 0106, amendment "PEM scale and σ").

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_pem_scale.py --seeds 3
    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_pem_scale.py \
        --seeds 1 --theta-r "30.0, 50.0, 70.0"

``sim-polarimetric-pem`` with its hidden train ideal (the nominal reduction), mounts 10×
faster, the lock-in's seed varied and its waits advancing its emulated clock; θi 50°. The
truth is the world's aperture-averaged matrix (``mueller_on_aperture``) over P Ω cos θr at
the run's read-back pose; pulls are (m_ij − truth)/σ of the absolute elements.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from tests.instrument.run.test_pem_absolute_scale import _fit_with_truth
from tests.instrument.run.test_pem_run import fast_pem_bench, plan_text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--theta-r", default="50.0", help="θr list as TOML text")
    ap.add_argument("--time-constants", type=float, default=None,
                    help="the plan's settle per harmonic, τ (default: the plan's)")
    args = ap.parse_args()
    extra = "" if args.time_constants is None else f"time_constants = {args.time_constants}"
    pulls = []
    for seed in range(1, args.seeds + 1):
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            if "," in args.theta_r:  # several geometries: the pBRDF gate of one pass
                from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
                from tests.instrument.pipelines.polarimetry.closed_loop import run_with_truth

                path, _ = run_with_truth(folder, fast_pem_bench(folder, seed=seed),
                                         plan_text(ti="50.0", tr=args.theta_r, extra=extra),
                                         steps=8, world_name="sim-polarimetric-pem",
                                         frame_deg=0.0)
                done = fit_polarimetric_run(path, report=False, write=False)
                fit = done.summary["pbrdf"]
                print(f"seed {seed}: pBRDF {fit['verdict']}; "
                      + ", ".join(f"{n} {v:.6g} ± {e:.2g}" for n, v, e in zip(
                          fit["param_names"], fit["params"], fit["stderr"], strict=True)))
                for p in done.points:
                    print(f"  θr {p.group.theta_r:.1f}: reduction χ² {p.raw.chi2:.1f} for "
                          f"{p.raw.dof} dof")
                continue
            point, truth = _fit_with_truth(folder, fast_pem_bench(folder, seed=seed),
                                           plan_text(ti="50.0", tr=args.theta_r,
                                                     extra=extra),
                                           8, "sim-polarimetric-pem")
        m, s = point.brdf.m, point.brdf.sigma
        pulls.append((m - truth) / s)
        rms_sigma = np.sqrt(np.mean(s**2, axis=0))
        print(f"seed {seed}: m00 {m[0, 0]:.4f} ± {s[0, 0]:.4f} (truth {truth[0, 0]:.4f}); "
              f"σ by column {np.array2string(rms_sigma, precision=2)}; reduction χ² "
              f"{point.raw.chi2:.1f} for {point.raw.dof} dof")
    if pulls:
        p = np.array(pulls)
        print("pull rms by column:", np.array2string(
            np.sqrt(np.mean(p**2, axis=(0, 1))), precision=2))


if __name__ == "__main__":
    main()
