"""Microfacet distributions and visibility terms (Walter et al. 2007; Heitz 2014)."""

import numpy as np
import pytest
from scipy.integrate import quad

from analysis.brdf import microfacet as mf


@pytest.mark.parametrize("alpha", [0.01, 0.05, 0.2, 0.5, 1.0])
@pytest.mark.parametrize("name", ["ggx", "beckmann"])
def test_distribution_normalisation(name: str, alpha: float) -> None:
    # ∫ D(h) cos θh dω = 2π ∫₀¹ D(c) c dc = 1; substitute c = cos t to resolve sharp lobes.
    d = mf.ggx_d if name == "ggx" else mf.beckmann_d
    val, _ = quad(
        lambda t: float(d(np.cos(t), alpha)) * np.cos(t) * np.sin(t) * 2 * np.pi,
        0, np.pi / 2, points=[alpha, 3 * alpha], limit=400, epsabs=1e-13,
    )
    assert val == pytest.approx(1.0, abs=1e-8)


@pytest.mark.parametrize("s", [1.0, 10.0, 100.0, 1000.0])
def test_blinn_phong_normalisation(s: float) -> None:
    val, _ = quad(lambda c: float(mf.blinn_phong_d(c, s)) * c * 2 * np.pi, 0, 1, limit=200)
    assert val == pytest.approx(1.0, abs=1e-10)


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_smith_visibility_equals_naive_form_where_finite(dist: str) -> None:
    mu = np.linspace(0.05, 1.0, 20)
    mi, mr = np.meshgrid(mu, mu)
    a = 0.3
    g1 = mf.smith_g1
    lam_i = 1 / g1(mi, a, distribution=dist) - 1
    lam_r = 1 / g1(mr, a, distribution=dist) - 1
    naive = 1 / (1 + lam_i + lam_r) / (4 * mi * mr)
    np.testing.assert_allclose(mf.smith_visibility(mi, mr, a, distribution=dist), naive, rtol=1e-10)


def test_ggx_visibility_grazing_limit() -> None:
    # independently computed: GGX α=0.3, μi=0.5 → V(μo→0) = 3.333333333 (finite; the naive
    # form gives inf)
    v = mf.smith_visibility(0.5, 0.0, 0.3)
    assert np.isfinite(v)
    a2 = 0.09
    assert v == pytest.approx(0.5 / (0.5 * np.sqrt(a2)), rel=1e-9)
    assert mf.smith_visibility(0.5, 1e-8, 0.3) == pytest.approx(v, rel=1e-7)


def test_beckmann_lambda_matches_heitz_definition() -> None:
    from scipy.special import erf

    mu = np.array([0.1, 0.4, 0.8, 0.99])
    al = 0.4
    a = mu / (al * np.sqrt(1 - mu**2))
    lam = (erf(a) - 1) / 2 + np.exp(-a * a) / (2 * a * np.sqrt(np.pi))
    np.testing.assert_allclose(mf.beckmann_mu_lambda(mu, al), mu * lam, rtol=1e-12)


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("theta_o", [0.0, 0.6, 1.2, np.radians(89.0)])
def test_weak_white_furnace(dist: str, theta_o: float) -> None:
    # Heitz 2014: ∫ G1(ωo) D(ωm) <ωo, ωm>⁺ dωm / cos θo = 1
    alpha = 0.5
    mu_o = np.cos(theta_o)
    so = np.sin(theta_o)
    t, w = np.polynomial.legendre.leggauss(160)
    th = 0.25 * np.pi * (t + 1)
    wt = 0.25 * np.pi * w
    ph = np.linspace(0, 2 * np.pi, 256, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    c = np.cos(T)
    dot = np.maximum(so * np.sin(T) * np.cos(P) + mu_o * c, 0.0)
    d = mf.ggx_d(c, alpha) if dist == "ggx" else mf.beckmann_d(c, alpha)
    integ = np.sum(d * dot * np.sin(T) * wt[:, None]) * (2 * np.pi / ph.size)
    g1 = mf.smith_g1(mu_o, alpha, distribution=dist)
    assert g1 * integ / mu_o == pytest.approx(1.0, abs=2e-4)


@pytest.mark.parametrize(
    ("fn", "dfn"),
    [
        (mf.ggx_d, mf.ggx_d_dalpha),
        (mf.beckmann_d, mf.beckmann_d_dalpha),
        (mf.blinn_phong_d, mf.blinn_phong_d_ds),
    ],
)
def test_distribution_derivatives(fn, dfn) -> None:
    c = np.linspace(0.3, 1.0, 15)
    a = 0.37 if fn is not mf.blinn_phong_d else 12.0
    h = 1e-6 * a
    num = (fn(c, a + h) - fn(c, a - h)) / (2 * h)
    np.testing.assert_allclose(dfn(c, a), num, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_visibility_derivative(dist: str) -> None:
    mu = np.linspace(0.0, 1.0, 11)
    mi, mr = np.meshgrid(mu, mu)
    a = 0.25
    h = 1e-7
    num = (
        mf.smith_visibility(mi, mr, a + h, distribution=dist)
        - mf.smith_visibility(mi, mr, a - h, distribution=dist)
    ) / (2 * h)
    ana = mf.smith_visibility_dalpha(mi, mr, a, distribution=dist)
    ok = np.abs(num) < 1e6  # the doubly grazing corner is huge in both
    np.testing.assert_allclose(ana[ok], num[ok], rtol=1e-5, atol=1e-8)


def test_vcavity_symmetric_and_finite() -> None:
    mu = np.linspace(0.0, 1.0, 9)
    mi, mr = np.meshgrid(mu, mu)
    ch = np.full_like(mi, 0.9)
    cb = np.full_like(mi, 0.7)
    v = mf.vcavity_visibility(mi, mr, ch, cb)
    assert np.all(np.isfinite(v))
    np.testing.assert_allclose(v, v.T)
