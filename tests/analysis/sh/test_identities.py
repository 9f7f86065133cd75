"""SH identities, transfer, separation and the consistency checker."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.sh.consistency import (
    bootstrap_consistent_errors,
    calibrate,
    check,
    known_lighting_residual,
    scale_threshold,
    statistic,
    threshold_factor,
)
from analysis.sh.convention import PROJECT_CONVENTION, SHConvention, convert
from analysis.sh.convolve import convolve, per_coefficient
from analysis.sh.filters import lambertian_filter, phong_filter
from analysis.sh.identities import (
    albedo_ratio,
    brdf_transfer,
    diffuse_plus_specular,
    four_images,
    irradiance_reflected,
    known_lighting,
    lighting_transfer,
    one_object_two_lightings,
    rank_one,
    render_missing_image,
    separate_diffuse_specular,
    two_objects_one_lighting,
)
from analysis.sh.transform import directions_to_angles

LMAX = 8


def _lighting(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    l = np.repeat(np.arange(LMAX + 1), 2 * np.arange(LMAX + 1) + 1)
    return rng.standard_normal((LMAX + 1) ** 2) / (1.0 + l)


def _scramble_band(c: np.ndarray, l: int, seed: int = 0) -> np.ndarray:
    out = c.copy()
    sl = slice(l * l, (l + 1) ** 2)
    out[sl] = np.random.default_rng(seed).permutation(out[sl])
    return out


A1 = phong_filter(LMAX, 20.0).values
A2 = phong_filter(LMAX, 60.0).values


def test_m10_known_lighting_holds_and_estimates_the_filter() -> None:
    lig = _lighting(1)
    b = convolve(lig, A1)
    res = known_lighting(b, lig)
    assert np.all(res.error < 1e-14) and np.all(res.defined)
    np.testing.assert_allclose(res.estimate, A1[1:], rtol=1e-12)
    bad = known_lighting(_scramble_band(b, 5), lig)
    assert bad.error[4] > 0.1 and np.all(np.delete(bad.error, 4) < 1e-14)


def test_m12_diffuse_plus_specular_recovers_a_l_without_kd() -> None:
    lig = _lighting(2)
    d = _lighting(3)  # any D_lm: the identity eliminates K_d
    b = 0.37 * d + convolve(lig, A1)
    res = diffuse_plus_specular(b, lig, d)
    assert np.all(res.error < 1e-12)
    np.testing.assert_allclose(res.estimate, A1[1:], rtol=1e-10)
    assert diffuse_plus_specular(_scramble_band(b, 4), lig, d).error[3] > 0.05


def test_m16_m19_m21_m25_hold_on_consistent_data_and_fail_otherwise() -> None:
    l1, l2 = _lighting(4), _lighting(5)
    b11, b12 = convolve(l1, A1), convolve(l1, A2)  # (lighting, material)
    b21, b22 = convolve(l2, A1), convolve(l2, A2)
    m16 = two_objects_one_lighting(b11, b12)
    assert np.all(m16.error < 1e-13)
    np.testing.assert_allclose(m16.estimate, A2[1:] / A1[1:], rtol=1e-12)
    assert np.all(one_object_two_lightings(b11, b21, l1, l2).error < 1e-13)
    assert np.all(four_images(b11, b12, b21, b22).error < 1e-13)
    assert four_images(b11, b12, b21, _scramble_band(b22, 3)).error[3] > 0.1
    lights = [l1, l2, _lighting(6)]
    mats = [A1, A2, lambertian_filter(LMAX).values + 0.1]
    stack = np.array([[convolve(li, a) for a in mats] for li in lights])
    r1 = rank_one(stack)
    assert np.all(r1.error < 1e-13)
    stack[1, 2] = _scramble_band(stack[1, 2], 6)
    assert rank_one(stack).error[6] > 0.05


def test_rendering_the_fourth_image_both_routes() -> None:
    l1, l2 = _lighting(7), _lighting(8)
    b11, b12, b21 = convolve(l1, A1), convolve(l1, A2), convolve(l2, A1)
    truth = convolve(l2, A2)
    np.testing.assert_allclose(render_missing_image(b11, b12, b21), truth, atol=1e-13)
    np.testing.assert_allclose(render_missing_image(b11, b12, b21, route="lighting"), truth,
                               atol=1e-12)
    gamma = brdf_transfer(b11, b12)
    np.testing.assert_allclose(gamma.values, A2 / A1, rtol=1e-12)
    with pytest.raises(ValueError):
        render_missing_image(b11, b12, b21, route="magic")


def test_lighting_transfer_never_returns_nan() -> None:
    b1 = np.zeros(9)
    b2 = np.ones(9)
    res = lighting_transfer(b1, b2)
    assert np.all(res.values == 0.0) and not res.reliable.any()
    e = known_lighting(np.zeros(9), np.zeros(9))
    assert np.all(e.error == 0.0) and not e.defined.any()


def test_separation_and_albedo_ratio() -> None:
    c = _lighting(9)
    sep = separate_diffuse_specular(c)
    np.testing.assert_allclose(sep.diffuse + sep.specular, c)
    assert np.all(sep.specular[:9] == 0) and np.all(sep.diffuse[9:] == 0)
    assert 0 < sep.diffuse_energy_fraction < 1
    rng = np.random.default_rng(10)
    i1 = rng.uniform(0.2, 1.0, (40, 40))
    i2 = 0.45 * i1 + 0.002 * rng.standard_normal(i1.shape)
    res = albedo_ratio(i1, i2)
    assert abs(res.ratio - 0.45) < 4 * res.std and res.std < 1e-3


def test_irradiance_in_reflected_parameterisation() -> None:
    # constant lighting: E = Â_0 L_00 Y_00 everywhere, so D has only the l = 0 term
    lig = np.zeros(9)
    lig[0] = 2.0
    d = irradiance_reflected(lig, lmax=4)
    expect = np.pi * 2.0 / (2.0 * np.sqrt(np.pi)) * np.sqrt(4.0 * np.pi)
    assert abs(d[0] - expect) < 1e-10 and np.all(np.abs(d[1:]) < 1e-10)
    # lighting along the view axis: D is symmetric about it, so only m = 0 terms survive
    lig = np.zeros(9)
    lig[2] = 1.0  # Y_10 ∝ z
    d = irradiance_reflected(lig, lmax=6, view=(0.0, 0.0, 1.0))
    l = np.repeat(np.arange(7), 2 * np.arange(7) + 1)
    m = np.arange(49) - l * l - l
    assert np.all(np.abs(d[m != 0]) < 1e-10) and abs(d[2]) > 0.1


def test_calibrated_checker_false_alarm_and_power() -> None:
    rng = np.random.default_rng(12)
    n_orders = 10
    scale = np.linspace(0.01, 0.05, n_orders)
    consistent = np.abs(0.02 + scale * rng.standard_normal((400, n_orders)))
    cal = calibrate(consistent, false_alarm=0.05)
    fresh = np.abs(0.02 + scale * rng.standard_normal((2000, n_orders)))
    fa = np.mean([check(e, cal).inconsistent for e in fresh])
    assert fa <= 0.08  # 0.05 ± binomial spread
    shifted = fresh[:200] + 3 * scale
    assert np.mean([check(e, cal).inconsistent for e in shifted]) > 0.95
    rep = check(fresh[0], cal)
    assert rep.ratio.shape == (n_orders,) and np.all(rep.noise_error > 0)
    with pytest.raises(ValueError):
        calibrate(consistent[:10], false_alarm=0.01)
    assert statistic(np.array([-1.0, 2.0])) == 4.0


def test_known_lighting_residual_is_zero_for_a_convolved_image() -> None:
    rng = np.random.default_rng(13)
    lig = _lighting(14)
    v = rng.standard_normal((500, 3))
    th, ph = directions_to_angles(v / np.linalg.norm(v, axis=1, keepdims=True))
    from analysis.sh.transform import evaluate

    img = evaluate(convolve(lig, A1), th, ph)
    res = known_lighting_residual(img, th, ph, lig)
    assert res.relative_rms < 1e-10
    np.testing.assert_allclose(res.filter, A1, rtol=1e-8, atol=1e-10)


@settings(max_examples=30, deadline=None)
@given(
    lmax=st.integers(min_value=0, max_value=5),
    kind=st.sampled_from(["real", "complex"]),
    cs=st.booleans(),
    seed=st.integers(min_value=0, max_value=2**31),
)
def test_convention_round_trip_property(lmax: int, kind: str, cs: bool, seed: int) -> None:
    c = np.random.default_rng(seed).standard_normal((lmax + 1) ** 2)
    other = SHConvention(kind=kind, condon_shortley=cs)
    back = convert(convert(c, source=PROJECT_CONVENTION, target=other), source=other,
                   target=PROJECT_CONVENTION)
    np.testing.assert_allclose(back, c, atol=1e-14)
    assert per_coefficient(np.arange(lmax + 1), lmax).shape == c.shape


def test_bootstrap_calibration_detects_an_inconsistent_image() -> None:
    """Known lighting, M10 in coefficient space, calibrated by a parametric bootstrap."""
    from analysis.sh.transform import evaluate, scattered_fit_operator

    rng = np.random.default_rng(15)
    lig = _lighting(16)
    v = rng.standard_normal((1500, 3))
    th, ph = directions_to_angles(v / np.linalg.norm(v, axis=1, keepdims=True))
    clean = evaluate(convolve(lig, A1), th, ph)
    sigma = 0.01 * np.mean(np.abs(clean))

    op = scattered_fit_operator(th, ph, lmax=LMAX)

    def errors_of(samples: np.ndarray) -> np.ndarray:
        return known_lighting(op.apply(samples), lig).error

    cal = calibrate(bootstrap_consistent_errors(clean, sigma, errors_of, n_cases=60, rng=rng),
                    false_alarm=0.05)
    observed = clean + sigma * rng.standard_normal(clean.shape)
    assert not check(errors_of(observed), cal).inconsistent
    other = evaluate(convolve(_lighting(17), A1), th, ph)
    tampered = np.where(th < np.pi / 2, observed, other)  # one hemisphere from other lighting
    rep = check(errors_of(tampered), cal)
    assert rep.inconsistent and np.max(rep.ratio) > 3


def test_threshold_factor_recalibrates_a_decision_that_misses_a_shared_departure() -> None:
    """Consistent cases carry a departure (+0.03 on every order) that the noise-only
    calibration does not know: its false alarms exceed α; the conformal factor on
    u = T/threshold over 200 such cases brings new ones back to ≤ α (binomial spread)."""
    rng = np.random.default_rng(21)
    n_orders = 8
    scale = np.full(n_orders, 0.01)

    def draw(n: int, shift: float = 0.0) -> np.ndarray:
        return 0.02 + shift + scale * rng.standard_normal((n, n_orders))

    cal = calibrate(draw(400), false_alarm=0.01)
    departed = draw(2000, 0.01)
    u = np.array([check(e, cal).statistic for e in departed]) / cal.threshold
    assert np.mean(u > 1) > 0.05  # the noise-only decision is not calibrated here
    q = threshold_factor(u[:200], false_alarm=0.01)
    cal_q = scale_threshold(cal, q)
    assert cal_q.threshold == pytest.approx(q * cal.threshold) and q > 1
    fa = np.mean([check(e, cal_q).inconsistent for e in departed[200:]])
    assert fa <= 0.01 + 3 * np.sqrt(0.01 * 0.99 / 200), fa  # conformal coverage spread
    with pytest.raises(ValueError):
        threshold_factor(u[:50], false_alarm=0.01)  # 50 cases cannot calibrate α = 0.01
    with pytest.raises(ValueError):
        scale_threshold(cal, 0.0)
