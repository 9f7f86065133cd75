"""Partial polarisers (finite extinction ε) in the DRR's instrument matrix and calibration.

The readings are built from :func:`analysis.polarimetry.elements.diattenuator` (q = 1,
r = ε) matrix by matrix, a path independent of the vectorised W under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from analysis.polarimetry import (
    PolarimetryInputError,
    diattenuator,
    drr_angles,
    instrument_matrix,
    linear_polariser,
    linear_retarder,
    reduce,
)
from analysis.polarimetry.calibration import ReferenceScan, calibrate_drr
from analysis.polarimetry.drr import generator_extinction

QWP = math.pi / 2
#: Hidden DRR: retarder offsets (deg), retardances (rad), analyser polariser (deg).
HIDDEN = np.array([2.0, -1.0, QWP * 1.05, QWP * 0.95, 0.5])
EXTINCTION = 1e-5  # a Glan–Taylor prism's datasheet value


def _explicit_w(g_deg, a_deg, d_g, d_a, p_a_deg, eps, eps_a=None):
    """W row by row from 4×4 Mueller matrices: ``a_k = [D_ε(p_a) Ret]_0``,
    ``g_k = Ret D_ε(0) (1, 0, 0, 0)`` (the analyser's ε is ``eps_a`` where given)."""
    pol_g = diattenuator(0.0, 1.0, eps)
    pol_a = diattenuator(math.radians(p_a_deg), 1.0, eps if eps_a is None else eps_a)
    rows = []
    for tg, ta in zip(g_deg, a_deg, strict=True):
        gen = linear_retarder(math.radians(tg), d_g) @ pol_g @ np.array([1.0, 0, 0, 0])
        ana = (pol_a @ linear_retarder(math.radians(ta), d_a))[0]
        rows.append(np.outer(ana, gen).ravel())
    return np.array(rows)


def test_zero_extinction_is_todays_ideal_polariser_w_exactly():
    g, a = drr_angles(36)
    kw = {"psg_retardance": 1.4, "psa_retardance": 1.7, "psg_polariser_deg": 0.3,
          "psa_polariser_deg": -0.6}
    ideal = instrument_matrix(g, a, **kw)
    np.testing.assert_array_equal(
        instrument_matrix(g, a, psg_extinction=0.0, psa_extinction=0.0, **kw), ideal)
    # and the ideal W is the ideal polariser's (linear_polariser), element by element
    rows = [np.outer((linear_polariser(math.radians(-0.6)) @ linear_retarder(
        math.radians(ta), 1.7))[0], linear_retarder(math.radians(tg), 1.4)
        @ linear_polariser(math.radians(0.3)) @ np.array([1.0, 0, 0, 0])).ravel()
        for tg, ta in zip(g, a, strict=True)]
    np.testing.assert_allclose(ideal, rows, atol=1e-15)


@given(st.floats(0.0, 0.5), st.floats(0.0, 0.5))
def test_partial_polarisers_w_is_the_diattenuators(eps_g, eps_a):
    g, a = drr_angles(25)
    w = instrument_matrix(g + 2.0, a - 1.0, psg_retardance=1.5, psa_retardance=1.6,
                          psa_polariser_deg=0.5, psg_extinction=eps_g, psa_extinction=eps_a)
    np.testing.assert_allclose(w, _explicit_w(g + 2.0, a - 1.0, 1.5, 1.6, 0.5, eps_g, eps_a),
                               atol=1e-14)


@pytest.mark.parametrize("bad", [-1e-9, 1.0, 2.0, math.nan, math.inf])
def test_an_extinction_outside_0_to_1_names_its_arm(bad):
    g, a = drr_angles(25)
    for arm in ("psg_extinction", "psa_extinction"):
        with pytest.raises(PolarimetryInputError) as err:
            instrument_matrix(g, a, psg_retardance=QWP, psa_retardance=QWP, **{arm: bad})
        assert err.value.argument == arm


def _pull_means(eps_model: float, n_draws: int) -> np.ndarray:
    """Mean pull of the 15 normalised elements of air and a retarder over seeded draws
    of readings taken through ε = 1e-5 polarisers (relative noise 10⁻⁵, 36 steps)."""
    g, a = drr_angles(36)
    w_true = _explicit_w(g, a, QWP, QWP, 0.0, EXTINCTION)
    w_model = instrument_matrix(g, a, psg_retardance=QWP, psa_retardance=QWP,
                                psg_extinction=eps_model, psa_extinction=eps_model)
    out = []
    for m in (np.eye(4), linear_retarder(math.radians(30.0), 1.2)):
        clean = w_true @ m.ravel()
        sigma = 1e-5 * np.abs(clean).max()
        pulls = []
        for seed in range(n_draws):
            y = clean + sigma * np.random.default_rng(seed).standard_normal(clean.size)
            est = reduce(y, sigma, w_model)
            pulls.append(((est.m_normalised - m) / np.where(
                est.sigma_normalised > 0, est.sigma_normalised, 1.0)).ravel()[1:])
        out.append(np.mean(pulls, axis=0))
    return np.concatenate(out)


def test_modelled_extinction_unbiased_where_the_ideal_model_is_biased():
    n = 100
    # with ε in W the model is exact: each mean pull is N(0, 1/√N)
    assert np.max(np.abs(_pull_means(EXTINCTION, n))) < 3.0 / math.sqrt(n)
    # the ideal model scales the normalised elements by (1 − 2ε) to (1 − 4ε): at this
    # noise that is about 1.3σ on the diagonal of air, far outside the draws' spread
    assert np.max(np.abs(_pull_means(0.0, n))) > 10.0 / math.sqrt(n)


def _scans(rng: np.random.Generator, rel_noise: float) -> list[ReferenceScan]:
    g, a = drr_angles(36)
    w = _explicit_w(g + HIDDEN[0], a + HIDDEN[1], HIDDEN[2], HIDDEN[3], HIDDEN[4],
                    EXTINCTION)
    refs = (("air", np.eye(4), 0.0, 0.0),
            ("polariser", linear_polariser(math.radians(3.0)), 0.0, 0.0),
            ("retarder", linear_retarder(math.radians(32.0), 1.5), 30.0, QWP))
    scans = []
    for kind, m, ang, ret in refs:
        clean = 0.9 * w @ m.ravel()
        sigma = rel_noise * np.abs(clean).max()
        scans.append(ReferenceScan(kind=kind, intensities=clean + sigma * rng.standard_normal(
            clean.size), sigmas=np.full(clean.size, sigma), psg_retarder_deg=g,
            psa_retarder_deg=a, angle_deg=ang, retardance=ret))
    return scans


def _mahalanobis2(eps_model: float, seed: int) -> tuple[float, float]:
    scans = _scans(np.random.default_rng(seed), 1e-5)
    cal = calibrate_drr(scans, psg_retardance=QWP, psa_retardance=QWP,
                        psg_extinction=eps_model, psa_extinction=eps_model)
    d = cal.params - HIDDEN
    return float(d @ np.linalg.solve(cal.cov, d)), cal.chi2 / cal.dof


def test_calibration_with_modelled_extinction_lands_on_the_hidden_optics():
    seeds = range(4)
    with_eps = [_mahalanobis2(EXTINCTION, s) for s in seeds]
    # Mahalanobis² of 5 parameters ~ χ²(5): the 99.9 % quantile is 20.5 per seed; the
    # sum over 4 seeds ~ χ²(20), 99.9 % quantile 45.3
    assert all(d2 < 20.5 for d2, _ in with_eps), with_eps
    assert sum(d2 for d2, _ in with_eps) < 45.3
    assert all(abs(red - 1.0) < 5.0 * math.sqrt(2.0 / 100) for _, red in with_eps)
    # the ideal-polariser model fails the same test (sum 75, χ²/dof 1.2 to 1.8)
    ideal = [_mahalanobis2(0.0, s) for s in seeds]
    assert sum(d2 for d2, _ in ideal) > 45.3, ideal


def test_calibration_keeps_the_extinction_it_assumed():
    scans = _scans(np.random.default_rng(1), 1e-3)
    cal = calibrate_drr(scans, psg_retardance=QWP, psa_retardance=QWP,
                        psg_extinction=1e-5, psa_extinction=2e-5)
    assert (cal.psg_extinction, cal.psa_extinction) == (1e-5, 2e-5)
    g, a = drr_angles(36)
    np.testing.assert_array_equal(
        cal.instrument_matrix(g, a),
        instrument_matrix(g + cal.params[0], a + cal.params[1], psg_retardance=cal.params[2],
                          psa_retardance=cal.params[3], psa_polariser_deg=cal.params[4],
                          psg_extinction=1e-5, psa_extinction=2e-5))
    with pytest.raises(PolarimetryInputError) as err:
        calibrate_drr(scans, psg_retardance=QWP, psa_retardance=QWP, psa_extinction=1.0)
    assert err.value.argument == "psa_extinction"


@given(st.floats(0.0, 0.999), st.floats(0.0, 1.0))
def test_a_polarised_source_leaks_through_the_generator_as_a_smaller_extinction(eps, dop):
    # the partial polariser on (1, s, 0, 0) sends the state of ε' on an unpolarised source
    sent = diattenuator(0.0, 1.0, eps) @ np.array([1.0, dop, 0.0, 0.0])
    e_eff = generator_extinction(eps, dop)
    assert sent[1] / sent[0] == pytest.approx((1.0 - e_eff) / (1.0 + e_eff), abs=1e-12)
    assert generator_extinction(eps) == eps


def test_generator_extinction_input_checks():
    with pytest.raises(PolarimetryInputError) as err:
        generator_extinction(1e-5, 1.5)
    assert err.value.argument == "source_dop"
    with pytest.raises(PolarimetryInputError) as err:
        generator_extinction(-1.0, 0.5)
    assert err.value.argument == "extinction"
