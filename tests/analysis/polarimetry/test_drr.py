"""DRR and PEM reduction: identities from noiseless data, pulls with noise, input checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.polarimetry import (
    PolarimetryInputError,
    analyser_row,
    condition_number,
    drr_angles,
    generator_stokes,
    instrument_matrix,
    linear_polariser,
    linear_retarder,
    normalise,
    pem_instrument_rows,
    reduce,
)
from tests.analysis.polarimetry.synth import QWP, drr_w, measure

SAMPLES = {
    "air": np.eye(4),
    "polariser_0": linear_polariser(0.0),
    "polariser_30": linear_polariser(math.radians(30)),
    "qwp_20": linear_retarder(math.radians(20), QWP),
}


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_noiseless_drr_recovers_sample_exactly(name):
    w = drr_w(36)
    est = reduce(w @ SAMPLES[name].ravel(), 1e-3, w)
    np.testing.assert_allclose(est.m, SAMPLES[name], atol=1e-12)
    assert est.dof == 20 and est.chi2 < 1e-12


def test_row_major_vec_convention():
    # row k, column 4i+j multiplies M[i, j]: a_i g_j
    g, a = drr_angles(16)
    w = instrument_matrix(g, a, psg_retardance=QWP, psa_retardance=QWP)
    m = np.zeros((4, 4))
    m[1, 2] = 1.0
    expected = [analyser_row(ta, QWP)[1] * generator_stokes(tg, QWP)[2]
                for tg, ta in zip(g, a, strict=True)]
    np.testing.assert_allclose(w @ m.ravel(), expected, atol=1e-15)


def test_normalised_matrix_and_its_covariance():
    w = drr_w(36)
    m = 0.4 * linear_polariser(math.radians(30))
    est = reduce(w @ m.ravel(), 1e-3, w)
    np.testing.assert_allclose(est.m_normalised, m / m[0, 0], atol=1e-12)
    assert est.sigma_normalised[0, 0] == 0.0
    assert np.all(est.sigma_normalised.ravel()[1:] > 0)


def test_the_normalised_m00_has_no_variance_whatever_the_rounding():
    """n00 = m00/m00 ≡ 1: its row and column of the covariance are zero for every m00,
    where 1/m00 − m00/m00² rounds to ±1 ulp for some (seen: σ = 1.8e-18 from an SVD whose
    m00 differed in the last bit)."""
    rng = np.random.default_rng(19)
    cov = np.eye(16) + 0.1
    for m00 in rng.uniform(1e-3, 2.0, 500):
        m = rng.uniform(-1.0, 1.0, (4, 4))
        m[0, 0] = m00
        mn, cn = normalise(m, cov)
        assert mn[0, 0] == 1.0
        assert not np.any(cn[0]) and not np.any(cn[:, 0])


def test_pulls_are_standard_normal_over_seeds():
    w = drr_w(36)
    truth = linear_retarder(math.radians(20), QWP) @ linear_polariser(math.radians(10))
    sigma = 2e-3
    pulls, chi2 = [], []
    for seed in range(200):
        est = reduce(measure(w, truth, sigma, np.random.default_rng(seed)), sigma, w)
        pulls.append(((est.m - truth) / est.sigma).ravel())
        chi2.append(est.chi2)
    p = np.array(pulls)
    # 200 draws per element: the mean has σ = 0.071 and the std σ ≈ 0.05; 4σ bounds
    assert np.all(np.abs(p.mean(axis=0)) < 0.29)
    assert np.all(np.abs(p.std(axis=0) - 1.0) < 0.21)
    # χ² with 20 dof: mean 20, σ of the mean √40/√200 = 0.45
    assert abs(np.mean(chi2) - 20.0) < 1.8


def test_normalised_pulls_match_their_propagated_sigma():
    w = drr_w(36)
    truth = 0.5 * linear_polariser(math.radians(30))
    sigma = 1e-3
    pulls = []
    for seed in range(200):
        est = reduce(measure(w, truth, sigma, np.random.default_rng(1000 + seed)), sigma, w)
        n = truth / truth[0, 0]
        pulls.append((est.m_normalised - n).ravel()[1:] / est.sigma_normalised.ravel()[1:])
    p = np.array(pulls)
    assert np.all(np.abs(p.mean(axis=0)) < 0.29)
    assert np.all(np.abs(p.std(axis=0) - 1.0) < 0.21)


def test_condition_number_optimum_near_smith_retardance():
    # Smith 2002 (Appl. Opt. 41, 2488): the DRR's condition number is smallest near a
    # retardance of 127° (2.2 rad) for the 1:5 angle ratio; a quarter wave is worse.
    g, a = drr_angles(36)
    deltas = np.radians(np.arange(100.0, 160.0, 0.25))
    cond = [condition_number(instrument_matrix(g, a, psg_retardance=d, psa_retardance=d))
            for d in deltas]
    best = math.degrees(float(deltas[int(np.argmin(cond))]))
    assert 125.0 <= best <= 134.0
    qwp = condition_number(drr_w(36))
    assert qwp > min(cond) * 1.2


def test_condition_number_independent_of_steps_beyond_the_harmonics():
    # the normalised W^T W is a sum of harmonics up to 24θ; with ≥ 25 equal steps the
    # sums are exact, so the condition number no longer depends on the step count
    c = [condition_number(drr_w(n)) for n in (25, 36, 72)]
    assert c[1] == pytest.approx(c[0], rel=1e-9) and c[2] == pytest.approx(c[0], rel=1e-9)


def test_equal_steps_below_25_alias_except_23():
    # harmonics up to 24θ alias with fewer than 25 equal steps over 180° (drr_angles doc)
    ranks = {n: condition_number(drr_w(n, math.radians(127))) for n in range(16, 26)}
    assert [n for n, c in ranks.items() if math.isfinite(c)] == [23, 25]
    with pytest.raises(PolarimetryInputError, match="rank"):
        w16 = drr_w(16)
        reduce(np.zeros(16), 1.0, w16)


def test_too_few_steps_is_a_typed_error():
    with pytest.raises(PolarimetryInputError) as err:
        drr_angles(15)
    assert err.value.argument == "steps"
    g, a = drr_angles(16)
    w = instrument_matrix(g[:15], a[:15], psg_retardance=QWP, psa_retardance=QWP)
    with pytest.raises(PolarimetryInputError, match="rank") as err:
        reduce(np.zeros(15), 1.0, w)
    assert err.value.argument == "w"


def test_repeated_rows_are_rank_deficient():
    g, a = drr_angles(16)
    w = instrument_matrix(np.tile(g[:8], 4), np.tile(a[:8], 4), psg_retardance=QWP,
                          psa_retardance=QWP)
    with pytest.raises(PolarimetryInputError, match="rank"):
        reduce(np.zeros(32), 1.0, w)
    assert condition_number(w) == math.inf


@settings(max_examples=30, deadline=None)
@given(st.integers(max_value=15))
def test_drr_angles_rejects_fewer_than_16_steps(steps):
    with pytest.raises(PolarimetryInputError):
        drr_angles(steps)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 35), st.sampled_from([math.nan, math.inf, -math.inf]),
       st.sampled_from(["intensities", "sigmas"]))
def test_non_finite_data_named(index, bad, which):
    w = drr_w(36)
    data = {"intensities": np.ones(36), "sigmas": np.ones(36)}
    data[which][index] = bad
    with pytest.raises(PolarimetryInputError) as err:
        reduce(data["intensities"], data["sigmas"], w)
    assert err.value.argument == which


def test_non_positive_sigma_rejected():
    w = drr_w(36)
    with pytest.raises(PolarimetryInputError, match="> 0"):
        reduce(np.ones(36), 0.0, w)


def _pem_w(amplitude: float) -> np.ndarray:
    # analysers spanning I, Q, U, V: polariser at 0, 45, 90 and a QWP-polariser for V
    analysers = np.array([analyser_row(0.0, 0.0, p) for p in (0.0, 45.0, 90.0)]
                         + [analyser_row(45.0, QWP, 0.0)])
    # two generator settings: PEM at 45° after a polariser at 0° (I, Q, V) and
    # PEM at 0° after a polariser at 45° (I, U, V)
    return np.vstack([
        pem_instrument_rows(analysers, amplitude_rad=amplitude),
        pem_instrument_rows(analysers, amplitude_rad=amplitude, pem_axis_deg=0.0,
                            polariser_deg=45.0)])


def test_pem_rows_match_time_average_of_modulated_signal():
    amp = 2.405
    w = _pem_w(amp)
    m = linear_retarder(math.radians(25), 1.0) @ linear_polariser(math.radians(60), 0.9)
    a_row = analyser_row(0.0, 0.0, 45.0)
    # numerical Fourier analysis of I(t) over one PEM period
    t = np.linspace(0.0, 2 * math.pi, 4096, endpoint=False)
    intens = np.array([a_row @ m @ linear_retarder(math.pi / 4, amp * math.sin(x))
                       @ linear_polariser(0.0) @ np.array([1.0, 0, 0, 0]) for x in t])
    dc = intens.mean()
    # RMS amplitude of a Fourier component b·sin t is b/√2, with b = 2·mean(I sin t)
    f1 = math.sqrt(2) * np.mean(intens * np.sin(t))
    f2 = math.sqrt(2) * np.mean(intens * np.cos(2 * t))
    rows = w[3:6] @ m.ravel()  # analyser 1 (45°), first generator setting
    assert rows[0] == pytest.approx(dc, abs=1e-12)
    assert rows[1] == pytest.approx(f1, abs=1e-12)
    assert rows[2] == pytest.approx(f2, abs=1e-12)


def test_pem_data_reduce_through_reduce():
    w = _pem_w(2.405)
    assert condition_number(w) < 50
    truth = linear_retarder(math.radians(25), 1.0) @ linear_polariser(math.radians(60), 0.9)
    est = reduce(w @ truth.ravel(), 1e-3, w)
    np.testing.assert_allclose(est.m, truth, atol=1e-12)


def test_single_pem_setting_cannot_see_u_columns():
    analysers = np.array([analyser_row(0.0, 0.0, p) for p in (0.0, 45.0, 90.0)]
                         + [analyser_row(45.0, QWP, 0.0)])
    w = pem_instrument_rows(analysers, amplitude_rad=2.405)
    with pytest.raises(PolarimetryInputError, match="rank"):
        reduce(np.zeros(len(w)), 1.0, w)


def test_vectorised_instrument_matrix_equals_element_products():
    rng = np.random.default_rng(2)
    g, a = rng.uniform(-180, 180, 20), rng.uniform(-180, 180, 20)
    w = instrument_matrix(g, a, psg_retardance=1.9, psa_retardance=2.3,
                          psg_polariser_deg=7.0, psa_polariser_deg=-4.0)
    for k in range(20):
        gen = (linear_retarder(math.radians(g[k]), 1.9) @ linear_polariser(math.radians(7.0))
               @ np.array([1.0, 0, 0, 0]))
        ana = (linear_polariser(math.radians(-4.0)) @ linear_retarder(math.radians(a[k]), 2.3))[0]
        np.testing.assert_allclose(w[k], np.outer(ana, gen).ravel(), atol=1e-15)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40))
def test_mismatched_retarder_angle_arrays_named(n_g, n_a):
    if n_g == n_a:
        return
    with pytest.raises(PolarimetryInputError) as err:
        instrument_matrix(np.zeros(n_g), np.zeros(n_a), psg_retardance=QWP,
                          psa_retardance=QWP)
    assert err.value.argument == "psa_retarder_deg"


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(["amplitude_rad", "pem_axis_deg", "polariser_deg"]),
       st.sampled_from([math.nan, math.inf, -math.inf]))
def test_pem_non_finite_settings_named(name, bad):
    kwargs = {"amplitude_rad": 2.405, "pem_axis_deg": 45.0, "polariser_deg": 0.0}
    kwargs[name] = bad
    with pytest.raises(PolarimetryInputError) as err:
        pem_instrument_rows(np.array([[0.5, 0.5, 0.0, 0.0]]), **kwargs)
    assert err.value.argument == name


def test_dark_matrix_has_no_normalised_form_and_says_so():
    w = drr_w(36)
    est = reduce(np.zeros(36) - 1e-6, 1e-3, w)  # m00 slightly negative: noise in the dark
    assert not est.normalised_valid
    assert np.all(est.m_normalised == 0) and np.all(np.isfinite(est.cov_normalised))
    assert reduce(w @ np.eye(4).ravel(), 1e-3, w).normalised_valid
