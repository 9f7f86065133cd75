"""The speed/accuracy trade of a dual-rotating-retarder scan: κ and the normalised Mueller
elements' σ against the steps per geometry and the engine's duration estimate, its Pareto
front (the scalar trade's function) and what ``scatterlab plan`` prints and draws."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from analysis.polarimetry.drr import drr_angles, instrument_matrix, reduce
from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.plans.planfile import parse_plan
from instrument.plans.polarimetric_tradeoff import (
    PolarimetricOption,
    element_sigma,
    polarimetric_sweep,
    predict_polarimetric,
)
from instrument.plans.tradeoff import pareto_front

ROOT = Path(__file__).resolve().parents[3]
PLAN = ROOT / "examples" / "brdf_polarimetric.toml"


@pytest.fixture(scope="module")
def sweep():
    spec = parse_plan(PLAN.read_text(encoding="utf-8"))
    return polarimetric_sweep(spec, load_profile("sim-polarimetric"),
                              [PolarimetricOption(k) for k in (25, 36, 48, 72)])


def test_more_steps_take_longer_and_never_raise_sigma(sweep):
    steps = [r.option.steps for r in sweep]
    t = np.array([r.duration_s for r in sweep])
    mean = np.array([r.sigma["sigma_mean"] for r in sweep])
    worst = np.array([r.sigma["sigma_max"] for r in sweep])
    assert np.all(np.diff(t) > 0), t
    assert np.all(np.diff(mean) <= 0) and np.all(np.diff(worst) <= 0), (mean, worst)
    # 4 geometries × K steps (and nothing else: the plan's darks are per point)
    assert [r.n_points for r in sweep] == [4 * k for k in steps]
    # at ≥ 25 equal steps κ does not change (13 for quarter-wave retarders, Smith 2002)
    # and σ falls as 1/√K: σ·√K is the same for every K
    assert all(r.kappa == pytest.approx(13.0, abs=0.5) for r in sweep)
    np.testing.assert_allclose(mean * np.sqrt(steps), mean[0] * math.sqrt(25), rtol=0.02)
    # the meter's floor of sim-polarimetric (2.6e-10 W against the 1e-7 W reading the
    # planner assumes: 2.6e-3 of it) dominates its 1e-4 relative noise; κ = 13 bounds how
    # far the reduction can amplify it, either way
    floor = 2.6e-10 / 1e-7
    assert floor / 13 < mean[0] < 13 * floor, mean[0]
    # every step count is on the front: each is slower and more accurate than the last
    front = pareto_front(sweep, "sigma_mean")
    assert [r.option.steps for r in front] == steps


def test_the_predicted_sigma_is_the_scatter_of_reduced_matrices():
    # 400 seeded draws of readings with the predicted noise, reduced: their scatter
    # matches the prediction within the sampling error of a σ from 400 draws (3.5 %; 5σ)
    g, a = drr_angles(36)
    w = instrument_matrix(g, a, psg_retardance=math.pi / 2, psa_retardance=math.pi / 2)
    prior = np.eye(4)
    prior[0, 1] = prior[1, 0] = 0.4  # a partial polariser
    rel, floor = 1e-3, 3e-4
    predicted = element_sigma(w, prior, rel, floor)
    clean = w @ prior.ravel()
    sigma = np.hypot(rel * clean, floor * clean.mean())
    rng = np.random.default_rng(11)
    draws = np.array([
        reduce(clean + sigma * rng.standard_normal(clean.size), sigma, w).m_normalised
        for _ in range(400)])
    ratio = draws.std(axis=0, ddof=1).ravel()[1:] / predicted.ravel()[1:]
    assert np.all(np.abs(ratio - 1.0) < 5 * 0.035), np.round(ratio, 3)
    assert predicted[0, 0] == 0.0


def test_a_plan_without_polarimetry_is_refused_with_its_name():
    spec = parse_plan(PLAN.read_text(encoding="utf-8").split("[polarimetry]")[0])
    with pytest.raises(ValueError, match="no \\[polarimetry\\] table"):
        predict_polarimetric(spec, load_profile("sim-polarimetric"), PolarimetricOption(36))
    with pytest.raises(ValueError, match="sends no light to the meter"):
        g, a = drr_angles(36)
        element_sigma(instrument_matrix(g, a, psg_retardance=1.0, psa_retardance=1.0),
                      np.zeros((4, 4)), 1e-4)


def test_scatterlab_plan_prints_the_front_and_draws_it(capsys, tmp_path):
    assert main(["plan", str(PLAN), "--bench", "sim-polarimetric", "--out",
                 str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "the Pareto front:" in out
    rows = [line.split() for line in out.splitlines()
            if line.startswith("    ") and line.split()[0].isdigit()]
    steps = [int(r[0]) for r in rows]
    assert steps == [25, 30, 36, 48, 60, 72, 96]
    assert [int(r[1]) for r in rows] == [4 * k for k in steps]
    mine = next(line for line in out.splitlines() if "← this plan" in line)
    assert mine.split()[0] == "36"
    png = tmp_path / "brdf_polarimetric_tradeoff.png"
    assert f"trade-off picture: {png}" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
