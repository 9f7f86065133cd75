"""Cloude coherency-matrix test: non-physical matrices flagged, physical ones at the stated rate."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.polarimetry import (
    PolarimetryInputError,
    depolariser,
    diattenuator,
    linear_retarder,
    reduce,
)
from analysis.polarimetry.realizability import (
    coherency_matrix,
    mueller_from_coherency,
    realizability,
)
from tests.analysis.polarimetry.synth import drr_w, measure


def _elliptic_element() -> np.ndarray:
    return (linear_retarder(math.radians(20), 1.1) @ linear_retarder(math.radians(65), 0.7)
            @ diattenuator(math.radians(5), 0.9, 0.2))


def test_pure_element_has_one_non_zero_eigenvalue():
    m = _elliptic_element()
    lam = np.linalg.eigvalsh(coherency_matrix(m))
    np.testing.assert_allclose(lam[:3], 0.0, atol=1e-12)
    assert lam[3] == pytest.approx(m[0, 0])
    np.testing.assert_allclose(mueller_from_coherency(coherency_matrix(m)), m, atol=1e-14)


def test_ideal_depolariser_has_equal_eigenvalues():
    np.testing.assert_allclose(np.linalg.eigvalsh(coherency_matrix(depolariser(1.0))), 0.25)


def test_non_physical_matrix_is_flagged():
    # diag(1, 1, 1, −1): a "mirror" of V alone, not a convex sum of Jones systems
    m = np.diag([1.0, 1.0, 1.0, -1.0])
    res = realizability(m, np.eye(16) * 1e-6)
    assert res.eigenvalues[0] == pytest.approx(-0.5)
    assert res.flagged and res.p_value < 1e-3


def test_slightly_non_physical_measurement_flagged_with_its_noise():
    w = drr_w(36, math.radians(127))
    m = depolariser(1.0, 0.5)
    m[1, 1] = 1.1  # pushes one eigenvalue to −0.025
    est = reduce(measure(w, m, 1e-3, np.random.default_rng(5)), 1e-3, w)
    res = realizability(est.m, est.cov)
    assert res.flagged
    # …and nothing was altered: the estimate keeps its non-physical element
    assert est.m[1, 1] == pytest.approx(1.1, abs=0.01)


@pytest.mark.parametrize(("name", "truth", "max_rate"), [
    # at the boundary (three zero eigenvalues) the rate is ≈ alpha; inside, ≤ alpha
    ("pure", _elliptic_element(), 0.05),
    ("partially_depolarising", depolariser(1.0, 0.6) @ linear_retarder(0.4, 1.0), 0.05),
])
def test_false_flag_rate_of_physical_matrices(name, truth, max_rate):
    w = drr_w(36, math.radians(127))
    noise = 2e-3
    flags = []
    for seed in range(300):
        est = reduce(measure(w, truth, noise, np.random.default_rng(seed)), noise, w)
        flags.append(realizability(est.m, est.cov, alpha=0.05, n_boot=400,
                                   seed=seed).flagged)
    rate = float(np.mean(flags))
    # binomial σ for 300 trials at 5 %: 1.26 %; allow 4σ above the level
    assert rate <= max_rate + 0.05
    if name == "pure":
        assert rate >= 0.01  # the test is not vacuous at the boundary


@settings(max_examples=20, deadline=None)
@given(st.sampled_from([0.0, 1.0, -0.1, math.nan]))
def test_bad_alpha_named(alpha):
    with pytest.raises(PolarimetryInputError) as err:
        realizability(np.eye(4), np.eye(16), alpha=alpha)
    assert err.value.argument == "alpha"


def test_bad_covariance_named():
    with pytest.raises(PolarimetryInputError) as err:
        realizability(np.eye(4), np.eye(15))
    assert err.value.argument == "cov"
    asym = np.eye(16)
    asym[0, 1] = 0.5
    with pytest.raises(PolarimetryInputError, match="symmetric"):
        realizability(np.eye(4), asym)
