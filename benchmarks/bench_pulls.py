"""Do the reported σ match the scatter? Pulls and χ² p-values per detector.

For every scan of a known sample the true model's fit gives pulls z = (estimate − truth)/σ
per parameter and a χ² p-value. When the σ are right, the RMS of the pulls is 1 and the
p-values are uniform on [0, 1] (Kolmogorov–Smirnov test against U(0, 1),
:func:`scipy.stats.kstest`; p_KS > 0.01 asked). RMS < 1 means σ too large, > 1 too small.

* ``camera``: the closed-loop validation matrix (tests/instrument/sim_scan.py ``MATRIX``:
  ten samples, θi = 20°, 50°, 80°, the camera rendered without the motion emulators),
  every scan analysed as ``scatterlab fit`` does (default candidates, forward model, gate).
* ``power_meter``: scans through the engine on the emulated bench (PM100USB firmware over
  the pyusb backend, real drivers), one seed of the meter's noise per run, with per-point
  darks, reduced and fitted as ``scatterlab fit --detector power_meter`` does.
* ``lockin``: scans through the engine on the emulated spectral bench (SR830 firmware
  with a chopped photodiode, SC10 shutter, FW102C; real drivers), the samples of the
  power meter's runs at the 550 nm filter, one lock-in noise seed per run, per-point
  darks, reduced and fitted per wavelength as ``scatterlab fit`` does. The pulls use the
  fit's σ without the common scale and the lock-in's range-gain covariance: the emulator
  has the photodiode's nominal responsivity and an exact gain on every range, so those
  two stated errors (2 % and 1 %/√3) have nothing to scatter against here.

Run: ``python benchmarks/bench_pulls.py [--camera N] [--power-meter N] [--lockin N]
[--samples a,b] [--jobs J]`` (N seeds per sample; 0 skips the detector; J lock-in runs at
once: they mostly wait on the emulated settling, not on the CPU).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.instrument.pipelines.brdf.test_closed_loop import matrix_stats  # noqa: E402
from tests.instrument.pipelines.brdf.test_lockin_pulls import lockin_profile  # noqa: E402
from tests.instrument.sim_scan import MATRIX  # noqa: E402

#: Samples of the power-meter runs: (name, scene brdf, its parameters as profile TOML,
#: the registry model, truth).
PM_SAMPLES = (
    ("lambert-0.5", "lambert", "{ rho = 0.5 }", "lambert", (0.5,)),
    ("glossy-ggx", "lambert+ggx",
     '{ "lambert.rho" = 0.3, "ggx.ks" = 0.5, "ggx.alpha" = 0.2 }', "lambert+ggx",
     (0.3, 0.5, 0.2)),
)

PM_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "pulls"
[sample]
name = "{name}"
[scan]
skip_beam_points = true
theta_i = [20, 50]
theta_r = {{ start = -70, stop = 80, step = 10 }}
specular = {{ half_width_deg = 4, step_deg = 2 }}
[acquisition]
detectors = ["power_meter"]
dark = "per_point"
"""


def summary(label: str, pulls: list[np.ndarray], p_values: np.ndarray, seconds: float
            ) -> str:
    z = np.concatenate([np.ravel(x) for x in pulls])
    z = z[np.isfinite(z)]
    ks = stats.kstest(p_values[np.isfinite(p_values)], "uniform").pvalue
    return (f"| {label} | {len(p_values)} | {z.size} | {np.sqrt(np.mean(z**2)):.2f} | "
            f"{np.mean(z):+.2f} | {np.mean(np.abs(z) <= 2):.0%} | {np.median(p_values):.2f} | "
            f"{ks:.3g} | {seconds:.0f} |")


HEADER = ("| detector / sample | scans | pulls | RMS pull | mean pull | |z| ≤ 2 | median "
          "χ² p | KS p (χ² p-values uniform) | time (s) |\n|---|---:|---:|---:|---:|---:|"
          "---:|---:|---:|")


def camera(n: int, names: list[str] | None) -> None:
    print(HEADER)
    all_z, all_p = [], []
    t_all = time.perf_counter()
    for s in MATRIX:
        if names and s.name not in names:
            continue
        t0 = time.perf_counter()
        st = matrix_stats(s, range(n))
        all_z.append(st.pulls)
        all_p.append(st.p_values)
        print(summary(f"camera / {s.name}", [st.pulls], st.p_values,
                      time.perf_counter() - t0), flush=True)
    print(summary("**camera, all**", all_z, np.concatenate(all_p),
                  time.perf_counter() - t_all), flush=True)


def _pm_profile(brdf: str, params: str, seed: int) -> str:
    text = (ROOT / "instrument" / "bench" / "profiles" / "sim.toml").read_text("utf-8")
    text = re.sub(r'brdf = "lambert\+ggx"\nparams = \{[^}]*\}',
                  f'brdf = "{brdf}"\nparams = {params}', text)
    return text.replace("world=sim&seed=2", f"world=sim&seed={100 + seed}")


def over_samples(label: str, names: list[str] | None, scans) -> None:
    """One table row per sample of :data:`PM_SAMPLES` (``scans(sample)`` gives the pulls,
    shape (seeds, parameters), and the χ² p-values of its scans), then all together."""
    print(HEADER)
    all_z, all_p = [], []
    t_all = time.perf_counter()
    for sample in PM_SAMPLES:
        if names and sample[0] not in names:
            continue
        t0 = time.perf_counter()
        zs, ps = scans(sample)
        all_z.append(zs)
        all_p.append(ps)
        print(summary(f"{label} / {sample[0]}", [zs], ps, time.perf_counter() - t0),
              flush=True)
    print(summary(f"**{label}, all**", all_z, np.concatenate(all_p),
                  time.perf_counter() - t_all), flush=True)


def _fresh_emulators() -> None:
    """Every emulated device powered up afresh, so that a scan's seed is the one its
    profile names (emulators are shared by name within a process, and the lock-in pool's
    workers run several scans each)."""
    from hw_mocks import registry
    from hw_mocks.sim.world import reset_worlds

    registry.reset()
    reset_worlds()


def power_meter(n: int, names: list[str] | None) -> None:
    from instrument.cli import main as cli
    from instrument.pipelines.brdf.analyse import analyse
    from instrument.pipelines.brdf.reduce import ReductionOptions, reduce_run

    def scans(sample: tuple) -> tuple[np.ndarray, np.ndarray]:
        name, brdf, params, model, truth = sample
        zs, ps = [], []
        for seed in range(n):
            _fresh_emulators()
            with tempfile.TemporaryDirectory() as tmp:
                tmp_p = Path(tmp)
                (tmp_p / "bench.toml").write_text(_pm_profile(brdf, params, seed), "utf-8")
                (tmp_p / "plan.toml").write_text(PM_PLAN.format(name=name), "utf-8")
                assert cli(["run", str(tmp_p / "plan.toml"), "--bench",
                            str(tmp_p / "bench.toml"), "--out", str(tmp_p / "runs"),
                            "--no-fsync", "--quiet"]) == 0
                (path,) = (tmp_p / "runs").glob("*.h5")
                red = reduce_run(path, ReductionOptions(detector="power_meter"))
                res = analyse(red.points, (model,), run_cv=False, seed=seed)
                fit = res.fits[model]
                zs.append((fit.params - np.array(truth)) / fit.stderr)
                ps.append(res.goodness[model].p_value)
        return np.array(zs), np.array(ps)

    over_samples("power meter", names, scans)


#: The power meter's plan, read by the lock-in at the sim-spectral bench's 550 nm filter.
LOCKIN_PLAN = (PM_PLAN.replace("theta_r = {{ start = -70, stop = 80, step = 10 }}",
                               "theta_r = [-60, -40, -20, 0, 10, 30, 40, 60, 70]")
               .replace('detectors = ["power_meter"]', 'detectors = ["lockin"]')
               + "frames = 4\n[spectral]\nfilters = [2]\n")


def lockin_scan(name: str, brdf: str, params: str, model: str, truth: tuple[float, ...],
                seed: int, aperture_samples: int | None = None
                ) -> tuple[np.ndarray, float, float]:
    """One lock-in scan through the engine: (pulls of the true model's parameters, its χ²
    p-value, χ²/dof)."""
    from instrument.cli import main as cli
    from instrument.pipelines.brdf.spectral import SpectralOptions, analyse_spectral
    from instrument.run.runfile import read_run

    _fresh_emulators()
    with tempfile.TemporaryDirectory() as tmp:
        tmp_p = Path(tmp)
        (tmp_p / "bench.toml").write_text(lockin_profile(brdf, params, 300 + seed,
                                                         aperture_samples), "utf-8")
        (tmp_p / "plan.toml").write_text(LOCKIN_PLAN.format(name=name), "utf-8")
        assert cli(["run", str(tmp_p / "plan.toml"), "--bench", str(tmp_p / "bench.toml"),
                    "--out", str(tmp_p / "runs"), "--no-fsync", "--quiet"]) == 0
        (path,) = (tmp_p / "runs").glob("*.h5")
        done = analyse_spectral(read_run(path), SpectralOptions(models=(model,)), seed=seed)
    (wf,) = done.fits
    fit = wf.result.selection.fits[model]  # σ without the common scale (docstring)
    gof = wf.result.goodness[model]
    return (fit.params - np.array(truth)) / fit.stderr, gof.p_value, gof.chi2 / gof.dof


def lockin(n: int, names: list[str] | None, jobs: int,
           aperture_samples: int | None = None) -> None:
    from concurrent.futures import ProcessPoolExecutor

    def scans(sample: tuple) -> tuple[np.ndarray, np.ndarray]:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            done = list(pool.map(lockin_scan, *zip(*[(*sample, k, aperture_samples)
                                                     for k in range(n)], strict=True)))
        zs = np.array([d[0] for d in done])
        print(f"<!-- {sample[0]}: χ²/dof per scan {', '.join(f'{d[2]:.2f}' for d in done)}; "
              f"RMS pull per parameter {np.sqrt(np.mean(zs**2, axis=0)).round(2).tolist()} -->")
        return zs, np.array([d[1] for d in done])

    over_samples("lock-in", names, scans)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--camera", type=int, default=10, metavar="N")
    ap.add_argument("--power-meter", type=int, default=10, metavar="N")
    ap.add_argument("--lockin", type=int, default=0, metavar="N")
    ap.add_argument("--jobs", type=int, default=4, help="lock-in runs at once")
    ap.add_argument("--aperture-samples", type=int, default=None,
                    help="lock-in: the emulator's aperture_samples (resolution of its rule over "
                         "the photodiode, GoniometerScene)")
    ap.add_argument("--samples", default=None, help="comma-separated sample names")
    args = ap.parse_args()
    names = args.samples.split(",") if args.samples else None
    if args.camera:
        camera(args.camera, names)
    if args.power_meter:
        power_meter(args.power_meter, names)
    if args.lockin:
        lockin(args.lockin, names, args.jobs, args.aperture_samples)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
