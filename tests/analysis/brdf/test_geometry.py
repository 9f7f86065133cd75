"""Angle conventions of analysis.brdf.geometry."""

import numpy as np
import pytest

from analysis.brdf.geometry import (
    MU_FLOOR,
    angles_from_vector,
    direction,
    make_geometry,
    mirror_direction,
)


def test_specular_direction_is_phi_plus_pi() -> None:
    ti = np.radians(35.0)
    t, p = mirror_direction(ti, 0.3)
    g = make_geometry(ti, 0.3, t, p)
    # at the mirror direction the half vector is the normal and 2β = 2θi
    assert g.cos_theta_h == pytest.approx(1.0, abs=1e-12)
    assert g.cos_2beta == pytest.approx(np.cos(2 * ti), abs=1e-12)
    assert g.cos_alpha == pytest.approx(1.0, abs=1e-12)
    assert g.s_r == pytest.approx(g.s_i, abs=1e-12)


def test_cos_2beta_matches_physics_formula() -> None:
    rng = np.random.default_rng(0)
    ti, tr = rng.uniform(0, np.pi / 2, (2, 50))
    pi_, pr = rng.uniform(-np.pi, np.pi, (2, 50))
    g = make_geometry(ti, pi_, tr, pr)
    expect = np.cos(ti) * np.cos(tr) + np.sin(ti) * np.sin(tr) * np.cos(pr - pi_)
    np.testing.assert_allclose(g.cos_2beta, expect, atol=1e-12)
    # cos θn = (cosθi + cosθr) / (2 cos β)  (Torrance & Sparrow 1967)
    np.testing.assert_allclose(
        g.cos_theta_h, (np.cos(ti) + np.cos(tr)) / (2 * g.cos_beta), rtol=1e-10
    )


def test_grazing_is_floored_not_zero() -> None:
    g = make_geometry(np.pi / 2, 0.0, np.pi / 2, np.pi)
    assert g.mu_i >= MU_FLOOR and g.mu_r >= MU_FLOOR
    assert np.isfinite(g.tan2_theta_h)


@pytest.mark.parametrize("bad", [-0.1, np.pi / 2 + 0.01, np.nan])
def test_rejects_angles_outside_hemisphere(bad: float) -> None:
    with pytest.raises(ValueError):
        make_geometry(bad, 0.0, 0.2, 0.0)


def test_direction_roundtrip() -> None:
    t, p = np.radians(40.0), np.radians(-120.0)
    tt, pp = angles_from_vector(direction(t, p))
    assert tt == pytest.approx(t) and pp == pytest.approx(p)


def test_swapped_exchanges_directions() -> None:
    g = make_geometry(0.2, 0.1, 0.7, 2.0)
    s = g.swapped()
    assert s.mu_i == pytest.approx(g.mu_r) and s.xr == pytest.approx(g.xi)
