"""A single PEM pass over the glass: the pBRDF's gate with the point receiver and with the
finite receiver's model (ADR 0106, amendment "The pBRDF as the receiver reads it").

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_pem_pbrdf_receiver.py \
        --seeds 1 2 3

Per seed: ``sim-polarimetric-pem`` with its hidden train ideal (the nominal reduction),
θi 50°, θr 30°, 50°, 70°, the lock-in's seed varied. Printed per seed: each model's χ²/dof,
p and fitted (n, rms slope, albedo) with σ; and, per geometry, the largest |model − world|
in σ of the reading with the fitted-to-truth parameters, where the world's truth is its
own footprint- and aperture-averaged matrix (``mueller_on_aperture``) over P Ω cos θr at
the run's read-back pose: what each model leaves out at zero noise, and the quadrature
levels' convergence.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from analysis.brdf.reduction.detector import solid_angle_sr
from analysis.polarimetry.pbrdf import pbrdf, pbrdf_on_receiver
from hw_mocks.sim.world import find_world
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run, receiver_geometry
from instrument.pipelines.polarimetry.readings import read_polarimetric
from instrument.pipelines.polarimetry.reduce import source_scale
from instrument.run.runfile import read_run
from tests.instrument.pipelines.polarimetry.closed_loop import run_with_truth
from tests.instrument.run.test_pem_run import fast_pem_bench, plan_text

WORLD = "sim-polarimetric-pem"
TRUTH = (1.5, 0.0, 0.15, 0.3, 0.0)  # the profile's hidden glass; the ideal train's frame


def _world_truth(path: Path, steps: int) -> np.ndarray:
    """The world's matrix (1/sr) at each geometry's read-back pose."""
    world = find_world(WORLD)
    assert world is not None
    run = read_run(path)
    head = world.power_meter
    omega, _ = solid_angle_sr(head.aperture_diameter_mm, head.distance_mm)
    out = []
    for row in range(0, run.n_points, steps):
        state = world.snapshot()
        state = replace(state, source=replace(state.source, on=True), pose=world.pose(
            {a: float(run.positions[row, k]) for k, a in enumerate(run.axes)}))
        power = np.asarray(state.scene.mueller_on_aperture(  # type: ignore[union-attr]
            state.pose.detector_dir * head.distance_mm, -state.pose.detector_dir,
            head.aperture_diameter_mm, state))
        out.append(power / (state.source.power_w * omega
                            * math.cos(math.radians(float(run.theta_r[row])))))
    return np.array(out)


def one_seed(seed: int, folder: Path, theta_r: str) -> None:
    path, _ = run_with_truth(folder, fast_pem_bench(folder, seed=seed),
                             plan_text(ti="50.0", tr=theta_r), steps=8, world_name=WORLD,
                             frame_deg=0.0)
    truth = _world_truth(path, 8)
    for receiver_model in (False, True):
        t0 = time.perf_counter()
        done = fit_polarimetric_run(path, report=False, write=False,
                                    receiver_model=receiver_model)
        dt = time.perf_counter() - t0
        fit = done.summary["pbrdf"]
        p = dict(zip(fit["param_names"], zip(fit["params"], fit["stderr"], strict=True),
                     strict=True))
        print(f"seed {seed} {'receiver' if receiver_model else 'point   '}: χ²/dof "
              f"{fit['chi2'] / fit['dof']:.3f} ({fit['dof']} dof), p {fit['p_value']:.3g}; "
              + ", ".join(f"{n} {p[n][0]:.6f} ± {p[n][1]:.2g} "
                          f"({(p[n][0] - t) / p[n][1]:+.2f}σ)"
                          for n, t in (("n", 1.5), ("alpha", 0.15), ("albedo", 0.3)))
              + f"; level {fit['receiver_level']}, quadrature ≤ "
              f"{fit['quadrature_error_sigma']:.2g}σ; fit {dt:.1f} s")
    pts = done.points
    ang = np.radians([[q.group.theta_i, q.group.phi_i, q.group.theta_r, q.group.phi_r]
                      for q in pts]).T
    sigma = np.array([q.brdf.sigma for q in pts])
    prun = read_polarimetric(path)
    rg, _ = receiver_geometry(prun, source_scale(prun, None))
    assert rg is not None
    rows = [("point", pbrdf(TRUTH, *ang))]
    rows += [(f"level {lv}", pbrdf_on_receiver(TRUTH, *ang, rg, level=lv))
             for lv in range(4)]
    for label, model in rows:
        worst = np.max(np.abs(model - truth) / sigma, axis=(1, 2))
        print(f"  truth's {label:<8} against the world: max |Δ|/σ by geometry "
              + ", ".join(f"{v:.2g}" for v in worst))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[1])
    ap.add_argument("--theta-r", default="30.0, 50.0, 70.0", help="θr list as TOML text")
    args = ap.parse_args()
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as tmp:
            one_seed(seed, Path(tmp), args.theta_r)


if __name__ == "__main__":
    main()
