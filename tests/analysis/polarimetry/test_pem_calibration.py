"""The PEM polarimeter's calibration (:mod:`analysis.polarimetry.pem_calibration`) on
synthetic reference readings: the hidden parameters are recovered within their
covariance, and a calibrated reduction is unbiased where the nominal one is not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.polarimetry.drr import reduce
from analysis.polarimetry.elements import linear_polariser, linear_retarder
from analysis.polarimetry.pem import pem_design, pem_settings
from analysis.polarimetry.pem_calibration import (
    PemCalibration,
    PemReferenceScan,
    calibrate_pem,
)

AMPLITUDE = 2.405
#: amplitude 3 % high, modulator 0.4° off 45°, analyser retarder −0.4° and 2° of
#: retardance off a quarter wave, analyser polariser −0.3° (the simulated bench's values)
HIDDEN = np.array([1.03, 0.4, -0.4, math.radians(92.0), -0.3])
EXTINCTION = 1e-5
NOISE = 1e-4  # of the DC's full scale


def _truth() -> PemCalibration:
    return PemCalibration(params=HIDDEN, cov=np.zeros((5, 5)), psg_extinction=EXTINCTION,
                          psa_extinction=EXTINCTION)


REFERENCES = (("air", np.eye(4), 0.0), ("polariser", linear_polariser(0.0), 0.0),
              ("polariser", linear_polariser(math.radians(45.0)), 45.0),
              ("retarder", linear_retarder(math.radians(30.0), math.pi / 2), 30.0))


def _scans(rng: np.random.Generator) -> list[PemReferenceScan]:
    settings = pem_settings()
    out = []
    for kind, m, angle in REFERENCES:
        y = (_truth().design(settings, AMPLITUDE) @ m.ravel()).reshape(-1, 3)
        s = np.full(y.shape, NOISE)
        out.append(PemReferenceScan(kind, y + rng.normal(0.0, NOISE, y.shape), s, settings,
                                    AMPLITUDE, angle_deg=angle))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_hidden_parameters_are_recovered_within_their_covariance(seed):
    cal = calibrate_pem(_scans(np.random.default_rng(seed)),
                        analyser_retardance=math.pi / 2, psg_extinction=EXTINCTION,
                        psa_extinction=EXTINCTION)
    d = cal.params - HIDDEN
    # Mahalanobis² of 5 parameters: χ²(5) exceeds 20.5 once in 1000
    assert float(d @ np.linalg.solve(cal.cov, d)) < 20.5, (d, cal.sigma)
    assert cal.dof == 4 * 24 - (5 + 4 + 2 + 2)
    # χ²/dof within 5σ of 1 (the stored calibration's quality gate)
    assert abs(cal.chi2 / cal.dof - 1.0) < 5.0 * math.sqrt(2.0 / cal.dof)


def test_a_calibrated_reduction_is_unbiased_where_the_nominal_one_is_not():
    rng = np.random.default_rng(7)
    cal = calibrate_pem(_scans(rng), analyser_retardance=math.pi / 2,
                        psg_extinction=EXTINCTION, psa_extinction=EXTINCTION)
    settings = pem_settings()
    sample = linear_retarder(math.radians(20.0), math.pi / 2) @ linear_polariser(
        math.radians(10.0))
    y = _truth().design(settings, AMPLITUDE) @ sample.ravel()
    y = y + rng.normal(0.0, NOISE, y.shape)
    s = np.full(y.shape, NOISE)
    est = cal.reduce(y, s, settings, AMPLITUDE)
    nominal = reduce(y, s, pem_design(settings, amplitude_rad=AMPLITUDE))
    pull_cal = (est.m - sample) / est.sigma
    pull_nom = (nominal.m - sample) / nominal.sigma
    assert np.max(np.abs(pull_cal)) < 4.0, np.round(pull_cal, 1)
    assert np.max(np.abs(pull_nom)) > 20.0  # a 3 % amplitude error is tens of σ
    # the calibration's own uncertainty widens σ over the same W's readings-only σ
    plain = reduce(y, s, cal.design(settings, AMPLITUDE))
    assert np.all(est.sigma >= plain.sigma * (1 - 1e-9))
    assert np.any(est.sigma > plain.sigma * 1.01)


def test_without_an_air_scan_the_calibration_is_refused():
    scans = [s for s in _scans(np.random.default_rng(0)) if s.kind != "air"]
    with pytest.raises(ValueError, match="air"):
        calibrate_pem(scans, analyser_retardance=math.pi / 2)


def test_extinction_zero_gives_the_ideal_rows_bit_for_bit():
    settings = pem_settings()
    ideal = pem_design(settings, amplitude_rad=AMPLITUDE)
    assert np.array_equal(pem_design(settings, amplitude_rad=AMPLITUDE, psg_extinction=0.0,
                                     psa_extinction=0.0), ideal)
    # a partial polariser (q = 1, r = ε): DC of the air at the first setting rises by ε/2
    leaky = pem_design(settings, amplitude_rad=AMPLITUDE, psg_extinction=1e-2)
    assert leaky[0] @ np.eye(4).ravel() > ideal[0] @ np.eye(4).ravel()
