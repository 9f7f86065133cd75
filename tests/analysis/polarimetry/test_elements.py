"""Mueller matrices of the elements: conventions, identities and input checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from analysis.polarimetry import (
    PolarimetryInputError,
    depolariser,
    diattenuator,
    linear_polariser,
    linear_retarder,
    rotation,
    stokes_dop,
)

H = np.array([1.0, 1.0, 0.0, 0.0])


def test_polariser_at_zero_matches_goldstein():
    expected = 0.5 * np.array([[1, 1, 0, 0], [1, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]])
    np.testing.assert_allclose(linear_polariser(0.0), expected, atol=1e-15)


def test_polariser_at_45_passes_plus_u():
    out = linear_polariser(math.pi / 4) @ np.array([1.0, 0, 0, 0])
    np.testing.assert_allclose(out, [0.5, 0, 0.5, 0], atol=1e-15)


def test_quarter_wave_at_45_makes_positive_v_from_horizontal():
    # the handedness convention of the module docstring
    np.testing.assert_allclose(linear_retarder(math.pi / 4, math.pi / 2) @ H, [1, 0, 0, 1],
                               atol=1e-15)


def test_half_wave_rotates_linear_light_by_twice_its_angle():
    out = linear_retarder(math.radians(22.5), math.pi) @ H
    np.testing.assert_allclose(out, [1, 0, 1, 0], atol=1e-15)


def test_malus_law():
    for deg in (0.0, 17.0, 45.0, 80.0):
        t = math.radians(deg)
        out = linear_polariser(t) @ linear_polariser(0.0) @ np.array([1.0, 0, 0, 0])
        assert out[0] == pytest.approx(0.5 * math.cos(t) ** 2, abs=1e-15)


def test_rotation_composes_and_inverts():
    np.testing.assert_allclose(rotation(0.3) @ rotation(0.2), rotation(0.5), atol=1e-15)
    np.testing.assert_allclose(rotation(0.3) @ rotation(-0.3), np.eye(4), atol=1e-15)


def test_crossed_polarisers_block():
    m = linear_polariser(math.pi / 2) @ linear_polariser(0.0)
    np.testing.assert_allclose(m, 0.0, atol=1e-16)


def test_retarder_preserves_degree_of_polarisation():
    rng = np.random.default_rng(3)
    for _ in range(20):
        m = linear_retarder(rng.uniform(0, math.pi), rng.uniform(0, 2 * math.pi))
        s = np.array([1.0, *rng.normal(size=3)])
        s[1:] /= np.linalg.norm(s[1:])
        assert stokes_dop(m @ s) == pytest.approx(1.0, abs=1e-12)


def test_diattenuator_and_depolariser():
    m = diattenuator(0.0, 0.8, 0.2)
    assert m[0, 0] == pytest.approx(0.5) and m[0, 1] == pytest.approx(0.3)
    assert m[2, 2] == pytest.approx(0.4)
    np.testing.assert_allclose(depolariser(0.5) @ H, [0.5, 0, 0, 0])
    assert stokes_dop(depolariser(1.0, 0.3) @ H) == pytest.approx(0.3)


def test_stokes_dop_vectorised_and_dark():
    s = np.array([[1.0, 0.6, 0, 0.8], [2.0, 0, 0, 0], [0.0, 0, 0, 0]])
    np.testing.assert_allclose(stokes_dop(s), [1.0, 0.0, 0.0])


@given(st.sampled_from([math.nan, math.inf, -math.inf]))
def test_non_finite_arguments_are_named(bad):
    with pytest.raises(PolarimetryInputError) as err:
        linear_retarder(0.0, bad)
    assert err.value.argument == "retardance_rad"
    with pytest.raises(PolarimetryInputError) as err:
        stokes_dop([1.0, bad, 0.0, 0.0])
    assert err.value.argument == "stokes"


@given(st.floats(allow_nan=False, allow_infinity=False).filter(lambda x: not 0 <= x <= 1))
def test_transmittance_outside_unit_interval_rejected(q):
    with pytest.raises(PolarimetryInputError) as err:
        diattenuator(0.0, q, 0.0)
    assert err.value.argument == "q"


def test_stokes_shape_and_negative_intensity_rejected():
    with pytest.raises(PolarimetryInputError, match="length 4"):
        stokes_dop([1.0, 0.0, 0.0])
    with pytest.raises(PolarimetryInputError, match="I = S"):
        stokes_dop([-1.0, 0.0, 0.0, 0.0])
