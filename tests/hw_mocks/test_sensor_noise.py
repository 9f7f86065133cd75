"""The sensor's temporal noise draw (hw_mocks/sim/sensor.py, ``_TemporalNoise``):
exact Poisson counts where the mean is small (split from one Poisson total on the unlit
pixels, drawn per pixel elsewhere), one Gaussian for shot + read noise where the mean is
≥ 50 e⁻, and the two drawn apart next to the full well. Each test reads electrons back
from DN (K = 1 DN/e⁻, no fixed pattern) and compares them with the distribution the
EMVA 1288 model prescribes; tolerances are 5 standard errors of the statistic over the
pixels used (seeded, so each test is deterministic; a wrong distribution moves the
statistic by far more)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hw_mocks.sim.sensor import Sensor, SensorParams

SIDE = 512
N = SIDE * SIDE
# 1 DN per electron at 16 bits, no PRNU/DSNU: DN − black level = electrons (rounded)
PARAMS = dict(width=SIDE, height=SIDE, system_gain_dn_per_e=1.0 / 16.0, native_bits=12,
              black_level_dn=40.0, dsnu_e=0.0, prnu=0.0, dark_current_e_per_s=20.0)


def electrons(rate: np.ndarray | float, exposure_us: float, *, seed: int = 3, index: int = 0,
              **params) -> np.ndarray:
    sensor = Sensor(SensorParams(**(PARAMS | params)), seed=seed)
    rate = np.broadcast_to(np.asarray(rate, dtype=np.float32), (SIDE, SIDE))
    dn = sensor.expose(rate, exposure_us, gain_db=0.0, bits=16, roi=(0, 0, SIDE, SIDE),
                       frame_index=index)
    return dn.astype(np.float64) - 16.0 * 40.0


@pytest.mark.parametrize("exposure_us", [2000.0, 25000.0, 50000.0])
def test_unlit_pixels_have_exact_poisson_counts(exposure_us):
    """Dark current alone (λ₀ = 0.04, 0.5, 1.0 e⁻), no read noise: every count class
    0, 1, 2, ... holds N·P(k) pixels within 5 binomial σ, and neighbours are
    uncorrelated (the split drops electrons independently on the pixels)."""
    e = electrons(0.0, exposure_us, read_noise_e=0.0)
    lam0 = 20.0 * exposure_us * 1e-6
    assert np.array_equal(e, np.round(e)) and e.min() >= 0
    for k in range(6):
        p = math.exp(-lam0) * lam0**k / math.factorial(k)
        if N * p < 5:
            break
        assert abs(np.count_nonzero(e == k) - N * p) <= 5.0 * math.sqrt(N * p * (1 - p))
    a, b = e[:, :-1].ravel(), e[:, 1:].ravel()
    assert abs(np.corrcoef(a, b)[0, 1]) <= 5.0 / math.sqrt(a.size)


def test_frames_draw_independent_noise():
    """Two frames of the same sensor: their dark counts are uncorrelated."""
    a = electrons(0.0, 25000.0, index=0).ravel()
    b = electrons(0.0, 25000.0, index=1).ravel()
    assert abs(np.corrcoef(a, b)[0, 1]) <= 5.0 / math.sqrt(N)


def test_lit_low_light_pixels_and_read_noise():
    """Pixels with different small means (not the frame's least) draw Poisson counts per
    pixel: mean λ and variance λ + σ_d² (+1/12 DN² of rounding) per group."""
    rate = np.zeros((SIDE, SIDE), np.float32)
    rate[: SIDE // 2] = 2000.0 / 0.6  # photons/s: 2000 e⁻/s, 10 e⁻ in 5 ms
    rate[SIDE // 2 :] = 6000.0 / 0.6
    rate[0, 0] = 0.0  # one pixel at the least mean (dark current alone)
    e = electrons(rate, 5000.0, read_noise_e=2.5)
    for rows, lam in ((slice(1, SIDE // 2), 10.1), (slice(SIDE // 2, SIDE), 30.1)):
        x = e[rows].ravel()
        var = lam + 2.5**2 + 1.0 / 12.0
        assert x.mean() == pytest.approx(lam, abs=5.0 * math.sqrt(var / x.size))
        # the variance's standard error: √((μ₄ − σ⁴)/n) ≈ σ²√(2/n) (near-Gaussian)
        assert x.var() == pytest.approx(var, abs=5.0 * var * math.sqrt(2.0 / x.size))


@pytest.mark.parametrize("mean_e", [50.0, 400.0, 9000.0])
def test_bright_pixels_one_gaussian_for_shot_and_read_noise(mean_e):
    """λ ≥ 50 e⁻: mean λ, variance λ + σ_d² (+ rounding), and symmetric (the shot noise's
    Gaussian, as before)."""
    exposure_us = 1000.0
    rate = (mean_e - 20.0 * exposure_us * 1e-6) / (0.6 * exposure_us * 1e-6)
    x = electrons(rate, exposure_us, read_noise_e=2.5).ravel()
    var = mean_e + 2.5**2 + 1.0 / 12.0
    assert x.mean() == pytest.approx(mean_e, abs=5.0 * math.sqrt(var / N))
    assert x.var() == pytest.approx(var, abs=5.0 * var * math.sqrt(2.0 / N))
    skew = float(np.mean((x - x.mean()) ** 3)) / x.var() ** 1.5
    assert abs(skew) <= 5.0 * math.sqrt(6.0 / N)


def test_full_well_clips_the_shot_noise_before_the_read_noise():
    """λ at the full well W: the shot noise is clipped at W, then the read noise is
    added, so the mean is W − √(λ/2π) and no pixel reads more than W + 6 σ_d (unclipped
    shot noise would reach W + 4.5 √λ)."""
    well = 18000.0
    exposure_us = 1000.0
    rate = (well - 20.0 * exposure_us * 1e-6) / (0.6 * exposure_us * 1e-6)
    x = electrons(rate, exposure_us, read_noise_e=2.5).ravel()
    var_mean = (well * (0.5 - 1.0 / (2.0 * math.pi)) + 2.5**2) / N
    assert x.mean() == pytest.approx(well - math.sqrt(well / (2.0 * math.pi)),
                                     abs=5.0 * math.sqrt(var_mean))
    assert well < x.max() <= well + 6.0 * 2.5 + 0.5
