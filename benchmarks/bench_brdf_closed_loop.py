"""Closed-loop BRDF validation figures: coverage, model selection, σ vs scatter,
and the camera method's geometric systematics at high signal.

1. Three ground-truth samples scanned on the simulated bench (camera/scene/sensor code
   without the motion emulators), reduced by the absolute method and fitted as the receiver
   sees them (:func:`analysis.brdf.reduction.receiver_model`) with BIC selection among
   lambert, oren_nayar and lambert+ggx; tests/instrument/pipelines/brdf/test_closed_loop.py
   asserts the same numbers.
2. Noise-free, full resolution (1024² px): the reduced values against the BRDF at the
   nominal angles (the old point-sample reduction and the new one) and against the receiver
   model.
3. High SNR (1024² px, 80 % full well, 4 frames averaged): the sim bench's sample fitted
   with the receiver model and with the BRDF at the nominal angles, z = (estimate − truth)/σ.

4. ``--matrix N``: the validation matrix — ten ground-truth samples, one per
   family, from diffuse to a sharp GGX lobe (α = 0.02), scanned at θi = 20°, 50°, 80°
   (tests/instrument/sim_scan.py ``MATRIX``), N sensor seeds each, every scan analysed as
   ``scatterlab fit`` does (the default candidates, instrument-aware fits, the
   goodness-of-fit gate); per sample the right-model rate, the fraction of the true
   model's parameters inside the reported 2σ, the fraction flagged as not described by
   the model and the χ²/dof of the chosen fit.

Run: ``python benchmarks/bench_brdf_closed_loop.py [--quick] [--seeds N] [--high-snr N]
[--matrix N] [--workers N | --scheduler ADDRESS]``. With ``--workers``/``--scheduler``
the seeds run as Dask tasks (ADR 0070): the tables are the same, value for value, as the
serial run's (every seed carries its own RNG seeds). The high-SNR part sends its
full-resolution rendering (≈ 0.5 GB) to every worker once, so it gains only with several
seeds per worker: with
``--seeds 3 --high-snr 1`` two local workers took 138 s against 72 s serial on the shared
2-core box, with identical tables.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

# One BLAS thread, as in the Dask workers, so that serial and cluster runs compute alike.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.brdf import get_model
from analysis.brdf.fit import fit_brdf
from analysis.brdf.reduction import absolute_brdf, receiver_model, solid_angle_sr
from instrument.cli._cluster import add_cluster_options, mapper, open_cluster
from tests.instrument.pipelines.brdf.test_closed_loop import closed_loop, matrix_stats
from tests.instrument.sim_scan import (
    MATRIX,
    SAMPLES,
    Rendered,
    Sample,
    ScanSetup,
    receiver,
    reduce_seed,
    render,
)

#: The sim bench's own sample (instrument/bench/profiles/sim.toml [simulation.scene]).
EXAMPLE = Sample("example", "lambert+ggx", (0.5, 0.2, 0.2))
PHOTON_J = 6.62607015e-34 * 299792458.0 / 633e-9


def coverage_table(n: int, run_map: Callable | None = None) -> None:
    print("| sample | truth | seeds | inside 2σ (per parameter) | all inside 2σ | right model "
          "| std of z | estimate spread / reported σ | time (s) |")
    print("|---|---|---:|---|---:|---:|---|---|---:|")
    for s in SAMPLES:
        t0 = time.perf_counter()
        st = closed_loop(s, range(n), mapper=run_map)
        dt = time.perf_counter() - t0
        names = get_model(s.model).param_names
        truth = ", ".join(f"{k}={v:g}" for k, v in zip(names, s.params, strict=True))

        def fmt(a: np.ndarray, pct: bool = False) -> str:
            return ", ".join(f"{x:.0%}" if pct else f"{x:.2f}" for x in a)

        print(f"| {s.name} | {s.model}: {truth} | {n} | {fmt(st.coverage_2sigma, True)} | "
              f"{st.joint_coverage:.0%} | {st.right_model:.0%} | {fmt(st.z_std)} | "
              f"{fmt(st.spread_over_sigma)} | {dt:.1f} |")


def geometry_table() -> None:
    setup = ScanSetup(sensor_px=1024, power_w=1e-3)
    r = render(setup, EXAMPLE)
    a = r.angles_rad
    power = r.photon_rate.reshape(len(a), -1).sum(axis=1) * PHOTON_J
    rg = receiver(setup)
    model = get_model(EXAMPLE.model)
    p = np.array(EXAMPLE.params)
    nominal = model.evaluate(p, *a.T)
    seen = receiver_model(model, rg).evaluate(p, *a.T)
    cone, _ = solid_angle_sr(setup.aperture_mm, setup.distance_mm)
    old = absolute_brdf(power, power, *a.T, incident_power_w=setup.power_w,
                        solid_angle=cone).brdf
    new = absolute_brdf(power, power, *a.T, incident_power_w=setup.power_w,
                        solid_angle=rg.solid_angle_sr, receiver=rg).brdf
    spec = np.abs(np.abs(a[:, 3] - a[:, 1]) - np.pi) < 0.1
    spec &= np.abs(a[:, 2] - a[:, 0]) <= np.radians(4.5)
    rows = [("old reduction (cone Ω, G = 1) / f(nominal)", old / nominal - 1),
            ("new reduction (A/R², ÷G) / f(nominal)", new / nominal - 1),
            ("new reduction / receiver model", new / seen - 1)]
    print("| noise-free, 1024² px | min | max | mean, off specular | mean, ±4° of specular |")
    print("|---|---:|---:|---:|---:|")
    for name, d in rows:
        print(f"| {name} | {d.min():+.2e} | {d.max():+.2e} | {d[~spec].mean():+.2e} | "
              f"{d[spec].mean():+.2e} |")


def high_snr_seed(seed: int, *, r: Rendered) -> tuple[np.ndarray, float, np.ndarray]:
    """One high-SNR seed: σ, χ² and z of the receiver-aware fit, z of the nominal-angle fit."""
    a = r.angles_rad
    truth = np.array(EXAMPLE.params)
    seen = receiver_model(get_model(EXAMPLE.model), receiver(r.setup))
    plain = get_model(EXAMPLE.model)
    pts = reduce_seed(r, seed)
    fit = fit_brdf(seen, pts.brdf, *a.T, sigma=pts.u_point)
    naive = fit_brdf(plain, pts.brdf, *a.T, sigma=pts.u_point)
    z = (fit.params - truth) / fit.stderr
    z0 = (naive.params - truth) / naive.stderr
    return fit.stderr, float(fit.chi2), np.stack([z, z0])


def high_snr_table(seeds: int, run_map: Callable | None = None) -> None:
    setup = ScanSetup(sensor_px=1024, power_w=1e-3, fill=0.8, frames=4)
    r = render(setup, EXAMPLE)
    print("| seed | σ (ρd, ks, α) | z, receiver-aware fit | χ² (54 dof) "
          "| z, BRDF at nominal angles |")
    print("|---:|---|---|---:|---|")
    if run_map is None:
        per_seed = [high_snr_seed(seed, r=r) for seed in range(seeds)]
    else:
        per_seed = run_map(high_snr_seed, range(seeds), r=r)
    chi2, zs = [], []
    for seed, (stderr, c2, zz) in enumerate(per_seed):
        z, z0 = zz
        sig = ", ".join(f"{x:.2g}" for x in stderr)
        print(f"| {seed} | {sig} | {', '.join(f'{x:+.2f}' for x in z)} | {c2:.1f} | "
              f"{', '.join(f'{x:+.2f}' for x in z0)} |")
        chi2.append(c2)
        zs.append(z)
    z_all = np.array(zs)
    print(f"\n{seeds} seeds: χ² = {np.mean(chi2):.1f} ± {np.std(chi2) / np.sqrt(seeds):.1f}; "
          f"mean z = {', '.join(f'{x:+.2f}' for x in z_all.mean(axis=0))}; "
          f"std of z = {', '.join(f'{x:.2f}' for x in z_all.std(axis=0))}")


def matrix_table(n: int, names: list[str] | None = None, run_map: Callable | None = None
                 ) -> None:
    print("| sample | truth | seeds | right model | right or indistinguishable | flagged "
          "(model rejected) | truth inside reported 2σ (per parameter) | χ²/dof of the chosen "
          "fit: median [min, max] | clipped readings left out | s per fit | time (s) |")
    print("|---|---|---:|---:|---:|---:|---|---|---:|---:|---:|")
    for s in MATRIX:
        if names and s.name not in names:
            continue
        t0 = time.perf_counter()
        st = matrix_stats(s, range(n), mapper=run_map)
        names_p = get_model(s.model).param_names
        truth = ", ".join(f"{k}={v:g}" for k, v in zip(names_p, s.params, strict=True))
        cov = ", ".join(f"{x:.0%}" for x in st.coverage_2sigma)
        c = st.chi2_dof
        print(f"| {s.name} | {s.model}: {truth} | {n} | {st.right_model:.0%} | "
              f"{st.right_or_twin:.0%} | {st.flagged:.0%} | {cov} | {np.median(c):.2f} "
              f"[{c.min():.2f}, {c.max():.2f}] | {st.clipped:.1f} | {st.seconds_per_fit:.2f} | "
              f"{time.perf_counter() - t0:.0f} |", flush=True)
        others = sorted({x for x in st.chosen if x != s.model})
        if others:
            print(f"<!-- {s.name}: also chosen {', '.join(others)} -->", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="10 seeds per sample, 1 high-SNR")
    ap.add_argument("--seeds", type=int, default=None,
                    help="seeds per sample (default 50; 0 skips the coverage table)")
    ap.add_argument("--high-snr", type=int, default=None,
                    help="high-SNR seeds (default 3; 0 skips the full-resolution parts)")
    ap.add_argument("--matrix", type=int, default=0, metavar="N",
                    help="the validation matrix with N seeds per sample (default 0: skip)")
    ap.add_argument("--samples", default=None,
                    help="comma-separated matrix sample names (default: all)")
    add_cluster_options(ap, local_by_default=False)
    args = ap.parse_args()
    n = args.seeds if args.seeds is not None else (10 if args.quick else 50)
    hs = args.high_snr if args.high_snr is not None else (1 if args.quick else 3)
    t0 = time.perf_counter()
    with open_cluster(args, local_by_default=False, out=sys.stderr) as client:
        run_map = mapper(client)
        if args.matrix > 0:
            matrix_table(args.matrix, args.samples.split(",") if args.samples else None,
                         run_map)
            print()
        if n > 0:
            coverage_table(n, run_map)
        if hs > 0:
            print()
            geometry_table()
            print()
            high_snr_table(hs, run_map)
    print(f"\nwall time {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
