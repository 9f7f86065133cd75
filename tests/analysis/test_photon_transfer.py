"""Photon-transfer analysis recovers K, read noise, saturation and linearity."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.photon_transfer import pair_statistics, photon_transfer

SHAPE = (96, 96)


def sweep(k, read_e, full_well, rate_e_per_us, exposures, rng, nonlinearity=0.0, bits=16):
    """Pairs of flat and dark frames of an ideal (or compressive) linear camera."""
    prnu = 1.0 + 0.02 * rng.standard_normal(SHAPE)
    dsnu = 3.0 * rng.standard_normal(SHAPE)
    offset = 50.0

    def frame(t, light):
        lam = rate_e_per_us * t * prnu * light + 5e-6 * t
        e = np.minimum(rng.poisson(lam).astype(float), full_well)
        e = e * (1.0 - nonlinearity * e / full_well)
        dn = np.rint(k * (e + dsnu + read_e * rng.standard_normal(SHAPE)) + offset)
        return np.clip(dn, 0, 2**bits - 1)

    flats = np.stack([[frame(t, 1.0), frame(t, 1.0)] for t in exposures])
    darks = np.stack([[frame(t, 0.0), frame(t, 0.0)] for t in exposures])
    return flats, darks


def test_pair_statistics_removes_fixed_pattern():
    rng = np.random.default_rng(0)
    pattern = 50.0 * rng.standard_normal(SHAPE)
    pair = pattern + 100.0 + 2.0 * rng.standard_normal((2, *SHAPE))
    mean, var = pair_statistics(pair)
    assert mean == pytest.approx(100.0 + pattern.mean(), abs=0.05)
    assert var == pytest.approx(4.0, rel=0.05)


@pytest.mark.parametrize("k, read_e", [(0.25, 6.0), (2.0, 2.5)])
def test_recovers_gain_read_noise_and_saturation(k, read_e):
    rng = np.random.default_rng(42)
    full_well = 20000.0
    exposures = np.linspace(20.0, 1400.0, 24)  # rate 20 e⁻/µs → saturation at 1000 µs
    flats, darks = sweep(k, read_e, full_well, 20.0, exposures, rng)
    res = photon_transfer(flats, darks, exposures)
    assert res.system_gain_dn_per_e == pytest.approx(k, rel=0.03)
    assert res.system_gain_stderr < 0.03 * k
    # σ_d includes the DSNU-free temporal dark noise only (pairs cancel the DSNU).
    assert res.read_noise_e == pytest.approx(read_e, rel=0.05)
    # The variance peaks when the most responsive pixels (PRNU 2 %) start to clip, a few
    # per cent below the full well; the sweep's step is 6 % of it.
    assert 0.85 * full_well < res.saturation_capacity_e <= full_well
    assert res.linearity_error_percent < 0.5
    assert res.gain_fit_mask.sum() >= 5


def test_linearity_error_detects_compression():
    rng = np.random.default_rng(7)
    exposures = np.linspace(20.0, 1400.0, 24)
    flats, darks = sweep(1.0, 3.0, 20000.0, 20.0, exposures, rng, nonlinearity=0.05)
    res = photon_transfer(flats, darks, exposures)
    # A quadratic compression of 5 % at full well leaves about ±0.6 % around the best line
    # over 5–95 % of saturation; an ideal sensor stays below 0.2 %.
    assert res.linearity_error_percent > 0.4
    ideal = photon_transfer(*sweep(1.0, 3.0, 20000.0, 20.0, exposures,
                                   np.random.default_rng(7)), exposures)
    assert ideal.linearity_error_percent < 0.2


def test_single_dark_pair_and_argument_checks():
    rng = np.random.default_rng(3)
    exposures = np.linspace(20.0, 1400.0, 12)
    flats, darks = sweep(0.5, 4.0, 20000.0, 20.0, exposures, rng)
    res = photon_transfer(flats, darks[0], exposures)
    assert res.system_gain_dn_per_e == pytest.approx(0.5, rel=0.05)
    with pytest.raises(ValueError):
        photon_transfer(flats[:, 0], darks, exposures)
    with pytest.raises(ValueError):
        photon_transfer(flats, darks, exposures[:-1])
    with pytest.raises(ValueError):
        photon_transfer(flats[:2], darks[:2], exposures[:2])
