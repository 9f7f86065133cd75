"""EMVA 1288 evaluation with uncertainties (analysis.emva1288) on synthetic frames.

The frames come from the independent generator of tests/analysis/test_photon_transfer.py
(exact Poisson electrons, PRNU 2 %, DSNU 3 e⁻, a full well), not from the simulated sensor
that the end-to-end tests use.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.emva1288 import (
    SweepStatistics,
    Uniformity,
    characterize,
    spatial_variance,
    uniformity_exposure_index,
)
from analysis.photon_transfer import pair_statistics
from tests.analysis.test_photon_transfer import SHAPE, sweep

EXPOSURES = np.linspace(20.0, 1400.0, 40)  # 20 e⁻/µs: the 20000 e⁻ well fills at 1000 µs


def evaluate(k, read_e, seed, nonlinearity=0.0, photons=None):
    rng = np.random.default_rng(seed)
    flats, darks = sweep(k, read_e, 20000.0, 20.0, EXPOSURES, rng, nonlinearity)
    light = np.array([[pair_statistics(p)] for p in flats])
    dark = np.array([[pair_statistics(p)] for p in darks])
    stats = SweepStatistics(EXPOSURES, light[..., 0], light[..., 1], dark[..., 0],
                            dark[..., 1], SHAPE[0] * SHAPE[1])
    j = uniformity_exposure_index(stats)
    uni = Uniformity(flats[j].mean(axis=0), darks[j].mean(axis=0), 2, 2, EXPOSURES[j])
    return characterize(stats, uni, photons_per_pixel_per_s=photons, n_bootstrap=200)


@pytest.mark.parametrize("k, read_e, seed", [(0.25, 6.0, 1), (2.0, 2.5, 2)])
def test_recovers_the_generator_within_its_uncertainties(k, read_e, seed):
    r = evaluate(k, read_e, seed, photons=20.0e6 / 0.5)  # η = 0.5 by construction
    checks = {"K": (r.system_gain_dn_per_e, r.u_system_gain_dn_per_e, k),
              "σ_d": (r.dark_noise_e, r.u_dark_noise_e, read_e),
              "DSNU": (r.dsnu_e, r.u_dsnu_e, 3.0),
              "PRNU": (r.prnu_rel, r.u_prnu_rel, 0.02),
              "dark current": (r.dark_current_e_per_s, r.u_dark_current_e_per_s, 5.0),
              "η": (r.quantum_efficiency, r.u_quantum_efficiency, 0.5)}
    z = {name: (v - t) / u for name, (v, u, t) in checks.items()}
    assert all(abs(v) < 2.5 for v in z.values()), z
    # the saturation lies just below the well (the PRNU spreads the pixels' approach)
    assert 0.9 * 20000 < r.saturation_capacity_e < 20000 + 3 * r.u_saturation_capacity_e
    assert r.linearity_fit_mask.sum() > 20 and r.gain_fit_mask.sum() > 15


def test_linearity_error_of_a_compressive_camera_stands_above_its_noise():
    ideal = evaluate(0.25, 6.0, 3)
    bent = evaluate(0.25, 6.0, 3, nonlinearity=0.05)
    assert abs(ideal.linearity_error_unbiased_percent) < 3 * ideal.u_linearity_error_percent
    assert bent.linearity_error_percent > 10 * bent.u_linearity_error_percent
    assert bent.linearity_error_unbiased_percent == pytest.approx(
        bent.linearity_error_percent, rel=0.05)
    assert ideal.quantum_efficiency is None and ideal.u_quantum_efficiency is None


def test_spatial_variance_removes_the_temporal_part():
    rng = np.random.default_rng(4)
    pattern = 1.0 * rng.standard_normal((128, 128))
    frames = pattern + 2.0 * rng.standard_normal((4, 128, 128))
    s2, u = spatial_variance(frames.mean(axis=0), 4.0, 4)
    assert abs(s2 - 1.0) < 2.5 * u and u < 0.05


def test_bad_sweeps_are_refused():
    t = np.array([10.0, 20.0, 30.0])
    ones = np.ones((3, 1))
    with pytest.raises(ValueError, match="increase"):
        SweepStatistics(t[::-1], ones, ones, ones, ones, 100)
    with pytest.raises(ValueError, match="shape"):
        SweepStatistics(t, np.ones((2, 1)), ones, ones, ones, 100)
    dark = SweepStatistics(t, ones, ones, ones, ones, 100)
    uni = Uniformity(np.ones((4, 4)), np.ones((4, 4)), 2, 2, 10.0)
    with pytest.raises(ValueError, match="is the light on"):
        characterize(dark, uni, n_bootstrap=50)


def test_quantisation_deviation_bounds_the_sheppard_correction():
    from analysis.emva1288 import quantisation_deviation_dn2

    assert quantisation_deviation_dn2(0.5) == pytest.approx(0.00792, rel=0.01)
    assert quantisation_deviation_dn2(0.8) < 1e-4
    # a camera whose offsets all sit on a whole DN shows a variance within the bound
    rng = np.random.default_rng(5)
    y = np.rint(0.5 * rng.standard_normal(200_000))
    assert abs(y.var() - 0.25 - 1 / 12) < quantisation_deviation_dn2(0.5) + 0.003
