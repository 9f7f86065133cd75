"""Lock-in BRDF reduction against synthetic readings from the documented photodiode model
(hw_mocks/sim/photodiode.py: R_V = (√2/π)·R(λ)·G·P), with seeded noise."""

import math

import numpy as np
import pytest

from analysis.brdf.reduction import solid_angle_sr
from analysis.brdf.reduction.lockin import (
    SQUARE_CHOPPER_FUNDAMENTAL_RMS,
    Photodiode,
    expected_lockin_r_v,
    lockin_brdf_absolute,
    lockin_brdf_ratio,
    lockin_gain_u_rel,
    photodiode_from_profile,
    range_covariance_rel,
)

PD = Photodiode((400.0, 700.0), (0.2, 0.45), 0.02, 1e6)
LAM = 550.0
P_I = 1e-3
OMEGA, _ = solid_angle_sr(9.5, 300.0)


def _scan(seed: int, rel_noise: float = 0.01):
    rng = np.random.default_rng(seed)
    tr = np.radians(np.linspace(5, 75, 30))
    ti = np.full(tr.shape, np.radians(30.0))
    pr = np.full(tr.shape, np.pi)
    f_true = 0.4 / np.pi + 2.0 * np.exp(-((tr - ti) / 0.05) ** 2)  # decades of range
    r_true = expected_lockin_r_v(f_true, tr, photodiode=PD, wavelength_nm=LAM,
                                 incident_power_w=P_I, solid_angle=OMEGA)
    u = rel_noise * r_true
    r_meas = r_true + u * rng.standard_normal(r_true.shape)
    sens = np.array([min(s for s in (1e-3, 1e-2, 1e-1, 1.0) if r <= 0.8 * s) for r in r_true])
    return ti, pr, tr, f_true, r_meas, u, sens


def test_chopper_factor_is_the_square_wave_fundamental() -> None:
    # the SR830 manual's example: 2 V pk-pk square wave reads 0.900 V rms (p. 3-3)
    assert pytest.approx(0.9003, abs=1e-4) == 2.0 * SQUARE_CHOPPER_FUNDAMENTAL_RMS
    assert PD.volts_rms_per_watt(550.0) == pytest.approx(math.sqrt(2) / math.pi * 0.325e6)


def test_absolute_route_pulls_within_2_sigma() -> None:
    pulls = []
    for seed in range(20):
        ti, pr, tr, f_true, r, u, sens = _scan(seed)
        pts = lockin_brdf_absolute(r, u, sens, ti, 0 * ti, tr, pr, photodiode=PD,
                                   wavelength_nm=LAM, incident_power_w=P_I,
                                   solid_angle=OMEGA)
        pulls.append((pts.brdf - f_true) / pts.u_stat)
    pulls = np.concatenate(pulls)
    assert abs(pulls.mean()) < 0.1
    assert pulls.std() == pytest.approx(1.0, abs=0.1)
    assert np.mean(np.abs(pulls) < 2) > 0.93


def test_ratio_route_agrees_with_absolute_and_cancels_responsivity() -> None:
    ti, pr, tr, f_true, r, u, sens = _scan(7)
    # direct beam: the whole incident power on the photodiode, read with 0.1 % noise
    r_ref = PD.volts_rms_per_watt(LAM) * P_I
    u_ref = 1e-3 * r_ref
    rat = lockin_brdf_ratio(r, u, sens, ti, 0 * ti, tr, pr, reference_r_v=r_ref,
                            u_reference_r_v=u_ref, reference_sensitivity_v=1.0,
                            solid_angle=OMEGA)
    ab = lockin_brdf_absolute(r, u, sens, ti, 0 * ti, tr, pr, photodiode=PD,
                              wavelength_nm=LAM, incident_power_w=P_I, solid_angle=OMEGA)
    np.testing.assert_allclose(rat.brdf, ab.brdf, rtol=1e-12)
    # a wrong responsivity moves the absolute route, not the ratio route
    wrong = Photodiode((400.0, 700.0), (0.22, 0.495), 0.02, 1e6)
    ab2 = lockin_brdf_absolute(r, u, sens, ti, 0 * ti, tr, pr, photodiode=wrong,
                               wavelength_nm=LAM, incident_power_w=P_I, solid_angle=OMEGA)
    np.testing.assert_allclose(ab2.brdf, ab.brdf / 1.1, rtol=1e-12)
    # the ratio's common scale is the reference's noise; the absolute one the responsivity
    assert rat.u_scale_rel == pytest.approx(1e-3, rel=1e-9)
    assert ab.u_scale_rel == pytest.approx(0.02, rel=1e-9)
    pulls = (rat.brdf - f_true) / rat.u_total
    assert np.mean(np.abs(pulls) < 2) > 0.9


def test_gain_errors_are_shared_per_range_and_cancel_on_the_reference_range() -> None:
    s = np.array([1e-3, 1e-3, 1e-2, 1.0])
    u2 = lockin_gain_u_rel(1e-3)[()] ** 2
    assert u2 == pytest.approx((0.01 / math.sqrt(3)) ** 2)
    cov = range_covariance_rel(s)
    np.testing.assert_allclose(cov, u2 * np.array([[1, 1, 0, 0], [1, 1, 0, 0], [0, 0, 1, 0],
                                                   [0, 0, 0, 1]]))
    cov_r = range_covariance_rel(s, reference_sensitivity_v=1.0)
    assert cov_r[3, 3] == 0.0 and cov_r[0, 3] == 0.0
    assert cov_r[0, 0] == pytest.approx(2 * u2) and cov_r[0, 2] == pytest.approx(u2)
    np.testing.assert_allclose(np.linalg.eigvalsh(cov_r).min(), 0.0, atol=1e-18)


def test_overloaded_readings_are_flagged_not_values() -> None:
    ti, pr, tr, _, r, u, sens = _scan(1)
    over = np.zeros(r.shape, dtype=bool)
    over[4] = True
    pts = lockin_brdf_absolute(r, u, sens, ti, 0 * ti, tr, pr, photodiode=PD,
                               wavelength_nm=LAM, incident_power_w=P_I, solid_angle=OMEGA,
                               overload=over)
    assert not pts.valid[4] and pts.valid.sum() == r.size - 1


@pytest.mark.parametrize(("section", "match"), [
    ({"transimpedance_v_per_a": 1e6}, "responsivity_a_per_w"),
    ({"responsivity_a_per_w": [0.3, 0.4], "transimpedance_v_per_a": 1e6}, "responsivity_nm"),
    ({"responsivity_a_per_w": -0.3, "transimpedance_v_per_a": 1e6}, "> 0"),
    ({"responsivity_a_per_w": [0.3, 0.4], "responsivity_nm": [600, 500],
      "transimpedance_v_per_a": 1e6}, "increasing"),
])
def test_profile_section_errors_name_the_key(section: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        photodiode_from_profile(section)


def test_bad_readings_are_refused() -> None:
    with pytest.raises(ValueError, match="lockin_r_v"):
        lockin_brdf_absolute([np.nan], [0.1], [1.0], [0.1], [0.0], [0.2], [np.pi],
                             photodiode=PD, wavelength_nm=LAM, incident_power_w=P_I,
                             solid_angle=OMEGA)
    with pytest.raises(ValueError, match="reference reading"):
        lockin_brdf_ratio([1e-3], [1e-5], [1e-2], [0.1], [0.0], [0.2], [np.pi],
                          reference_r_v=0.0, u_reference_r_v=0.0,
                          reference_sensitivity_v=1.0, solid_angle=OMEGA)


# the noise model of a run's readings ----------------------------------------------------
def _snapshots(seed: int, n_points: int = 150, n: int = 4, a: float = 1e-16,
               b: float = 2e-12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(true R, mean R, standard error of the mean from the point's own spread) of
    ``n_points`` points of ``n`` snapshots each, one snapshot's variance a + b·R."""
    from numpy.random import default_rng

    rng = default_rng(seed)
    r_true = 10 ** rng.uniform(-6, -3, n_points)
    sd = np.sqrt(a + b * r_true)
    snaps = r_true[:, None] + sd[:, None] * rng.standard_normal((n_points, n))
    return r_true, snaps.mean(axis=1), snaps.std(axis=1, ddof=1) / np.sqrt(n)


def test_the_pooled_noise_model_recovers_a_and_b_from_three_dof_spreads():
    from analysis.brdf.reduction.lockin import pooled_reading_sigma

    a, b = 1e-16, 2e-12
    fits = [pooled_reading_sigma(m, u, 4)[1:] for m, u in
            (_snapshots(seed)[1:] for seed in range(40))]
    got = np.array(fits) / [a, b]
    # 150 points × 3 dof: one seed gives a and b to about 25 % (1σ, the spread of these
    # seeds), so each within 0.75; their mean over 40 seeds within 0.15 (≈ 3.5σ)
    assert np.all(np.abs(got - 1) < 0.75)
    assert np.all(np.abs(np.mean(got, axis=0) - 1) < 0.15)


def test_weights_from_the_pooled_model_give_chi2_per_dof_near_one_and_own_spreads_three():
    """With σ of each mean from its own four snapshots, E[χ²/ν] = 3/(3 − 2) = 3 (the
    reciprocal of χ²₃/3); from the pooled model it is 1."""
    from analysis.brdf.reduction.lockin import pooled_reading_sigma

    pooled, own = [], []
    for seed in range(40):
        r_true, mean, u = _snapshots(100 + seed)
        sigma, _, _ = pooled_reading_sigma(mean, u, 4)
        pooled.append(np.mean(((mean - r_true) / sigma) ** 2))
        own.append(np.mean(((mean - r_true) / u) ** 2))
    # pooled: E[v/v̂] ≈ 1 + CV(v̂)², the model's a and b known to ~25 % per run of 150
    # points (test above), so 1 to about 1.2 (1.19 measured on these seeds); the noise of
    # 40 × 150 χ²₁ terms is ±0.05 (3σ)
    assert 0.95 < np.mean(pooled) < 1.3
    # own spreads: a t₃² per point, mean 3 (3.2 on these seeds): the lock-in's χ²/dof 3–5
    assert np.mean(own) > 2.5


def test_dark_readings_enter_the_noise_model_at_zero_signal():
    from analysis.brdf.reduction.lockin import pooled_reading_sigma

    _, mean, u = _snapshots(7, n_points=20)
    dark = np.full(20, np.sqrt(1e-16 / 4))
    sigma, a, b = pooled_reading_sigma(mean, u, 4, dark_u_v=dark, n_dark_readings=4)
    assert abs(a / 1e-16 - 1) < 0.3 and b > 0 and sigma.shape == (20,)
    with pytest.raises(ValueError, match="at least two readings"):
        pooled_reading_sigma(mean, u, 1)
    # noiseless readings: their own (zero) σ back, nothing invented
    assert np.all(pooled_reading_sigma(mean, np.zeros(20), 4)[0] == 0)
