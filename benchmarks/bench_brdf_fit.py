"""Fit speed: Lambertian + Cook–Torrance (GGX, height-correlated Smith) on 10,000 samples.

``analysis.brdf.fit.fit_brdf`` (geometry built once, analytic Jacobian, log-parameterised α)
against ``scipy.optimize.curve_fit`` with numerical (2-point) derivatives on the same data,
the same model code (``BRDFModel.evaluate``), the same bounds, weights and start — and lmfit
if it is installed. Both must reach the same optimum (checked) before timings are reported.

A control row gives ``curve_fit`` (trf) the geometry built once as well
(``BRDFModel.evaluate_geometry``): it separates what the speed-up owes to caching the
geometry from what it owes to the analytic Jacobian and the lean LM step.

``--selection`` times the default fit instead: model selection among the
default candidates as ``scatterlab fit`` runs it (``instrument.pipelines.brdf.analyse.
analyse`` with its ``DEFAULT_MODELS``, cross-validation on) on the closed loop's 57-point
in-plane scan of the glossy sample (tests/instrument/sim_scan.py, sensor seed 0); wall and
CPU time, median of the repeats. ``--models`` times another candidate list.

Run:  python benchmarks/bench_brdf_fit.py [--quick] [--samples N] [--repeats R]
      python benchmarks/bench_brdf_fit.py --selection [--repeats R] [--models a,b+c]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import scipy
from scipy.optimize import curve_fit

from analysis.brdf import get_model
from analysis.brdf.fit import fit_brdf
from analysis.brdf.geometry import make_geometry

TRUE = np.array([0.3, 0.5, 0.2])  # rho_d, ks, alpha
START = np.array([0.5, 0.3, 0.4])


def make_data(n: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    """Random goniometer geometries (θ ∈ [0, 85°], φr ∈ (−π, π]) with 3 % Gaussian noise."""
    rng = np.random.default_rng(seed)
    n_inc = 10
    ti = np.repeat(np.radians(np.linspace(0.0, 75.0, n_inc)), n // n_inc)
    m = ti.size
    tr = np.radians(rng.uniform(0.0, 85.0, m))
    pr = np.where(rng.random(m) < 0.5, np.pi, rng.uniform(-np.pi, np.pi, m))
    pi_ = np.zeros(m)
    f = get_model("lambert+ggx").evaluate(TRUE, ti, pi_, tr, pr)
    sig = 0.03 * f
    y = f + sig * rng.standard_normal(m)
    return y, sig, ti, pi_, tr, pr


def timed_round_robin(
    fns: dict[str, Callable[[], object]], repeats: int
) -> dict[str, tuple[float, float, object]]:
    """Median wall and CPU (process) time of each function, run in turn within every repeat
    so that a shared, busy machine slows them all alike (the ratios are what this benchmark
    reports; CPU time is less sensitive to other jobs on the machine)."""
    outs = {k: f() for k, f in fns.items()}  # warm-up (imports, caches)
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeats):
        for k, f in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            outs[k] = f()
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    return {k: (statistics.median(wall[k]), statistics.median(cpu[k]), outs[k]) for k in fns}


def selection_timing(repeats: int, models: str | None) -> None:
    """The default fit's wall and CPU time on the 57-point closed-loop scan (docstring)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from instrument.pipelines.brdf.analyse import DEFAULT_MODELS, analyse
    from tests.instrument.sim_scan import SAMPLES, ScanSetup, reduce_seed, render

    names = list(DEFAULT_MODELS) if models is None else models.split(",")
    pts = reduce_seed(render(ScanSetup(), SAMPLES[1]), 0)
    res = analyse(pts, names)  # warm-up (imports, caches)
    walls, cpus = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        res = analyse(pts, names)
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    fit = res.chosen_fit
    print(f"# default fit: {len(names)} candidates, {pts.n} points, median of {repeats} runs; "
          f"python {platform.python_version()}, numpy {np.__version__}")
    print("| candidates | wall [ms] | CPU [ms] | chosen | χ² | α |")
    print("|---:|---:|---:|---|---:|---|")
    print(f"| {len(names)} | {statistics.median(walls) * 1e3:.0f} | "
          f"{statistics.median(cpus) * 1e3:.0f} | {res.chosen} | {fit.chi2:.1f} | "
          f"{fit.params[-1]:.5f} ± {fit.stderr[-1]:.1e} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 repeats instead of 15")
    ap.add_argument("--samples", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--selection", action="store_true",
                    help="time the default model selection on a 57-point scan instead")
    ap.add_argument("--models", default=None, help="candidates for --selection")
    args = ap.parse_args()
    repeats = args.repeats or (3 if args.quick else 15)
    if args.selection:
        selection_timing(repeats, args.models)
        return

    model = get_model("lambert+ggx")
    y, sig, ti, pi_, tr, pr = make_data(args.samples)
    n = y.size
    xdata = np.stack([ti, pi_, tr, pr])

    def ours() -> object:
        return fit_brdf(model, y, ti, pi_, tr, pr, sigma=sig, start=START)

    def f_curve(x: np.ndarray, rho: float, ks: float, alpha: float) -> np.ndarray:
        return model.evaluate([rho, ks, alpha], x[0], x[1], x[2], x[3])

    bounds = (model.lower, model.upper)

    def scipy_trf() -> object:
        return curve_fit(f_curve, xdata, y, p0=START, sigma=sig, absolute_sigma=True,
                         bounds=bounds)

    def scipy_lm() -> object:
        return curve_fit(f_curve, xdata, y, p0=START, sigma=sig, absolute_sigma=True)

    geom = make_geometry(ti, pi_, tr, pr)

    def f_cached(_x: object, rho: float, ks: float, alpha: float) -> np.ndarray:
        return model.evaluate_geometry(np.array([rho, ks, alpha]), geom)

    def scipy_trf_cached() -> object:
        return curve_fit(f_cached, None, y, p0=START, sigma=sig, absolute_sigma=True,
                         bounds=bounds)

    fns: dict[str, Callable[[], object]] = {"ours": ours, "trf": scipy_trf, "lm": scipy_lm,
                                            "trf_cached": scipy_trf_cached}
    try:
        import lmfit

        def lm_resid(pars: object) -> np.ndarray:
            v = pars.valuesdict()  # type: ignore[attr-defined]
            return (y - model.evaluate([v["rho"], v["ks"], v["alpha"]], ti, pi_, tr, pr)) / sig

        def run_lmfit() -> object:
            pars = lmfit.Parameters()
            for name, s, lo, hi in zip(("rho", "ks", "alpha"), START, model.lower, model.upper,
                                       strict=True):
                pars.add(name, value=s, min=lo, max=hi)
            return lmfit.minimize(lm_resid, pars)

        fns["lmfit"] = run_lmfit
    except ImportError:
        lmfit = None
    res = timed_round_robin(fns, repeats)
    t_ours, c_ours, r_ours = res["ours"]
    t_trf, c_trf, (p_trf, cov_trf) = res["trf"]
    t_lm, c_lm, (p_lm, cov_lm) = res["lm"]
    # GGX depends on α² only: unbounded lm may land on −α, the same optimum
    p_lm = np.abs(p_lm)

    def chi2(p: np.ndarray) -> float:
        r = (y - model.evaluate(p, ti, pi_, tr, pr)) / sig
        return float(r @ r)

    rows = [("analysis.brdf fit_brdf (LM, analytic J, cached geometry)", t_ours, c_ours,
             r_ours.params, r_ours.stderr, chi2(r_ours.params))]
    rows.append(("scipy curve_fit, bounds (trf), 2-point J", t_trf, c_trf, p_trf,
                 np.sqrt(np.diag(cov_trf)), chi2(p_trf)))
    rows.append(("scipy curve_fit, no bounds (lm), 2-point J", t_lm, c_lm, p_lm,
                 np.sqrt(np.diag(cov_lm)), chi2(p_lm)))
    t_tc, c_tc, (p_tc, cov_tc) = res["trf_cached"]
    rows.append(("control: scipy curve_fit (trf), 2-point J, geometry built once", t_tc, c_tc,
                 p_tc, np.sqrt(np.diag(cov_tc)), chi2(p_tc)))
    if lmfit is not None:
        t_lf, c_lf, r_lf = res["lmfit"]
        p_lf = np.array([r_lf.params[k].value for k in ("rho", "ks", "alpha")])
        e_lf = np.array([r_lf.params[k].stderr or np.nan for k in ("rho", "ks", "alpha")])
        rows.append((f"lmfit {lmfit.__version__} leastsq", t_lf, c_lf, p_lf, e_lf, chi2(p_lf)))

    ref = rows[0]
    print(f"# brdf_fit: lambert+ggx on {n} samples, median of {repeats} runs")
    print(f"# python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}"
          f", {platform.machine()}")
    print(f"# truth {TRUE.tolist()}, start {START.tolist()}")
    print("| method | wall [ms] | CPU [ms] | wall speed-up vs trf | rho | ks | alpha | chi2 "
          "| max abs(Δp)/σ vs ours |")
    print("|---|---|---|---|---|---|---|---|---|")
    worst = 0.0
    for name, t, c, p, e, c2 in rows:
        dev = float(np.max(np.abs(p - ref[3]) / ref[4]))
        worst = max(worst, dev)
        print(f"| {name} | {t * 1e3:.1f} | {c * 1e3:.1f} | {rows[1][1] / t:.1f}× | "
              f"{p[0]:.5f}±{e[0]:.1e} | {p[1]:.5f}±{e[1]:.1e} | {p[2]:.5f}±{e[2]:.1e} | "
              f"{c2:.3f} | {dev:.1e} |")
    same = worst < 1e-3
    print(f"# same optimum (all |Δp| < 1e-3 σ): {same}")
    print(f"# speed-up vs curve_fit(trf): wall {t_trf / t_ours:.1f}×, CPU {c_trf / c_ours:.1f}×;"
          f" vs curve_fit(lm): wall {t_lm / t_ours:.1f}×, CPU {c_lm / c_ours:.1f}× "
          "(target ≥ 5×)")
    print(f"# control, curve_fit(trf) on the geometry built once: wall {t_tc / t_ours:.1f}×, "
          f"CPU {c_tc / c_ours:.1f}× (the part owed to the Jacobian and LM step alone)")
    if not same:
        raise SystemExit("optimizers disagree: timings are not comparable")


if __name__ == "__main__":
    main()
