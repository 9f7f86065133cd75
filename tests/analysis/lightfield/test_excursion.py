"""The expected-Euler-characteristic threshold on synthetic smooth Gaussian fields.

Stationary unit-variance fields with a Gaussian covariance of known length: white noise
smoothed by a Gaussian kernel of standard deviation ``s`` samples has covariance
``exp(−h²/(4 s²))``, so ``Λ = −ρ''(0) = 1/(2 s²)`` per axis, uncorrelated axes
(Adler & Taylor 2007, ch. 5; Worsley et al. 1996).  The threshold from the curvatures of
the searched square must give the nominal per-field exceedance rate of the maximum, within
the binomial spread of the number of fields drawn.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.stats import binom

from analysis.lightfield.excursion import EulerTail, lipschitz_killing

N = 80  # periodic field (no edge effects of the circular smoothing)
SIDE = 48  # searched square inside it
S = 6.0  # kernel width (samples): the grid's maximum is within ≈ 1 % of the continuum's
FIELDS = 2000
ALPHA = 0.05


@functools.cache
def _fields(s: float, seed: int) -> np.ndarray:
    """``FIELDS`` stationary unit-variance Gaussian fields, covariance exp(−h²/4s²)."""
    rng = np.random.default_rng(seed)
    ky, kx = np.fft.fftfreq(N), np.fft.rfftfreq(N)
    kernel = np.exp(-2.0 * (np.pi * s) ** 2 * (ky[:, None] ** 2 + kx[None, :] ** 2))
    w = rng.standard_normal((FIELDS, N, N))
    f = np.fft.irfft2(np.fft.rfft2(w) * kernel, s=(N, N))[:, :SIDE, :SIDE]
    # unit variance: white noise of variance 1 smoothed by the kernel has variance Σ|k|²/N²
    full = np.concatenate([kernel, kernel[:, 1:(N + 1) // 2][:, ::-1]], axis=1)
    return f / np.sqrt(np.sum(full**2) / N**2)


def _tail(s: float) -> EulerTail:
    lam = 1.0 / (2.0 * s * s)
    ones = np.ones((SIDE, SIDE))
    return lipschitz_killing(ones * lam, ones * np.sqrt(lam), ones * np.sqrt(lam),
                             np.ones((SIDE, SIDE), bool), (1.0, 1.0))


def test_threshold_gives_the_nominal_rate_of_the_maximum() -> None:
    s = S
    fields = _fields(s, seed=6)
    assert np.std(fields) == pytest.approx(1.0, abs=0.02)
    tail = _tail(s)
    # the curvatures of a SIDE × SIDE square: area / (2 s²) and half the perimeter /(s√2)
    assert tail.l2 == pytest.approx(SIDE**2 / (2 * s * s), rel=1e-12)
    assert tail.l1 == pytest.approx(0.5 * 4 * SIDE / (s * np.sqrt(2)), rel=1e-12)
    u = tail.threshold(ALPHA)
    assert float(tail.probability(u)) == pytest.approx(ALPHA, rel=1e-9)
    hits = int(np.sum(fields.reshape(FIELDS, -1).max(axis=1) > u))
    lo, hi = binom.ppf([0.0005, 0.9995], FIELDS, ALPHA)
    assert lo <= hits <= hi, (hits, lo, hi, u)


def test_cell_count_of_the_correlation_area_is_not_the_field_tail() -> None:
    """The count the threshold replaced — one independent trial per correlation area
    (here a square of the covariance's full width at half maximum, (2.355 s)²) — sets a
    threshold whose rate on the same fields is off the nominal one, which is why the
    localiser no longer uses it."""
    from scipy.special import ndtri

    s = S
    fields = _fields(s, seed=6)
    cells = SIDE**2 / (2.355 * s) ** 2
    u_cells = float(-ndtri(ALPHA / cells))
    hits = int(np.sum(fields.reshape(FIELDS, -1).max(axis=1) > u_cells))
    lo, hi = binom.ppf([0.0005, 0.9995], FIELDS, ALPHA)
    assert not lo <= hits <= hi


def test_region_mask_and_empty_region() -> None:
    ones = np.ones((4, 6))
    half = np.zeros((4, 6), bool)
    half[:2] = True
    t = lipschitz_killing(ones, ones, 2 * ones, half, (1.0, 1.0))
    assert t.l2 == pytest.approx(12.0)
    # two sides along axis 2 of length 6 (metric 2): 24; two along axis 1 of length 2: 4
    assert t.l1 == pytest.approx(0.5 * (2 * 6 * 2 + 2 * 2 * 1))
    empty = lipschitz_killing(ones, ones, ones, np.zeros((4, 6), bool), (1.0, 1.0))
    assert float(empty.probability(3.0)) == 0.0
    with pytest.raises(ValueError, match="false_alarm"):
        t.threshold(1.5)
    assert np.isfinite(t.probability(np.inf)) and float(t.probability(np.inf)) == 0.0


@pytest.mark.parametrize(("axis", "h"), [(0, 0.02), (1, 0.1)])
def test_metric_is_the_curvature_of_the_statistic_correlation(axis: int, h: float) -> None:
    """``Λ`` from the responses' derivatives equals ``2(1 − corr(Z(x), Z(x + h)))/h²`` for a
    small step, the correlation taken from the same noise model on the responses at both
    places (a finite-difference check of the formula, no sampling)."""
    from analysis.lightfield import LightField2D, theta_grid
    from analysis.lightfield.excursion import _quadratic_forms, statistic_metric
    from analysis.lightfield.ray_fit import ray_model
    from analysis.lightfield.spectral import fourier_orders

    n, domain = 64, (-0.6, 0.6)
    y = np.arange(-50.0, 50.1, 1.0)
    lf = LightField2D(np.zeros((y.size, n)), y, theta_grid(domain, n), domain, 100.0)
    use = np.abs(lf.theta_rad) <= 0.45
    p = fourier_orders(n)
    phi = (np.abs(p) <= 6).astype(float)
    noise = 1.0 + 0.1 * np.abs(p)  # coloured, as the reconstruction's
    x = np.array([[5.0, -150.0]])
    lam = statistic_metric(lf, use, phi, noise, x).metric[0]
    step = np.zeros(2)
    step[axis] = h
    r, _, _ = ray_model(lf, use, phi, np.vstack([x, x + step]))
    v = np.where(phi > 0, phi**2 * noise, 0.0)
    q = _quadratic_forms(r[:, None], use, v)[0]
    corr = q[0, 1] / np.sqrt(q[0, 0] * q[1, 1])
    assert lam[axis, axis] == pytest.approx(2.0 * (1.0 - corr) / h**2, rel=0.02)
    assert np.all(np.linalg.eigvalsh(lam) > 0)
