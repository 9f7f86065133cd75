"""Hidden-truth closed loops through the engine, the emulated drivers and ``scatterlab
fit`` with a measured polarimeter calibration: the validation matrix (validation.py: air,
a polariser at 0°, 30° and 45°, a quarter-wave plate, the Fresnel dielectric at θi 20°, 50°
and 70° — Brewster's angle, 56.3°, shows in m01/m00 —, a rough metal, a depolarising
diffuser), one seed each; and ``examples/brdf_polarimetric.toml``, whose pBRDF fit
recovers the hidden glass. The ten-seed statistics (fraction within 2σ, pull spread) are
``benchmarks/bench_polarimetric_validation.py``'s. Every test here runs the engine: all
are slow.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from instrument.pipelines.polarimetry.calibration import calibration_folder
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from tests.instrument.pipelines.polarimetry.closed_loop import fast_bench, run_with_truth
from tests.instrument.pipelines.polarimetry.validation import (
    SAMPLES,
    calibrate,
    measure,
    report,
    verdict,
)
from tests.shared_files import made_once

ROOT = Path(__file__).resolve().parents[4]


@pytest.fixture(scope="module")
def calibration(tmp_path_factory) -> Path:
    def make(folder: Path) -> Path:
        return calibrate(folder, None)[1]
    return made_once(tmp_path_factory, "polcal", make)  # once per session


@pytest.mark.slow  # one engine run of 25 steps and two reductions each: 15-40 s
@pytest.mark.parametrize("sample", SAMPLES, ids=[s.name for s in SAMPLES])
def test_the_validation_matrix_with_and_without_the_calibration(calibration, tmp_path,
                                                                sample):
    found = measure(sample, None, tmp_path, calibration)
    # One seed, 15 elements, ten samples: 3σ for all 15 would fail one sample in 25 by
    # chance alone, a third of the matrix's runs. Each sample is held to a one-in-a-
    # thousand chance instead, on both the worst element (4σ: 1 − (1 − 6.3e-5)^15 ≈ 1e-3)
    # and the sum of squares (the χ² of 15 pulls, its 0.999 quantile), so a bias spread
    # over many elements fails as surely as one large pull. The 2σ standard over ten
    # seeds is the benchmark's (BENCHMARKS.md, polarimetric validation).
    pulls = np.asarray(found.calibrated, dtype=float)
    assert np.all(np.abs(pulls) < 4.0), np.round(pulls, 2)
    assert float(np.sum(pulls**2)) < stats.chi2.ppf(0.999, pulls.size), np.round(pulls, 2)
    first, second = verdict(found.calibrated, found.nominal)
    assert first.startswith("calibrated:")
    text = report([found])
    assert text.splitlines()[0] == f"{sample.name} (1 seed):"
    if sample.name == "diffuser":
        # an ideal depolariser: only m00, which the polarimeter's errors keep; the report
        # says the uncalibrated elements do not show them
        assert "not visibly off" in second and second in text
        assert np.max(np.abs(found.m_normalised.ravel()[1:])) < 0.05
        return
    # the dielectric at 20° reflects little light, and its σ hides part of the bias: 3.4 to
    # 6.1σ over ten seeds (3.8 for this one, the profile's seed 2); every other sample is
    # tens of σ off (BENCHMARKS.md, polarimetric validation)
    expected = "marginally off" if sample.name == "dielectric 20°" else "visibly off"
    assert second.endswith(f"— {expected}") and second in text, second
    if sample.name.startswith("dielectric"):
        # Brewster's angle (56.3°) shows: near and beyond it the specular reflection is
        # mostly s light (m01/m00 → −1), at 20° much less so
        m01 = found.m_normalised[0, 1]
        assert (m01 > -0.3) if sample.theta_i < 30.0 else (m01 < -0.5), m01


def test_the_report_judges_pulls_by_the_seeds_pooled():
    rng = np.random.default_rng(7)
    good = rng.standard_normal(15) * 0.5
    first, second = verdict(good, good + 20.0)
    assert first.endswith("— recovered") and second.endswith("— visibly off")
    assert verdict(good + 3.5, good)[0].endswith("NOT recovered")
    assert "not visibly off" in verdict(good, good)[1]
    assert verdict(good, good + 4.0)[1].endswith("— marginally off")
    # ten seeds: one element at 3.2σ of 150 is expected; the fraction and spread judge
    pooled = rng.standard_normal(150)
    pooled[0] = 3.2
    assert verdict(pooled, pooled)[0].endswith("— recovered")
    assert verdict(2.0 * pooled, pooled)[0].endswith("NOT recovered")


@pytest.mark.slow  # the example's 4 geometries × 36 steps: 60-120 s
def test_the_example_plan_fit_recovers_the_hidden_glass(calibration, tmp_path):
    plan = (ROOT / "examples" / "brdf_polarimetric.toml").read_text(encoding="utf-8")
    path, _ = run_with_truth(tmp_path, fast_bench(tmp_path), plan, steps=36)
    shutil.copytree(calibration.parent, calibration_folder(path.parent))
    done = fit_polarimetric_run(path, report=False, write=False)
    assert done.summary["calibrated"]
    assert len(done.points) == 4
    fit = done.summary["pbrdf"]
    # the gate passes: the fit estimates the polarimeter's frame (the generator
    # polariser's hidden 0.3° from the plane of incidence, ADR 0107) with the sample
    assert fit["adequate"], fit["verdict"]
    # four parameters of one seed: 3σ each (at 2σ one run in five fails by chance)
    for k, truth in ((0, 1.5), (2, 0.15), (3, 0.3), (4, 0.3)):
        assert abs(fit["params"][k] - truth) < 3.0 * fit["stderr"][k], (
            fit["param_names"][k], fit["params"][k], fit["stderr"][k])
