"""Complex-index Fresnel: limits, an independent real-arithmetic form, phase convention."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.brdf.fresnel import (
    brewster_angle,
    fresnel,
    normal_incidence_reflectance,
    schlick,
)


def _conductor_real(c: np.ndarray, n: float, k: float) -> tuple[np.ndarray, np.ndarray]:
    """Rs, Rp in real arithmetic (the form of Lagarde 2013 / pbrt FrConductor), written from
    a² + b² = √((n² − k² − s²)² + 4n²k²), a = √((a²+b² + n² − k² − s²)/2)."""
    s2 = 1 - c * c
    t0 = n * n - k * k - s2
    a2b2 = np.sqrt(t0 * t0 + 4 * n * n * k * k)
    a = np.sqrt(0.5 * (a2b2 + t0))
    rs = (a2b2 - 2 * a * c + c * c) / (a2b2 + 2 * a * c + c * c)
    t1 = a2b2 * c * c + s2 * s2
    t2 = 2 * a * c * s2
    rp = rs * (t1 - t2) / (t1 + t2)
    return rs, rp


@pytest.mark.parametrize("n", [1.33, 1.5, 2.4, 0.18 + 3.1j, 0.96 + 6.69j])
def test_normal_incidence(n: complex) -> None:
    nr, k = np.real(n), np.imag(n)
    expect = ((nr - 1) ** 2 + k**2) / ((nr + 1) ** 2 + k**2)
    assert pytest.approx(expect, rel=1e-12) == fresnel(1.0, n).R
    assert normal_incidence_reflectance(n) == pytest.approx(expect, rel=1e-12)
    # rp = -rs at normal incidence with the stated sign convention
    res = fresnel(1.0, n)
    assert res.rp == pytest.approx(-res.rs, rel=1e-12)


def test_dielectric_glass_value() -> None:
    assert pytest.approx(0.04, rel=1e-12) == fresnel(1.0, 1.5).R


@pytest.mark.parametrize("n", [1.33, 1.5, 3.5])
def test_brewster_zero_of_rp(n: float) -> None:
    tb = brewster_angle(n)
    res = fresnel(np.cos(tb), n)
    assert res.Rp == pytest.approx(0.0, abs=1e-20)
    assert res.Rs > 0.01


@pytest.mark.parametrize("n", [1.5, 0.18 + 3.1j, 0.96 + 6.69j, 0.7])
def test_grazing_reflects_everything(n: complex) -> None:
    res = fresnel(0.0, n)
    assert pytest.approx(1.0, abs=1e-12) == res.R
    assert res.Rs == pytest.approx(1.0, abs=1e-12)
    assert res.Rp == pytest.approx(1.0, abs=1e-12)


def test_total_internal_reflection() -> None:
    n = 1 / 1.5  # glass → air
    crit = np.arcsin(n)
    c = np.cos(np.linspace(crit + 1e-3, np.pi / 2, 20))
    np.testing.assert_allclose(fresnel(c, n).R, 1.0, atol=1e-12)


@pytest.mark.parametrize(("n", "k"), [(0.18, 3.1), (0.96, 6.69), (2.5, 0.3), (1.5, 0.0)])
def test_matches_independent_real_form(n: float, k: float) -> None:
    c = np.cos(np.radians(np.linspace(0, 90, 91)))
    rs, rp = _conductor_real(c, n, k)
    res = fresnel(c, complex(n, k))
    np.testing.assert_allclose(res.Rs, rs, atol=1e-13)
    np.testing.assert_allclose(res.Rp, rp, atol=1e-13)


def test_aluminium_p_dip_and_schlick_error() -> None:
    # independently computed: Al (0.96 + 6.69i) has min Rp = 0.747 near 81°, and Schlick
    # errs by 0.092
    th = np.radians(np.linspace(0, 90, 9001))
    res = fresnel(np.cos(th), 0.96 + 6.69j)
    assert res.Rp.min() == pytest.approx(0.747, abs=2e-3)
    assert np.degrees(th[np.argmin(res.Rp)]) == pytest.approx(81.0, abs=1.0)
    err = np.abs(schlick(np.cos(th), res.R[0]) - res.R)
    assert err.max() == pytest.approx(0.092, abs=3e-3)


def test_phase_sign_flips_with_conjugate_convention() -> None:
    # Intensities agree under n+ik → n−ik, the ellipsometric phase changes sign.
    c = np.cos(np.radians(60.0))
    a = fresnel(c, 0.18 + 3.1j)
    b = fresnel(c, 0.18 - 3.1j)
    assert pytest.approx(b.R, rel=1e-12) == a.R
    assert a.delta == pytest.approx(-b.delta, abs=1e-12)
    # with exp(−iωt) and k > 0 the p wave lags: Δ = arg(rp/rs) is negative at 60° for gold
    assert a.delta < 0
    assert abs(np.degrees(a.delta)) == pytest.approx(130.1, abs=3.0)


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0.0, 1.0),
    st.floats(0.05, 10.0),
    st.floats(0.0, 10.0),
)
def test_reflectance_in_unit_interval(c: float, n: float, k: float) -> None:
    res = fresnel(c, complex(n, k))
    for r in (res.R, res.Rs, res.Rp):
        assert 0.0 <= float(r) <= 1.0 + 1e-12
