"""Closed-loop validation on the simulated bench.

Three samples with known ground truth — Lambertian ρ = 0.8; Lambertian ρ = 0.3 + Cook–
Torrance GGX (ks = 0.5, α = 0.2); Oren–Nayar ρ = 0.8, σ = 0.3 — are scanned in plane
(θi = 20°, 40°, 60°; θr from −70° to 80° in 10° steps plus ±4° around specular in 2°
steps; 57 points), reduced by the absolute method (receiver factor divided out) and fitted
as the receiver sees the models (instrument-aware) with selection among
{lambert, oren_nayar, lambert+ggx} (BIC, smallest model within ΔBIC ≤ 2).

* 50 seeds per sample through the simulated camera/scene/sensor code without the motion
  emulators (tests/instrument/sim_scan.py): each true parameter inside the reported 2σ in
  ≥ 90 % of the fits, the right model chosen in ≥ 90 %, and the reported σ predicting the
  scatter of the estimates over seeds. Slow-marked (about 30 s on the 2-core box).
* A few scans through the real engine on the fully emulated bench (firmware emulators,
  real drivers, run file, ``scatterlab fit``): slow-marked end-to-end test.

Figures: BENCHMARKS.md, section brdf_closed_loop.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from analysis.brdf import get_model
from analysis.brdf.reduction import receiver_model
from analysis.brdf.selection import select_model
from tests.instrument.sim_scan import (
    CANDIDATES,
    MATRIX,
    SAMPLES,
    Rendered,
    Sample,
    ScanSetup,
    profile_text,
    receiver,
    reduce_seed,
    render,
)


@dataclass(frozen=True)
class LoopStats:
    sample: str
    n_seeds: int
    coverage_2sigma: np.ndarray   # per parameter
    joint_coverage: float
    right_model: float
    z_std: np.ndarray             # std over seeds of (estimate − truth)/σ, per parameter
    spread_over_sigma: np.ndarray  # std of the estimates / mean reported σ


def seed_fit(seed: int, *, r: Rendered, sample: Sample) -> tuple[np.ndarray, np.ndarray, bool]:
    """One seed of the loop: acquire every point of ``r`` with sensor ``seed``, reduce,
    select; the true model's estimates and σ, and whether it was the one chosen."""
    # instrument-aware candidates: each as the camera sees it (footprint through the pupil)
    cands = [receiver_model(get_model(c), receiver(r.setup)) for c in CANDIDATES]
    a = r.angles_rad
    pts = reduce_seed(r, seed)
    sel = select_model(cands, pts.brdf, a[:, 0], a[:, 1], a[:, 2], a[:, 3],
                       sigma=pts.u_point, criterion="bic", run_cv=False, n_starts=3, seed=seed)
    fit = sel.fits[sample.model]
    return fit.params, fit.stderr, sel.chosen == sample.model


def closed_loop(sample: Sample, seeds: Iterable[int], setup: ScanSetup | None = None, *,
                mapper: Callable[..., Sequence[Any]] | None = None) -> LoopStats:
    """Scan, reduce, select and compare with the truth for every seed.

    ``mapper(fn, items, **shared)`` runs the seeds elsewhere (a Dask cluster:
    ``instrument.batch.cluster.cluster_map``); every seed carries its own RNG seeds, so the
    statistics equal the loop's value for value.
    """
    r = render(setup or ScanSetup(), sample)
    seeds = list(seeds)
    if mapper is None:
        per_seed = [seed_fit(seed, r=r, sample=sample) for seed in seeds]
    else:
        per_seed = mapper(seed_fit, seeds, r=r, sample=sample)
    truth = np.array(sample.params)
    est = np.array([p for p, _, _ in per_seed])
    err = np.array([e for _, e, _ in per_seed])
    right = [c for _, _, c in per_seed]
    z = (est - truth) / err
    inside = np.abs(z) <= 2.0
    return LoopStats(sample.name, len(seeds), inside.mean(axis=0),
                     float(np.all(inside, axis=1).mean()), float(np.mean(right)),
                     z.std(axis=0), est.std(axis=0, ddof=1) / err.mean(axis=0))


@dataclass(frozen=True)
class MatrixStats:
    """Issue 13 §5, one sample of the validation matrix over seeds (default candidates,
    instrument-aware fits, the goodness-of-fit gate)."""

    sample: str
    n_seeds: int
    right_model: float          # chosen == truth
    right_or_twin: float        # … or indistinguishable from it (same k, ΔBIC ≤ 2)
    flagged: float              # chosen model rejected (p < 0.001)
    coverage_2sigma: np.ndarray  # truth inside the reported 2σ of the true model's fit
    chi2_dof: np.ndarray        # χ²/dof of the chosen fit, per seed
    clipped: float              # mean clipped readings left out per scan
    seconds_per_fit: float
    chosen: tuple[str, ...]     # per seed
    #: (estimate − truth)/σ of the true model's fit, shape (seeds, k), and its χ² p-value
    #: per seed: the pulls' RMS is 1 and the p-values uniform when σ match the scatter
    pulls: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    p_values: np.ndarray = field(default_factory=lambda: np.zeros(0))


def matrix_seed(seed: int, *, r, sample: Sample, models: tuple[str, ...]) -> tuple:
    """One seed of the validation matrix: (right model, right or an indistinguishable twin,
    flagged, truth inside 2σ per parameter, χ²/dof, clipped readings, chosen, fit seconds,
    the true model's pulls and its χ² p-value)."""
    import time

    from instrument.pipelines.brdf.analyse import analyse

    pts = reduce_seed(r, seed)
    t0 = time.perf_counter()
    res = analyse(pts, models, seed=seed)
    seconds = time.perf_counter() - t0
    rows = {row.name: row for row in res.selection.table}
    right = res.chosen == sample.model
    twin = right or (sample.model in res.plausible
                     and rows[sample.model].n_params == rows[res.chosen].n_params
                     and abs(rows[sample.model].bic - rows[res.chosen].bic) <= 2.0)
    fit = res.fits[sample.model]
    inside = np.abs(fit.params - np.array(sample.params)) <= 2.0 * fit.stderr
    pull = (fit.params - np.array(sample.params)) / fit.stderr
    return (right, twin, not res.adequate, inside, res.chosen_goodness.reduced_chi2,
            int(res.excluded_index.size), res.chosen, seconds, pull,
            res.goodness[sample.model].p_value)


def matrix_stats(sample: Sample, seeds: range, setup: ScanSetup | None = None,
                 models: tuple[str, ...] | None = None, *,
                 mapper: Callable[..., Sequence[Any]] | None = None) -> MatrixStats:
    """Scan, reduce, analyse with the default candidates (as ``scatterlab fit``) and compare
    with the truth for every seed (``mapper`` as in :func:`closed_loop`)."""
    from instrument.pipelines.brdf.analyse import DEFAULT_MODELS

    setup = setup or ScanSetup(theta_i_deg=(20.0, 50.0, 80.0))
    models = models or DEFAULT_MODELS
    r = render(setup, sample)
    if mapper is None:
        per = [matrix_seed(seed, r=r, sample=sample, models=models) for seed in seeds]
    else:
        per = mapper(matrix_seed, seeds, r=r, sample=sample, models=models)
    right, twin, flagged, inside, chi, clipped, chosen, seconds, pull, pv = zip(
        *per, strict=True)
    n = len(seeds)
    return MatrixStats(sample.name, n, float(np.mean(right)), float(np.mean(twin)),
                       float(np.mean(flagged)), np.mean(inside, axis=0), np.array(chi),
                       float(np.mean(clipped)), sum(seconds) / n, tuple(chosen),
                       np.array(pull), np.array(pv))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["lambert", "glossy-ggx", "sharp-ggx-0.02"])
def test_validation_matrix_reduced(name: str) -> None:
    """The validation matrix in CI: three samples of the matrix (diffuse, glossy, sharp α = 0.02 at
    θi up to 80°), 5 seeds, every scan analysed as ``scatterlab fit`` does. Each sample is
    either recovered (right model, truth inside the reported 2σ) or flagged; the full
    matrix (ten samples, 20 seeds) is benchmarks/bench_brdf_closed_loop.py --matrix."""
    sample = next(m for m in MATRIX if m.name == name)
    st = matrix_stats(sample, range(5))
    assert st.right_model >= 0.8, st
    assert np.all(st.coverage_2sigma >= 0.8) or st.flagged == 1.0, st
    # χ² of the chosen fits as expected for the noise (56 ± 11 for ~57 points)
    assert 0.6 < float(np.median(st.chi2_dof)) < 1.4, st


def test_closed_loop_quick_glossy() -> None:
    """Default-run sanity check: 6 seeds of the glossy sample."""
    st = closed_loop(SAMPLES[1], range(100, 106))
    assert st.right_model == 1.0
    assert np.all(st.coverage_2sigma >= 4 / 6)


@pytest.mark.slow
@pytest.mark.parametrize("sample", SAMPLES, ids=[s.name for s in SAMPLES])
def test_closed_loop_50_seeds(sample: Sample) -> None:
    st = closed_loop(sample, range(50))
    # nominal 2σ coverage is 95.4 % per parameter; ≥ 90 % asked (45 of 50)
    assert np.all(st.coverage_2sigma >= 0.9), st
    # all k parameters at once: nominal 0.954^k for independent errors (0.87 for k = 3)
    assert st.joint_coverage >= 0.85, st
    assert st.right_model >= 0.9, st
    # the reported σ predicts the scatter over seeds (50 seeds: std known to ±10 %)
    assert np.all((st.spread_over_sigma > 0.7) & (st.spread_over_sigma < 1.3)), st


#: Seeds of the sharp lobe's pull test and the χ² bounds on its statistic: Σ over seeds of
#: zᵀ C⁻¹ z (z the pulls of the three parameters, C the fit's correlation matrix) is χ²
#: with 3 × 10 degrees of freedom when the σ and correlations are right; the 0.5 % tails
#: on either side make a 1 % false-fail rate.
SHARP_SEEDS = range(10)
SHARP_CHI2_BOUNDS = (13.787, 53.672)  # scipy.stats.chi2.ppf([0.005, 0.995], 30)


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_sharp_lobe_sigma_match_the_scatter_over_seeds() -> None:
    """The sharp sample of the matrix (Lambert 0.3 + GGX ks 0.5, α = 0.05) fitted with the
    true model as ``scatterlab fit`` does, ten sensor seeds: the pulls' χ² over the seeds,
    with the fits' own correlations, lies between the 0.5 % tails of χ²₃₀ (an RMS pull of
    0.68–1.34). An earlier round measured a spread of 1.6–1.7 σ for ks and α on this
    sample; BENCHMARKS.md (honest_sigma_meter, "the sharp lobe's excess") has the sweep
    that did not reproduce it. About 6 min on the loaded 2-core box (the render, then ten
    fits)."""
    from instrument.pipelines.brdf.analyse import analyse

    sample = next(m for m in MATRIX if m.name == "sharp-ggx-0.05")
    r = render(ScanSetup(theta_i_deg=(20.0, 50.0, 80.0)), sample)
    truth = np.array(sample.params)
    chi2 = 0.0
    pulls = []
    for seed in SHARP_SEEDS:
        res = analyse(reduce_seed(r, seed), (sample.model,), run_cv=False, seed=seed)
        fit = res.fits[sample.model]
        z = (fit.params - truth) / fit.stderr
        chi2 += float(z @ np.linalg.solve(fit.correlation, z))
        pulls.append(z)
    rms = np.sqrt(np.mean(np.square(pulls), axis=0))
    assert SHARP_CHI2_BOUNDS[0] < chi2 < SHARP_CHI2_BOUNDS[1], (chi2, rms)

@pytest.mark.slow
def test_high_snr_truth_inside_reported_2sigma() -> None:
    """At high signal: the full-resolution camera (1024² px) with 80 %-full-well
    exposures averaged over 4 frames gives σ(ρd) ≈ 8·10⁻⁶ — 5× below the geometric
    biases of a point-sample reduction (the cone solid angle, +3.3·10⁻⁴; the footprint's
    1/r² and obliquities, ±2·10⁻⁴; the specular peak averaged over the footprint seen from
    the camera, −7·10⁻⁴). With the receiver factor divided out and the models fitted as
    the receiver sees them, the truth lies inside the reported 2σ; the same data fitted
    with the BRDF at the nominal angles put α many σ off (the test can fail). About 40 s."""
    from analysis.brdf.fit import fit_brdf

    setup = ScanSetup(sensor_px=1024, power_w=1e-3, fill=0.8, frames=4)
    sample = Sample("example", "lambert+ggx", (0.5, 0.2, 0.2))  # the sim bench's sample
    r = render(setup, sample)
    a = r.angles_rad
    truth = np.array(sample.params)
    pts = reduce_seed(r, 0)
    seen = receiver_model(get_model(sample.model), receiver(setup))
    fit = fit_brdf(seen, pts.brdf, *a.T, sigma=pts.u_point)
    z = (fit.params - truth) / fit.stderr
    assert np.all(fit.stderr / truth < 4e-5), fit.stderr
    assert np.all(np.abs(z) <= 2.0), z
    dof = pts.n - truth.size
    assert abs(fit.chi2 - dof) < 4 * np.sqrt(2 * dof), fit.chi2
    naive = fit_brdf(get_model(sample.model), pts.brdf, *a.T, sigma=pts.u_point)
    assert abs(naive.params[2] - truth[2]) > 4 * naive.stderr[2]


# ------------------------------------------------------------------------ through the engine
def _engine_scan(tmp_path: Path, sample: Sample, seed: int, setup: ScanSetup) -> Path:
    from instrument.bench.devices import open_bench
    from instrument.bench.profile import parse_profile
    from instrument.plans import build_plan, parse_plan
    from instrument.run.runner import start_run

    text = profile_text(setup, sample)
    # fast stage clocks, the camera stage at 0 mm (receiver distance = profile distance),
    # one sensor seed per scan
    text = (text.replace("speed=20", "speed=400")
            .replace("stage=MTS25-Z8&speed=400", "stage=MTS25-Z8&speed=400&start=0")
            .replace("simcam://camera?world=sim&seed=1", f"simcam://camera?world=sim&seed={seed}"))
    profile = parse_profile(text, source="closed-loop profile")
    plan = build_plan(parse_plan(setup.plan_text()), profile)
    with open_bench(profile) as bench:
        engine = start_run(plan, bench, runs_dir=tmp_path / f"{sample.name}-{seed}",
                           fsync=False, catalog=False)
        engine.run()
        return Path(engine.store.path)


@pytest.mark.slow
@pytest.mark.parametrize(("sample", "seed"), [(SAMPLES[1], 1), (SAMPLES[1], 2),
                                              (SAMPLES[2], 3)],
                         ids=["glossy-1", "glossy-2", "rough-3"])
def test_closed_loop_through_the_engine(tmp_path: Path, sample: Sample, seed: int) -> None:
    from instrument.cli import main

    path = _engine_scan(tmp_path, sample, seed, ScanSetup())
    with h5py.File(path, "r") as f:
        assert f["entry"].attrs["status"] == "finished"
        assert f["entry/points/index"].shape[0] == 57
    assert main(["fit", str(path), "--out", str(tmp_path / "report"), "--no-cv"]) == 0
    with h5py.File(tmp_path / "report" / "results.h5", "r") as f:
        g = f["entry/analysis"]
        res = json.loads(g["results_json"][()])
        params, stderr = g["chosen/params"][()], g["chosen/stderr"][()]
    assert res["selection"]["chosen"] == sample.model
    assert np.all(np.abs(params - np.array(sample.params)) < 3.5 * stderr), (params, stderr)


# ------------------------------------------------------------------------ the planner
def _planner_inputs(setup: ScanSetup, sample: Sample):
    from dataclasses import replace

    from instrument.bench.profile import parse_profile
    from instrument.plans.planfile import parse_plan
    from instrument.plans.tradeoff import setup_from_profile

    spec = parse_plan(setup.plan_text())
    profile = parse_profile(profile_text(setup, sample))
    prior, det = setup_from_profile(profile, spec, readout_s=0.02)
    return spec, profile, prior, replace(det, fill=setup.fill)


@pytest.mark.parametrize("frames", [1, 4])
def test_planner_prediction_matches_the_fit_uncertainty(frames: int) -> None:
    from analysis.brdf.fit import fit_brdf
    from instrument.plans.tradeoff import ScanOption, predict

    setup = ScanSetup(power_w=2e-8, fill=0.5, max_exposure_us=1000.0, frames=frames)
    sample = SAMPLES[1]
    spec, profile, prior, det = _planner_inputs(setup, sample)
    res = predict(spec, profile, ScanOption(10.0, 1000.0, frames), prior=prior, det=det)
    r = render(setup, sample)
    a = r.angles_rad
    pts = reduce_seed(r, 5)
    fit = fit_brdf(get_model(sample.model), pts.brdf, *a.T, sigma=pts.u_point)
    predicted = np.array([res.sigma[n] for n in fit.param_names])
    # Cramér–Rao prediction from the noise model against the fit's own covariance
    assert np.all(np.abs(predicted / fit.stderr - 1) < 0.3), (predicted, fit.stderr)
    assert res.n_points == 57 and res.motion_s > 10 and res.acquisition_s > 0


def test_planner_finds_the_fastest_scan_reaching_the_target() -> None:
    from instrument.plans.tradeoff import ScanOption, fastest_for_target, pareto_front, sweep

    setup = ScanSetup(power_w=2e-8, fill=0.5)
    spec, profile, prior, det = _planner_inputs(setup, SAMPLES[1])
    options = [ScanOption(s, c, f) for s in (10.0, 20.0) for c in (1e3, 1e4, 1e5)
               for f in (1, 4)]
    results = sweep(spec, profile, options, prior=prior, det=det)
    front = pareto_front(results, "ggx.alpha")
    durations = [r.duration_s for r in front]
    sigmas = [r.sigma["ggx.alpha"] for r in front]
    assert durations == sorted(durations) and sigmas == sorted(sigmas, reverse=True)
    target = float(np.median([r.sigma["ggx.alpha"] for r in results]))
    best = fastest_for_target(results, "ggx.alpha", target)
    assert best is not None and best.sigma["ggx.alpha"] <= target
    assert all(r.duration_s >= best.duration_s for r in results
               if r.sigma["ggx.alpha"] <= target)
    assert best in front
    assert fastest_for_target(results, "ggx.alpha", 1e-12) is None
    # more frames and longer caps never predict a larger σ at the same angles
    by = {(r.option.theta_r_step_deg, r.option.max_exposure_us, r.option.frames): r
          for r in results}
    assert by[(10.0, 1e4, 4)].sigma["ggx.alpha"] < by[(10.0, 1e4, 1)].sigma["ggx.alpha"]
    assert by[(10.0, 1e5, 1)].sigma["ggx.alpha"] <= by[(10.0, 1e3, 1)].sigma["ggx.alpha"]


def test_plan_target_uncertainty_hook(capsys) -> None:
    """The function ``scatterlab plan --target-uncertainty`` calls, on the sim bench."""
    import argparse

    from instrument.bench.profile import load_profile
    from instrument.cli._planner import add_arguments, run_from_args
    from instrument.plans import load_plan

    p = argparse.ArgumentParser()
    add_arguments(p)
    root = Path(__file__).resolve().parents[4]
    spec = load_plan(root / "examples" / "brdf_inplane.toml")
    args = p.parse_args(["--target-uncertainty", "5e-5", "--readout-s", "0.02"])
    assert run_from_args(args, spec, load_profile("sim")) == 0
    out = capsys.readouterr().out
    assert "Pareto front" in out and "fastest:" in out and "ggx.alpha" in out
    args = p.parse_args(["--target-uncertainty", "1e-9"])
    assert run_from_args(args, spec, load_profile("sim")) == 1
    assert "no candidate reaches" in capsys.readouterr().out
    args = p.parse_args(["--target-uncertainty", "1e-3", "--target-param", "nope"])
    assert run_from_args(args, spec, load_profile("sim")) == 2


@pytest.mark.parametrize(("prior", "says"), [
    ("lambert:x", "must be numbers"),
    ("lambert:0.5,0.2", "takes 1 parameters"),
    ("nosuch:1", "unknown BRDF model"),
])
def test_plan_prior_errors_name_the_option(prior: str, says: str) -> None:
    from instrument.cli._planner import _parse_prior

    with pytest.raises((ValueError, KeyError), match=says):
        _parse_prior(prior)
