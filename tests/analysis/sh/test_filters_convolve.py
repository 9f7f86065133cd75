"""BRDF filters, irradiance formula, convolution and Wiener deconvolution."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import eval_legendre

from analysis.sh.convolve import (
    band_power,
    convolve,
    estimate_coefficient_noise,
    wiener_deconvolve,
)
from analysis.sh.filters import (
    irradiance_9,
    kernel_energy_fraction,
    lambertian_filter,
    phong_filter,
    torrance_sparrow_filter,
)
from analysis.sh.transform import directions_to_angles, evaluate, real_sh_matrix


def _funk_hecke(kernel, l: int) -> float:
    val, _ = quad(lambda t: kernel(t) * eval_legendre(l, t), -1.0, 1.0, limit=400,
                  epsabs=1e-14, epsrel=1e-13)
    return 2.0 * np.pi * val


def test_lambertian_closed_form_matches_quadrature_and_known_values() -> None:
    f = lambertian_filter(12)
    for l in range(13):
        ref = _funk_hecke(lambda t: max(t, 0.0), l)
        assert abs(f.values[l] - ref) < 1e-12
    np.testing.assert_allclose(
        f.values[[0, 1, 2, 4, 6, 8]],
        [np.pi, 2 * np.pi / 3, np.pi / 4, -np.pi / 24, np.pi / 64, -0.024544],
        atol=5e-7,
    )
    assert np.all(f.values[3::2] == 0.0)
    assert f.parameterisation == "normal" and f.exact


def test_lambertian_large_l_asymptote_and_energy() -> None:
    f = lambertian_filter(10_000)
    assert np.all(np.isfinite(f.values))
    # |Â_l| l^2.5 → ≈ 5.0 (independently computed: −4.95, −5.007, −5.013 at 100, 1000, 10000)
    for l, ref in [(100, -4.95), (1000, -5.007), (10_000, -5.013)]:
        assert abs(f.values[l] * l**2.5 - ref) < 0.01
    e = kernel_energy_fraction(f.values[:3], 2 * np.pi / 3)
    assert abs(e[1] - 0.8750) < 1e-4 and abs(e[2] - 0.9922) < 1e-4


@pytest.mark.parametrize("s", [8.0, 32.0, 100.0])
def test_phong_exact_filter_matches_quadrature(s: float) -> None:
    f = phong_filter(24, s)
    for l in range(0, 25, 3):
        ref = _funk_hecke(lambda t, s=s: (s + 1) / (2 * np.pi) * max(t, 0.0) ** s, l)
        assert abs(f.values[l] - ref) < 1e-9
    assert abs(f.values[0] - 1.0) < 1e-13


def test_phong_exact_is_finite_at_large_s_and_has_exact_zeros() -> None:
    f = phong_filter(4000, 1024.0)
    assert np.all(np.isfinite(f.values))
    # integer s, l > s, l − s even: exact zeros of the Γ-ratio
    assert f.values[1026] == 0.0 and f.values[2000] == 0.0
    # band limit ~3√s where the filter falls below 1e−2
    assert abs(f.band_limit - 3 * np.sqrt(1024)) < 10
    approx = phong_filter(4 * 32, 1024.0, exact=False)
    assert np.max(np.abs(approx.values - f.values[: 4 * 32 + 1])) < 1e-3


def test_phong_approximation_error_figures() -> None:
    # independently computed: max error of exp(−l(l+1)/2s) over l ≤ 4√s: 0.014 (s=32), 0.0035 (128)
    for s, bound in [(32.0, 0.015), (128.0, 0.004)]:
        lm = int(4 * np.sqrt(s))
        err = np.max(np.abs(phong_filter(lm, s, exact=False).values - phong_filter(lm, s).values))
        assert err < bound


def test_torrance_sparrow_approximation_values() -> None:
    f = torrance_sparrow_filter(10, 0.1)
    np.testing.assert_allclose(f.values[[2, 5, 10]], [0.942, 0.741, 0.333], atol=2e-3)
    assert not f.exact and f.parameterisation == "reflected"


def test_irradiance_9_equals_filtered_expansion() -> None:
    rng = np.random.default_rng(2)
    lig = rng.standard_normal(9)
    n = rng.standard_normal((50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    th, ph = directions_to_angles(n)
    a = lambertian_filter(2).values
    ref = evaluate(convolve(lig, a), th, ph)
    np.testing.assert_allclose(irradiance_9(lig, n), ref, atol=1e-13)


def test_irradiance_9_against_brute_force_quadrature() -> None:
    # E(n) = ∫ L(ω) max(n·ω, 0) dω for an l ≤ 2 environment, by a fine product quadrature.
    rng = np.random.default_rng(4)
    lig = rng.standard_normal(9)
    x, w = np.polynomial.legendre.leggauss(200)
    phi = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    th = np.arccos(x)
    tt, pp = np.meshgrid(th, phi, indexing="ij")
    dirs = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1)
    lval = (real_sh_matrix(2, tt.ravel(), pp.ravel()) @ lig).reshape(tt.shape)
    wq = w[:, None] * (2 * np.pi / phi.size)
    n = np.array([0.2, 0.5, -0.84])
    n /= np.linalg.norm(n)
    e = np.sum(wq * lval * np.maximum(dirs @ n, 0.0))
    assert abs(irradiance_9(lig, n) - e) < 2e-3 * np.abs(lig).sum()


def test_wiener_lambertian_null_space_is_zero_and_flagged() -> None:
    rng = np.random.default_rng(7)
    lmax = 12
    l = np.repeat(np.arange(lmax + 1), 2 * np.arange(lmax + 1) + 1)
    truth = rng.standard_normal((lmax + 1) ** 2) / (l + 1.0)
    a = lambertian_filter(lmax).values
    sigma = 1e-3
    b = convolve(truth, a) + sigma * rng.standard_normal(truth.size)
    res = wiener_deconvolve(b, a)  # noise estimated from the null bands
    assert np.all(np.isfinite(res.coeffs)) and np.all(np.isfinite(res.gain))
    assert np.array_equal(res.unobservable, np.r_[False, False, False, [True, False] * 5])
    odd = (l % 2 == 1) & (l > 1)
    assert np.all(res.coeffs[odd] == 0.0)
    assert abs(res.noise_sigma / sigma - 1) < 0.25
    np.testing.assert_allclose(res.coeffs[:9], truth[:9], atol=5 * sigma / (np.pi / 4))
    assert 9 < res.dof < np.sum((2 * np.arange(lmax + 1) + 1)[~res.unobservable])
    with pytest.raises(ValueError):
        wiener_deconvolve(b, a, k=0.0)


def test_estimate_noise_needs_signal_free_bands() -> None:
    with pytest.raises(ValueError):
        estimate_coefficient_noise(np.ones(9), np.ones(3))
    assert band_power(np.arange(4.0))[1] == pytest.approx((1 + 4 + 9) / 3)


def test_every_filter_reports_its_band_limit() -> None:
    """Band limit = last l with |A_l| ≥ tol·|A_0|, from the closed forms:
    Lambertian Â_6/π = 1/64 ≥ 1e-2 > Â_8/π = 1/128; exp(−l(l+1)/(2s)) ≥ 1e-2 ⟺
    l(l+1) ≤ 2 s ln 100 (s = 50: 460.5 → l = 20); exp(−σ² l(l+1)) likewise with
    1/σ² = 2s (σ = 0.1 → 20)."""
    assert lambertian_filter(30).band_limit == 6
    assert lambertian_filter(30, tol=0.02).band_limit == 4  # Â_6/π = 0.0156 < 0.02
    assert phong_filter(60, 50.0, exact=False).band_limit == 20
    assert torrance_sparrow_filter(60, 0.1).band_limit == 20
    # the exact Phong filter cuts off close to its approximation's limit
    assert abs(phong_filter(60, 50.0).band_limit - 20) <= 1
