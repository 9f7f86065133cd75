"""Speed against accuracy of an in-plane BRDF scan: duration vs σ(α) over scan options.

For every option — θr step (angular density), exposure cap and frames averaged — this
measures

* the scan duration from the engine's estimator (``Plan.estimate`` motion on the optimised
  route + ``AcquisitionPolicy.estimated_seconds`` per point, 20 ms readout per frame),
* the **measured** scatter of the fitted GGX width α over sensor seeds: every point rendered
  by the simulated camera/scene/sensor (tests/instrument/sim_scan.py, no motion emulators),
  reduced (analysis.brdf.reduction) and fitted with Lambertian + Cook–Torrance GGX,
* the planner's **predicted** σ(α) (instrument.plans.tradeoff: Fisher information of the camera
  noise model),

then draws the Pareto plot (docs/brdf_tradeoff_pareto.png) and answers "the fastest scan
with σ(α) ≤ X" for a few X. Sample: ρd = 0.3, ks = 0.5, α = 0.2 under a 20 nW beam
(a neutral-density-filtered source: exposures of milliseconds, so they count).

Run: ``python benchmarks/bench_brdf_tradeoff.py [--quick] [--seeds N] [--png PATH]
[--workers N | --scheduler ADDRESS]``. With ``--workers``/``--scheduler`` the options run as
Dask tasks (ADR 0070), with the same numbers as the serial run.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

# One BLAS thread, as in the Dask workers, so that serial and cluster runs compute alike.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis.brdf import get_model  # noqa: E402
from analysis.brdf.fit import fit_brdf  # noqa: E402
from instrument.bench.profile import BenchProfile, parse_profile  # noqa: E402
from instrument.cli._cluster import add_cluster_options, mapper, open_cluster  # noqa: E402
from instrument.plans.pareto_plot import draw_front  # noqa: E402
from instrument.plans.planfile import parse_plan  # noqa: E402
from instrument.plans.tradeoff import (  # noqa: E402
    ScanOption,
    fastest_for_target,
    pareto_front,
    predict,
    setup_from_profile,
)
from tests.instrument.sim_scan import (  # noqa: E402
    SAMPLES,
    Rendered,
    Sample,
    ScanSetup,
    profile_text,
    reduce_seed,
    render,
)

READOUT_S = 0.02
PARAM = "ggx.alpha"


def measure_option(option: tuple[float, float, int], *, base: ScanSetup, sample: Sample,
                   profile: BenchProfile, rendered: dict[float, Rendered],
                   n_seeds: int) -> dict:
    """Prediction and measured scatter of σ(α) over ``n_seeds`` sensor seeds for one
    (θr step, exposure cap, frames)."""
    step, cap, nf = option
    model = get_model(sample.model)
    j = model.param_names.index(PARAM)
    setup = replace(base, theta_r_step=step, max_exposure_us=cap, frames=nf)
    spec = parse_plan(setup.plan_text())
    prior, det = setup_from_profile(profile, spec, readout_s=READOUT_S)
    det = replace(det, fill=setup.fill)
    pred = predict(spec, profile, ScanOption(step, cap, nf), prior=prior, det=det)
    r = replace(rendered[step], setup=setup)
    a = r.angles_rad
    est, rep = [], []
    for seed in range(n_seeds):
        pts = reduce_seed(r, 1000 + seed)
        fit = fit_brdf(model, pts.brdf, *a.T, sigma=pts.u_point)
        est.append(fit.params[j])
        rep.append(fit.stderr[j])
    return {
        "step": step, "cap_us": cap, "frames": nf, "points": pred.n_points,
        "duration_s": pred.duration_s, "motion_s": pred.motion_s,
        "acq_s": pred.acquisition_s, "pred": pred.sigma[PARAM],
        "measured": float(np.std(est, ddof=1)), "reported": float(np.mean(rep)),
        "bias": float(np.mean(est) - sample.params[j]), "result": pred,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="8 options, 4 seeds")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per option (default 16)")
    ap.add_argument("--png", default=str(ROOT / "docs" / "brdf_tradeoff_pareto.png"))
    add_cluster_options(ap, local_by_default=False)
    args = ap.parse_args()
    steps = (10.0, 20.0) if args.quick else (5.0, 10.0, 20.0, 30.0)
    caps = (1e3, 1e4) if args.quick else (1e3, 1e4, 1e5)
    frames = (1, 4) if args.quick else (1, 2, 4, 8)
    n_seeds = args.seeds or (4 if args.quick else 16)
    sample = SAMPLES[1]
    base = ScanSetup(power_w=2e-8, fill=0.5)
    profile = parse_profile(profile_text(base, sample))
    t0 = time.perf_counter()
    # the noise-free photon rates depend on the angles only: one rendering per θr step
    rendered = {step: render(replace(base, theta_r_step=step, max_exposure_us=caps[0],
                                     frames=frames[0]), sample) for step in steps}
    options = [(step, cap, nf) for step in steps for cap in caps for nf in frames]
    shared = {"base": base, "sample": sample, "profile": profile, "rendered": rendered,
              "n_seeds": n_seeds}
    with open_cluster(args, local_by_default=False, out=sys.stderr) as client:
        run_map = mapper(client)
        if run_map is None:
            rows = [measure_option(o, **shared) for o in options]
        else:
            rows = run_map(measure_option, options, **shared)
    wall = time.perf_counter() - t0
    print(f"{len(rows)} options × {n_seeds} seeds in {wall:.1f} s; sample {sample.model} "
          f"{sample.params}, σ of {PARAM}")
    print("| θr step | cap (ms) | frames | points | duration (s) | motion (s) "
          "| exposure+readout (s) "
          "| σ(α) measured | σ(α) reported | σ(α) predicted | Pareto |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|:-:|")
    results = [r["result"] for r in rows]
    front = {id(x) for x in pareto_front(results, PARAM)}
    for r in sorted(rows, key=lambda r: r["duration_s"]):
        print(f"| {r['step']:g}° | {r['cap_us'] / 1e3:g} | {r['frames']} | {r['points']} | "
              f"{r['duration_s']:.1f} | {r['motion_s']:.1f} | {r['acq_s']:.1f} | "
              f"{r['measured']:.2e} | {r['reported']:.2e} | {r['pred']:.2e} | "
              f"{'◆' if id(r['result']) in front else ''} |")
    ratio = np.array([r["pred"] / r["measured"] for r in rows])
    print(f"predicted/measured σ(α): median {np.median(ratio):.2f}, range "
          f"{ratio.min():.2f}–{ratio.max():.2f} ({n_seeds} seeds: measured σ ±"
          f"{100 / np.sqrt(2 * (n_seeds - 1)):.0f} %)")
    for target in (1e-3, 3e-4, 1e-4):
        best = fastest_for_target(results, PARAM, target)
        if best is None:
            print(f"σ(α) ≤ {target:g}: no option reaches it")
        else:
            m = next(r for r in rows if r["result"] is best)
            print(f"σ(α) ≤ {target:g}: {best.option.label()} — {best.duration_s:.1f} s, "
                  f"predicted {best.sigma[PARAM]:.2e}, measured {m['measured']:.2e}")
    _plot(rows, front, Path(args.png))
    print(f"Pareto plot: {args.png}")
    return 0


def _plot(rows: list[dict], front: set[int], path: Path) -> None:
    """One panel per exposure cap (so that no option hides under another), σ(α) against
    the duration; colour: θr step, marker: frames averaged, filled: measured, open:
    predicted; the black steps are the Pareto front of all options, on every panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    caps = sorted({r["cap_us"] for r in rows})
    fig, axes = plt.subplots(1, len(caps), figsize=(4.2 * len(caps) + 1.0, 4.8), sharey=True,
                             squeeze=False, layout="constrained")
    markers = {1: "o", 2: "s", 4: "^", 8: "D"}
    steps = sorted({r["step"] for r in rows})
    colors = dict(zip(steps, plt.cm.viridis(np.linspace(0, 0.9, len(steps))), strict=True))
    fr = sorted((r for r in rows if id(r["result"]) in front), key=lambda r: r["duration_s"])
    for ax, cap in zip(axes[0], caps, strict=True):
        for r in (r for r in rows if r["cap_us"] == cap):
            ax.plot(r["duration_s"], r["measured"], markers.get(r["frames"], "o"),
                    color=colors[r["step"]], ms=6)
            ax.plot(r["duration_s"], r["pred"], markers.get(r["frames"], "o"), mfc="none",
                    color=colors[r["step"]], ms=9, alpha=0.7)
        draw_front(ax, [r["result"] for r in fr], PARAM)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"exposure cap {cap / 1e3:g} ms", fontsize=9)
        ax.set_xlabel("scan duration (s)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].set_ylabel("σ of the fitted GGX roughness α (dimensionless)")
    handles = [plt.Line2D([], [], color="k", lw=1.0, label="Pareto front, all caps "
                          "(predicted)")]
    handles += [plt.Line2D([], [], ls="", marker="o", color=colors[s], label=f"θr step {s:g}°")
                for s in steps]
    handles += [plt.Line2D([], [], ls="", marker=mk, color="grey", label=f"{f} frame(s)")
                for f, mk in markers.items() if any(r["frames"] == f for r in rows)]
    handles += [plt.Line2D([], [], ls="", marker="o", color="grey", label="measured"),
                plt.Line2D([], [], ls="", marker="o", mfc="none", color="grey",
                           label="predicted by the planner")]
    fig.legend(handles=handles, fontsize=8, ncol=5, loc="outside lower center")
    fig.suptitle("In-plane BRDF scan on the simulated bench: speed against accuracy "
                 "(duration: engine estimate, motion + exposures + readout)", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
