"""PEM polarimeter settings and the per-geometry reduction of a PEM run."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from analysis.polarimetry.elements import linear_polariser, linear_retarder
from analysis.polarimetry.pem import (
    pem_condition_number,
    pem_design,
    pem_settings,
    reduce_pem,
)
from analysis.polarimetry.validation import PolarimetryInputError

AMP = 2.405  # J0(A) = 0


def test_the_default_two_by_four_settings_determine_all_sixteen_elements():
    settings = pem_settings()
    assert len(settings) == 8
    w = pem_design(settings, amplitude_rad=AMP)
    assert w.shape == (24, 16) and np.linalg.matrix_rank(w) == 16
    assert pem_condition_number(settings, amplitude_rad=AMP) == pytest.approx(9.2, abs=0.05)


def test_fewer_settings_never_suffice():
    # one generator setting spans three Stokes directions: rank 12 with any analysers
    assert np.linalg.matrix_rank(pem_design(pem_settings((0.0,)), amplitude_rad=AMP)) == 12
    # three analyser settings span three analyser directions: rank 12 as well
    three = pem_settings(analyser_retarder_deg=(-75.0, 0.0, 75.0))
    assert np.linalg.matrix_rank(pem_design(three, amplitude_rad=AMP)) == 12
    # and no 7 of the 8 settings make the matrix full rank (the 2 × 4 set is minimal)
    full = pem_settings()
    for subset in itertools.combinations(full, 7):
        assert np.linalg.matrix_rank(pem_design(subset, amplitude_rad=AMP)) < 16
    assert math.isinf(pem_condition_number(full[:4], amplitude_rad=AMP))


def test_reduce_pem_recovers_each_geometry_within_its_sigma():
    rng = np.random.default_rng(7)
    settings = pem_settings()
    w = pem_design(settings, amplitude_rad=AMP)
    truths = {"polariser 30°": linear_polariser(math.radians(30.0)),
              "quarter wave": linear_retarder(math.radians(20.0), math.pi / 2)}
    geometry, setting, readings = [], [], []
    for label, m in truths.items():
        clean = (w @ m.ravel()).reshape(len(settings), 3)
        for s in rng.permutation(len(settings)):  # the run's order need not be the rows'
            geometry.append(label)
            setting.append(int(s))
            readings.append(clean[s])
    sigma = 1e-3
    noisy = np.array(readings) + sigma * rng.standard_normal((len(readings), 3))
    out = reduce_pem(geometry, setting, noisy, np.full_like(noisy, sigma), w)
    assert list(out) == list(truths)
    for label, m in truths.items():
        est = out[label]
        assert est.dof == 24 - 16
        pull = (est.m - m) / est.sigma
        assert np.all(np.abs(pull) < 4.0), (label, np.round(pull, 2))


def test_a_geometry_missing_settings_is_named():
    w = pem_design(pem_settings(), amplitude_rad=AMP)
    geometry = ["a"] * 8 + ["b"] * 7
    setting = [*range(8), *range(7)]
    ones = np.ones((15, 3))
    with pytest.raises(PolarimetryInputError, match=r"geometry 'b'.*rank"):
        reduce_pem(geometry, setting, ones, ones, w)
    with pytest.raises(PolarimetryInputError, match=r"setting must be integers in 0\.\.7"):
        reduce_pem(["a"], [8], np.ones((1, 3)), np.ones((1, 3)), w)
    with pytest.raises(PolarimetryInputError, match=r"w must have shape \(3·S, 16\)"):
        reduce_pem(["a"], [0], np.ones((1, 3)), np.ones((1, 3)), w[:4])
