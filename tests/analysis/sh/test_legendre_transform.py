"""Legendre recurrences, convention and transforms."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.sh.convention import (
    PROJECT_CONVENTION,
    SHConvention,
    convert,
    degrees_orders,
    lm_index,
    lmax_from_size,
)
from analysis.sh.legendre import gauss_legendre, legendre_order, legendre_table
from analysis.sh.transform import (
    analysis,
    directions_to_angles,
    evaluate,
    fit_scattered,
    gl_grid,
    real_sh_matrix,
    synthesis,
)


def _reference_lambda(l: int, m: int, theta: float):
    """λ_l^m(cos θ) from the explicit finite sum of P_l^m, in high precision.

    P_l(x) = 2^−l Σ_k (−1)^k C(l,k) C(2l−2k,l) x^(l−2k) differentiated m times: independent
    of the recurrences under test. The sum cancels catastrophically, so it runs with about
    0.7·l + 60 digits (the largest term is ~C(2l,l)), and is checked against a run with
    200 more digits. mpmath is a test-only dependency: without it these tests skip.
    """
    mp = pytest.importorskip("mpmath")

    def at(dps: int):
        with mp.workdps(dps):
            x = mp.cos(mp.mpf(theta))
            s = mp.sin(mp.mpf(theta))
            tot = mp.mpf(0)
            for k in range(0, (l - m) // 2 + 1):
                n = l - 2 * k
                tot += (
                    (-1) ** k
                    * mp.binomial(l, k)
                    * mp.binomial(2 * l - 2 * k, l)
                    * mp.ff(n, m)
                    * x ** (n - m)
                )
            norm = mp.sqrt((2 * l + 1) / (4 * mp.pi) * mp.factorial(l - m) / mp.factorial(l + m))
            return +(s**m * tot / mp.mpf(2) ** l * norm)

    dps = int(0.7 * l) + 60
    a, b = at(dps), at(dps + 200)
    assert abs(a - b) <= abs(b) * mp.mpf(10) ** -30
    return b


def _check_against_reference(l: int, m: int, theta: float) -> None:
    ours = legendre_order(m, l, np.array([theta]))[-1, 0]
    ref = _reference_lambda(l, m, theta)
    assert np.isfinite(ours)
    if abs(ref) >= 1e-300:
        assert abs(ours - ref) <= 1e-10 * abs(ref), (l, m, theta, ours, ref)
    else:
        # Truly below the double range: graceful underflow, never garbage.
        assert abs(ours) <= 1e-300


@pytest.mark.parametrize(
    ("l", "m", "theta"),
    [(60, 0, 0.3), (100, 100, 0.05), (150, 75, 0.7), (200, 199, 3.1), (120, 40, 1e-3)],
)
def test_legendre_matches_high_precision(l: int, m: int, theta: float) -> None:
    _check_against_reference(l, m, theta)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("l", "m", "theta"),
    [
        (2048, 0, 0.7),
        (2048, 150, 0.05),  # near the pole, seed sin^150 θ ~ 1e−195 grows back to 6e−14
        (2048, 100, 0.001),  # seed underflows (1e−450) yet the value is 2e−156
        (2048, 1000, 0.05),  # truly 2e−877: must come back as 0, not NaN
        (2048, 1500, 0.9),
        (2048, 2048, 1.3),
        (500, 250, 0.05),  # SciPy returns 0 here, truth 4.3e−223 (mpmath)
        (1000, 999, 3.1),
    ],
)
def test_legendre_high_degree_against_high_precision(l: int, m: int, theta: float) -> None:
    _check_against_reference(l, m, theta)


def test_legendre_orthonormality_by_quadrature() -> None:
    lmax = 40
    theta, w = gauss_legendre(lmax + 1)
    table = legendre_table(lmax, theta)
    for m in (0, 3, 17, 40):
        g = table[m:, m] @ (table[m:, m] * w).T * 2.0 * np.pi
        np.testing.assert_allclose(g, np.eye(lmax - m + 1), atol=1e-13)


def test_gauss_legendre_matches_numpy() -> None:
    for n in (1, 2, 5, 40, 101):
        theta, w = gauss_legendre(n)
        x_ref, w_ref = np.polynomial.legendre.leggauss(n)
        order = np.argsort(np.cos(theta))
        np.testing.assert_allclose(np.cos(theta)[order], x_ref, atol=1e-14)
        np.testing.assert_allclose(w[order], w_ref, atol=1e-13)
        assert np.all(np.diff(theta) > 0)


def test_real_harmonics_match_graphics_constants() -> None:
    # Ramamoorthi & Hanrahan 2001 constants (their eq. 13), at a random direction.
    d = np.array([0.3, -0.5, 0.6])
    d /= np.linalg.norm(d)
    x, y, z = d
    th, ph = directions_to_angles(d)
    y_num = real_sh_matrix(2, np.array([th]), np.array([ph]))[0]
    c0, c1, c2, c20 = 0.5 / np.sqrt(np.pi), np.sqrt(3 / (4 * np.pi)), 0.5 * np.sqrt(
        15 / np.pi
    ), 0.25 * np.sqrt(5 / np.pi)
    expect = [c0, c1 * y, c1 * z, c1 * x, c2 * x * y, c2 * y * z, c20 * (3 * z * z - 1),
              c2 * x * z, 0.5 * c2 * (x * x - y * y)]
    np.testing.assert_allclose(y_num, expect, atol=1e-15)


def test_convention_conversion_round_trip_and_values() -> None:
    rng = np.random.default_rng(1)
    c = rng.standard_normal(16)
    cs_complex = SHConvention(kind="complex", condon_shortley=True)
    a = convert(c, source=PROJECT_CONVENTION, target=cs_complex)
    back = convert(a, source=cs_complex, target=PROJECT_CONVENTION)
    np.testing.assert_allclose(back, c, atol=1e-15)
    # Reality condition of CS complex coefficients: a_l,−m = (−1)^m conj(a_lm).
    l, m = degrees_orders(3)
    pos = m > 0
    np.testing.assert_allclose(
        a[lm_index(l[pos], -m[pos])], (-1.0) ** m[pos] * np.conj(a[pos]), atol=1e-15
    )
    # Function values agree: Σ a_lm Y_l^m (CS) = Σ c_lm Y_lm (real).
    th, ph = 0.8, 2.1
    ycs = []
    for ll, mm in zip(l, m, strict=True):
        lam = legendre_order(abs(mm), ll, np.array([th]))[-1, 0]
        val = lam * np.exp(1j * abs(mm) * ph)
        if mm > 0:
            val *= (-1) ** mm
        if mm < 0:
            val = np.conj(val)
        ycs.append(val)
    f_complex = np.sum(a * np.array(ycs))
    f_real = evaluate(c, np.array(th), np.array(ph))
    assert abs(f_complex.imag) < 1e-14
    assert abs(f_complex.real - f_real) < 1e-14
    with pytest.raises(ValueError):
        lmax_from_size(15)


@pytest.mark.parametrize(("precompute", "backend"),
                         [(True, "reference"), (False, "reference"), (False, "ducc0")])
@pytest.mark.parametrize("lmax", [0, 1, 2, 7, 32, 128])
def test_round_trip_small(lmax: int, precompute: bool, backend: str) -> None:
    rng = np.random.default_rng(lmax)
    grid = gl_grid(lmax, precompute=precompute)
    assert (grid.legendre is not None) == precompute
    c = rng.standard_normal((lmax + 1) ** 2)
    f = synthesis(c, grid=grid, backend=backend)
    assert f.shape == grid.shape
    err = np.max(np.abs(analysis(f, grid=grid, backend=backend) - c)) / np.max(np.abs(c))
    assert err < 1e-13


@pytest.mark.parametrize("backend", ["ducc0", "reference"])
def test_synthesis_matches_pointwise_evaluation(backend: str) -> None:
    rng = np.random.default_rng(5)
    grid = gl_grid(12)
    c = rng.standard_normal(169)
    th, ph = np.meshgrid(grid.theta, grid.phi, indexing="ij")
    np.testing.assert_allclose(synthesis(c, grid=grid, backend=backend), evaluate(c, th, ph),
                               atol=1e-12)


@pytest.mark.slow
@pytest.mark.timeout(1800)  # the reference at L = 2048 on a loaded shared box
@pytest.mark.parametrize("backend", ["ducc0", "reference"])
@pytest.mark.parametrize("lmax", [1024, 2048])
def test_round_trip_high_degree(lmax: int, backend: str) -> None:
    rng = np.random.default_rng(11)
    grid = gl_grid(lmax)
    c = rng.standard_normal((lmax + 1) ** 2)
    f = synthesis(c, grid=grid, backend=backend)
    assert np.all(np.isfinite(f))
    c2 = analysis(f, grid=grid, backend=backend)
    assert np.all(np.isfinite(c2))
    assert np.max(np.abs(c2 - c)) / np.max(np.abs(c)) <= 1e-10


def test_scattered_fit_recovers_band_limited_signal_with_mask() -> None:
    rng = np.random.default_rng(3)
    lmax = 6
    c = rng.standard_normal((lmax + 1) ** 2)
    v = rng.standard_normal((4000, 3))
    th, ph = directions_to_angles(v / np.linalg.norm(v, axis=1, keepdims=True))
    f = evaluate(c, th, ph)
    mask = th < 0.75 * np.pi  # a cap around the south pole is unobserved
    fit = fit_scattered(f, th, ph, lmax=lmax, mask=mask)
    np.testing.assert_allclose(fit.coeffs, c, atol=1e-9)
    assert fit.rank == (lmax + 1) ** 2
    assert fit.n_samples == int(mask.sum())
    # With noise, the reported errors describe the actual scatter.
    sigma = 0.05
    noisy = f + sigma * rng.standard_normal(f.shape)
    fit_n = fit_scattered(noisy, th, ph, lmax=lmax, mask=mask)
    assert abs(fit_n.noise_sigma / sigma - 1) < 0.1
    z = (fit_n.coeffs - c) / fit_n.coeff_std
    assert 0.7 < np.sqrt(np.mean(z**2)) < 1.3


@pytest.mark.parametrize("backend", ["ducc0", "reference"])
def test_transforms_accept_an_explicit_convention(backend: str) -> None:
    rng = np.random.default_rng(8)
    grid = gl_grid(6)
    c = rng.standard_normal(49)
    cs_complex = SHConvention(kind="complex", condon_shortley=True)
    a = analysis(synthesis(c, grid=grid, backend=backend), grid=grid, convention=cs_complex,
                 backend=backend)
    np.testing.assert_allclose(a, convert(c, source=PROJECT_CONVENTION, target=cs_complex),
                               atol=1e-13)
    np.testing.assert_allclose(synthesis(a, grid=grid, convention=cs_complex, backend=backend),
                               synthesis(c, grid=grid, backend=backend), atol=1e-13)


def test_vectorised_recurrence_matches_per_order_values_near_the_poles() -> None:
    """The all-orders recurrence of the transforms (scaled seeds) against legendre_order."""
    from analysis.sh.transform import _legendre_all_orders

    lmax = 400
    theta = np.array([1e-3, 0.02, 0.3, np.pi - 0.01])
    fast = _legendre_all_orders(lmax, theta)
    for m in (0, 7, 150, 300, 400):
        ref = legendre_order(m, lmax, theta)
        got = fast[m:, m]
        big = np.abs(ref) > 2.0**-290  # the transform drops values below 2^−300 by design
        np.testing.assert_allclose(got[big], ref[big], rtol=1e-10,
                                   atol=1e-12 * np.max(np.abs(ref)))
        assert np.all(np.abs(got[~big]) <= 2.0**-290)
        assert np.all(np.isfinite(got))


def test_chunked_recurrence_matches_per_order_values() -> None:
    """degree_chunks (locally rescaled, skipped polar rings) against legendre_order."""
    from analysis.sh.legendre import degree_chunks, sectoral_seeds

    lmax = 300
    # ordered by distance from the pole, as the kernel requires for its ring skipping
    theta = np.array([1e-3, 0.01, 0.05, 0.3, 0.9, 1.5])
    x, s = np.cos(theta), np.sin(theta)
    mant, expo = sectoral_seeds(s, lmax)
    m0, m1 = 230, 262
    got = np.zeros((m1 - m0, lmax - m0 + 1, theta.size))
    skipped = 0
    for k0, nc, n, skip, buf, sc in degree_chunks(
        m0, m1, lmax, x, mant[m0:m1], expo[m0:m1], chunk=8
    ):
        assert np.all(np.isfinite(buf[2 : nc + 2, :n, skip:]))
        lam = buf[2 : nc + 2, :n, skip:] * sc[:n].T[:, :, None]
        got[:n, k0 : k0 + nc, skip:] = lam.transpose(1, 0, 2)
        skipped += skip
    assert skipped > 0  # the polar rings were left out somewhere
    for m in (m0, 245, m1 - 1):
        ref = legendre_order(m, lmax, theta)
        row = got[m - m0, : lmax - m + 1]
        big = np.abs(ref) > 2.0**-290
        np.testing.assert_allclose(row[big], ref[big], rtol=1e-12)
        assert np.all(np.abs(row[~big]) <= 2.0**-290)


@pytest.mark.parametrize("lmax", [20, 58, 59, 90])
def test_stored_table_and_recurrence_give_the_same_transforms(lmax: int) -> None:
    # L = 20 stores a dense table on all rings, L = 58, 59 one on the northern rings by parity
    # (odd and even ring counts), L = 90 the recurrence's chunks; all against the recurrence.
    rng = np.random.default_rng(lmax + 1)
    c = rng.standard_normal((lmax + 1) ** 2)
    stored, plain = gl_grid(lmax, precompute=True), gl_grid(lmax, precompute=False)
    ref = {"backend": "reference"}
    f = synthesis(c, grid=stored, **ref)
    np.testing.assert_allclose(f, synthesis(c, grid=plain, **ref), rtol=0, atol=1e-12)
    np.testing.assert_allclose(analysis(f, grid=stored, **ref), analysis(f, grid=plain, **ref),
                               atol=1e-13)
