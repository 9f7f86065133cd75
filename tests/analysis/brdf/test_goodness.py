"""The χ² goodness-of-fit test of analysis.brdf.goodness (ADR 0051)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from analysis.brdf.goodness import goodness_of_fit


def test_a_correct_model_passes_with_its_expected_spread() -> None:
    r = np.random.default_rng(3).standard_normal(57)
    g = goodness_of_fit(r, 3)
    assert g.dof == 54 and g.chi2 == pytest.approx(float(r @ r))
    assert g.expected_spread == pytest.approx(np.sqrt(2 / 54))
    assert g.p_value == pytest.approx(chi2.sf(g.chi2, 54))
    assert g.adequate and not g.too_good
    assert "describes the data" in g.verdict() and "expected 1 ±" in g.summary()
    assert all(abs(x) > 3 for x in g.residuals)  # only genuine 3σ points are named


def test_a_rejected_model_inflates_by_the_birge_ratio_and_names_points() -> None:
    r = 3.0 * np.random.default_rng(4).standard_normal(57)
    r[10] = -40.0
    g = goodness_of_fit(r, 3)
    assert not g.adequate and g.p_value < 1e-3
    assert g.birge_ratio == pytest.approx(np.sqrt(g.chi2 / 54))
    assert g.disagreeing[0] == 10 and g.residuals[0] == -40.0
    assert list(np.abs(g.residuals)) == sorted(np.abs(g.residuals), reverse=True)
    assert g.verdict().startswith("the model does not describe the data")


def test_a_misfit_spread_thin_still_names_the_worst_points() -> None:
    r = np.full(60, 2.5)  # every point 2.5σ off: χ²/ν = 6.7, none above 3
    g = goodness_of_fit(r, 2)
    assert not g.adequate and len(g.disagreeing) == 5


def test_too_good_and_degenerate_cases() -> None:
    g = goodness_of_fit(np.full(100, 0.05), 2)
    assert g.adequate and g.too_good and "too large" in g.verdict()
    nan = goodness_of_fit(np.array([0.1, np.nan, 0.2, 0.3]), 1)
    assert not nan.adequate and nan.disagreeing[0] == 1
    assert not goodness_of_fit(np.zeros(3), 3).adequate  # no degrees of freedom
    with pytest.raises(ValueError):
        goodness_of_fit(np.zeros(5), 1, alpha=0.7)
