"""Lu–Chipman decomposition: known factors, and linear uncertainties against Monte Carlo."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from analysis.polarimetry import (
    PolarimetryInputError,
    depolariser,
    diattenuator,
    linear_polariser,
    linear_retarder,
    reduce,
)
from analysis.polarimetry.decomposition import PARAMETERS, decompose
from tests.analysis.polarimetry.synth import drr_w, measure


def _composite() -> np.ndarray:
    return (depolariser(1.0, 0.6) @ linear_retarder(math.radians(30), 1.0)
            @ diattenuator(math.radians(10), 0.9, 0.3))


def test_factors_of_a_known_product():
    d = decompose(_composite())
    np.testing.assert_allclose(d.m_depolariser @ d.m_retarder @ d.m_diattenuator,
                               _composite(), atol=1e-12)
    assert d.value("transmittance") == pytest.approx(0.6)
    assert d.value("diattenuation") == pytest.approx(0.5)     # (q − r)/(q + r)
    assert d.value("retardance") == pytest.approx(1.0)
    assert d.value("retardance_axis_deg") == pytest.approx(30.0)
    assert d.value("depolarisation_power") == pytest.approx(0.4)
    np.testing.assert_allclose(d.diattenuation_vector,
                               0.5 * np.array([math.cos(math.radians(20)),
                                               math.sin(math.radians(20)), 0.0]), atol=1e-12)


@pytest.mark.parametrize("deg", [-60.0, 0.0, 45.0, 80.0])
def test_pure_retarder_axis_is_its_fast_axis(deg):
    d = decompose(linear_retarder(math.radians(deg), 2.0))
    t = math.radians(deg)
    np.testing.assert_allclose(d.retardance_axis, [math.cos(2 * t), math.sin(2 * t), 0.0],
                               atol=1e-12)
    assert d.value("retardance") == pytest.approx(2.0)
    assert d.value("diattenuation") == pytest.approx(0.0, abs=1e-15)
    assert d.value("depolarisation_power") == pytest.approx(0.0, abs=1e-12)


def test_identity_and_ideal_depolariser():
    d = decompose(np.eye(4))
    np.testing.assert_allclose(d.params, [1, 0, 0, 0, 0], atol=1e-12)
    assert decompose(depolariser(0.3)).value("depolarisation_power") == pytest.approx(1.0)


def test_linear_sigma_matches_monte_carlo():
    w = drr_w(36, math.radians(127))
    truth = _composite()
    noise = 2e-3
    est0 = reduce(w @ truth.ravel(), noise, w)
    lin = decompose(est0.m, est0.cov)
    assert lin.sigma is not None
    rng = np.random.default_rng(42)
    draws = np.array([decompose(reduce(measure(w, truth, noise, rng), noise, w).m).params
                      for _ in range(400)])
    mc_sigma = draws.std(axis=0, ddof=1)
    # 400 draws: the MC σ is known to ±3.5 % (1σ); 15 % allows 4σ
    np.testing.assert_allclose(lin.sigma, mc_sigma, rtol=0.15)
    # and the estimates scatter about the truth within their σ
    assert np.all(np.abs(draws.mean(axis=0) - decompose(truth).params) < 4 * mc_sigma / 20)


def test_uncertainty_needs_covariance():
    with pytest.raises(ValueError, match="without a covariance"):
        decompose(np.eye(4)).uncertainty("retardance")
    d = decompose(np.eye(4) * 0.5, np.eye(16) * 1e-6)
    assert all(d.uncertainty(p) >= 0 for p in PARAMETERS)


def test_ideal_polariser_is_a_typed_error():
    with pytest.raises(PolarimetryInputError, match="D = 1") as err:
        decompose(linear_polariser(0.3))
    assert err.value.argument == "m"


@given(st.integers(0, 15), st.sampled_from([math.nan, math.inf]))
def test_non_finite_matrix_named(index, bad):
    m = np.eye(4).ravel()
    m[index] = bad
    with pytest.raises(PolarimetryInputError) as err:
        decompose(m.reshape(4, 4))
    assert err.value.argument == "m"
