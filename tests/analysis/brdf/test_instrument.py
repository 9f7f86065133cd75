"""Instrument-aware models: detector aperture and beam divergence."""

import numpy as np
import pytest

from analysis.brdf import get_model
from analysis.brdf.fit import fit_brdf
from analysis.brdf.instrument import cone_quadrature, convolve_instrument
from analysis.brdf.integrate import dhr


def test_cone_quadrature_mean_cosine() -> None:
    # mean of cos δ over a uniform cone of half-angle a is (1 + cos a)/2
    for a in (0.01, 0.1, 0.5):
        q = cone_quadrature(a, n_radial=3, n_azimuth=6)
        assert q.weights.sum() == pytest.approx(1.0, rel=1e-14)
        assert np.sum(q.weights * np.cos(q.delta)) == pytest.approx((1 + np.cos(a)) / 2)
    assert cone_quadrature(0.0).delta.size == 1


def test_lambertian_seen_through_aperture() -> None:
    # f_meas = ρ/π · <cos θ'>/cos θr = ρ/π (1 + cos a)/2 away from the horizon
    a = 0.05
    m = convolve_instrument(get_model("lambert"), aperture_half_angle=a)
    tr = np.radians([0.0, 30.0, 60.0])
    got = m.evaluate([0.5], 0.2, 0.0, tr, np.pi)
    np.testing.assert_allclose(got, 0.5 / np.pi * (1 + np.cos(a)) / 2, rtol=1e-12)


def test_sharp_lobe_is_broadened_but_energy_kept() -> None:
    base = get_model("ggx")
    p = [1.0, 0.02]
    inst = convolve_instrument(
        base, aperture_half_angle=0.03, divergence_half_angle=0.01, n_radial=2, n_azimuth=6
    )
    ti = np.radians(30.0)
    peak_base = base.evaluate(p, ti, 0.0, ti, np.pi)
    peak_inst = inst.evaluate(p, ti, 0.0, ti, np.pi)
    assert peak_inst < 0.7 * peak_base
    quad = {"method": "mirror", "lobe_width": 0.01, "n_per_panel": 16, "n_chi": 48}
    e0 = dhr(base, p, ti, **quad)
    e1 = dhr(inst, p, ti, **quad)
    assert e1 == pytest.approx(e0, rel=0.01)


def test_near_specular_only_leaves_far_points_untouched() -> None:
    base = get_model("lambert+ggx")
    inst = convolve_instrument(base, aperture_half_angle=0.02, near_specular=0.2)
    p = [0.3, 0.5, 0.05]
    tr = np.radians(np.linspace(0, 80, 41))
    a = base.evaluate(p, np.radians(40.0), 0.0, tr, np.pi)
    b = inst.evaluate(p, np.radians(40.0), 0.0, tr, np.pi)
    far = np.abs(tr - np.radians(40.0)) > 0.2
    np.testing.assert_array_equal(a[far], b[far])
    assert not np.allclose(a[~far], b[~far])


def test_fitting_with_the_instrument_removes_the_width_bias() -> None:
    base = get_model("lambert+ggx")
    true = np.array([0.2, 0.6, 0.02])
    inst = convolve_instrument(base, aperture_half_angle=0.05, n_radial=3, n_azimuth=8)
    ti = np.repeat(np.radians([20.0, 40.0, 60.0]), 121)
    tr = np.tile(np.radians(np.linspace(0.0, 85.0, 121)), 3)
    f = inst.evaluate(true, ti, 0.0, tr, np.pi)
    sig = 0.02 * f
    y = f + sig * np.random.default_rng(5).standard_normal(f.size)
    naive = fit_brdf(base, y, ti, 0.0, tr, np.pi, sigma=sig, n_starts=3)
    aware = fit_brdf(inst, y, ti, 0.0, tr, np.pi, sigma=sig, n_starts=3)
    assert naive.params[2] > true[2] * 1.15  # the aperture broadens the apparent lobe
    assert abs(aware.params[2] - true[2]) < 3 * aware.stderr[2]
    assert aware.chi2 < naive.chi2
