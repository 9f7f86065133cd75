"""The continuous light-field renderer: geometry, quadrature convergence, radiometry."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.lightfield import FlatlandBRDF, material
from hw_mocks.sim.lightfield_scene import MATERIALS, BarObject, HiddenScene, PointObject, Wall


def test_four_thesis_materials_are_available_and_plausible():
    assert set(MATERIALS) == {"brushed_metal", "coated_paper_glossy", "coated_paper_matte",
                              "pearl_paint_glass"}
    for m in MATERIALS.values():
        assert 0 < m.specular_width_rad < np.deg2rad(10)
        assert m.specular_reflectance + m.diffuse_reflectance <= 1.0
    gam = {k: v.degree_of_specularity((-0.6, 0.6)) for k, v in MATERIALS.items()}
    assert gam["brushed_metal"] > 0.9 > gam["pearl_paint_glass"] > gam["coated_paper_matte"]


def test_disc_ray_geometry_and_interval():
    obj = PointObject(10.0, -100.0, 2.0)
    c = np.array([10.0, 40.0])
    centre = np.arctan((c - 10.0) / 100.0)
    assert np.all(obj.radiance_at(c, centre) == 1.0)
    lo, hi = obj.interval(c)
    assert np.all(obj.radiance_at(c, lo - 1e-4) == 0) and np.all(obj.radiance_at(c, hi + 1e-4)
                                                                     == 0)
    assert np.allclose(obj.radiance_at(c, lo + 1e-7), 1.0)


def test_bar_of_a_lambertian_wall_matches_the_closed_form():
    lam = FlatlandBRDF(0.0, 0.01, 0.6)
    bar = BarObject(-20.0, 30.0, -50.0, 2.0)
    scene = HiddenScene((bar,), Wall(-100, 100, lam), d2_mm=0.0)
    c = np.array([0.0, 5.0])
    out = scene.radiance(c, np.zeros(2))
    lo, hi = bar.interval(c)
    exact = 2.0 * 0.3 * (np.sin(hi) - np.sin(lo))  # ρ/2 · R · ∫ cos θ dθ
    assert np.allclose(out, exact, rtol=1e-10)


def test_quadrature_has_converged_far_below_any_noise_level():
    brdf = material("pearl_paint_glass")
    objs = (PointObject(0.0, -224.5, 3.0, 1.0, "gaussian"), BarObject(20, 60, -300, 0.5))
    ym = np.linspace(-150, 150, 101)
    tm = np.linspace(-0.5, 0.5, 101)
    coarse = HiddenScene(objs, Wall(-100, 100, brdf), 100.0).radiance(ym, tm)
    fine = HiddenScene(objs, Wall(-100, 100, brdf), 100.0,
                       panel_rad=0.05 * brdf.specular_width_rad).radiance(ym, tm)
    assert np.max(np.abs(coarse - fine)) < 1e-8 * np.max(fine)


def test_off_wall_rays_are_dark_and_inputs_broadcast():
    scene = HiddenScene((PointObject(0.0, -100.0, 2.0),), Wall(-50, 50, material(
        "brushed_metal")), d2_mm=100.0)
    assert scene.radiance(200.0, 0.0) == 0.0
    out = scene.radiance(np.zeros((3, 1)), np.linspace(-0.1, 0.1, 4)[None, :])
    assert out.shape == (3, 4)


def test_tilted_wall_moves_the_specular_peak():
    brdf = FlatlandBRDF(0.8, np.deg2rad(1.0), 0.0)
    obj = (PointObject(0.0, -200.0, 1.0),)
    th = np.linspace(-0.3, 0.3, 2001)
    flat = HiddenScene(obj, Wall(-100, 100, brdf), 0.0).radiance(np.zeros_like(th), th)
    # with the BRDF written in the local frame, f_spec depends on θ_m − θ_o only, so a
    # uniform tilt changes the obliquity cos(θ_o − Θ) but not the peak direction (eq. 2-6)
    tilt = HiddenScene(obj, Wall(-100, 100, brdf, 0.2), 0.0).radiance(np.zeros_like(th), th)
    assert th[np.argmax(flat)] == pytest.approx(0.0, abs=1e-3)
    assert th[np.argmax(tilt)] == pytest.approx(0.0, abs=1e-3)
    assert tilt.max() / flat.max() == pytest.approx(np.cos(0.2), rel=1e-3)
