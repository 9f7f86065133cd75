"""Refocusing, the depth filter, resolution formulas and placement on the object side."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.lightfield import (
    FlatlandBRDF,
    LightField2D,
    depth_profile,
    fourier_orders,
    point_response,
    reconstruct,
    refocus,
    theoretical_resolution,
    theta_grid,
)
from hw_mocks.sim.lightfield_scene import HiddenScene, PointObject, Wall

DOM = (-0.6, 0.6)
N = 128
WALL = np.linspace(-100, 100, 401)
SOLV = (-0.45, 0.45)


def empty_wall() -> LightField2D:
    return LightField2D(np.zeros((WALL.size, N)), WALL, theta_grid(DOM, N), DOM)


def test_rp_refocusing_preserves_radiance_where_conventional_loses_it():
    th = theta_grid(DOM, N)
    # an ideal (unfiltered) point source: radiance 1 on every ray through it
    lf = empty_wall()
    vals = []
    for y0 in (0.0, 70.0):
        t_star = np.arctan((WALL - y0) / 200.0)
        on = np.abs(th[None, :] - t_star[:, None]) <= 0.5 * lf.dtheta_rad
        st = refocus(lf.with_radiance(on / 1.0), y_mm=[y0], z_mm=[-200.0],
                     solvable_domain_rad=SOLV)
        vals.append((st.conventional[0, 0], st.radiance_preserving[0, 0],
                     st.measure_rad[0, 0]))
    (c0, rp0, m0), (c1, rp1, m1) = vals
    assert m1 < 0.8 * m0  # the off-centre source sees less of the wall in the domain
    assert rp0 == pytest.approx(1.0, abs=0.1) and rp1 == pytest.approx(1.0, abs=0.1)
    assert c1 / c0 == pytest.approx(m1 / m0, rel=0.05)


def test_depth_filter_finds_depth_and_is_sharper_than_one_profile():
    phi = (np.abs(fourier_orders(N)) <= 12).astype(float)
    lf = point_response(empty_wall(), 0.0, -224.5, phi)
    z = np.linspace(-330, -120, 211)
    st = refocus(lf, y_mm=np.linspace(-60, 60, 241), z_mm=z, solvable_domain_rad=SOLV)
    res = theoretical_resolution(12, domain_rad=DOM, distance_mm=224.5, aperture_mm=200.0,
                                 solvable_domain_rad=SOLV)
    prof, freqs = depth_profile(st, 0.0, window_halfwidth_mm=2 * res.transverse_mm,
                                max_frequency_per_mm=1 / res.transverse_mm,
                                min_frequency_per_mm=0.1 / res.transverse_mm)
    assert abs(z[np.argmax(prof)] + 224.5) < res.depth_mm
    one, _ = depth_profile(st, 0.0, window_halfwidth_mm=2 * res.transverse_mm,
                           max_frequency_per_mm=freqs[0] * 1.001,
                           min_frequency_per_mm=0.0)
    prod = prof ** freqs.size  # the product itself (prof is its geometric mean)
    assert np.count_nonzero(prod > 0.5) < np.count_nonzero(one > 0.5)


def test_window_removes_interference_of_an_object_at_the_same_depth():
    phi = (np.abs(fourier_orders(N)) <= 12).astype(float)
    a = point_response(empty_wall(), -30.0, -224.5, phi).radiance
    b = point_response(empty_wall(), 30.0, -200.0, phi).radiance
    lf = empty_wall().with_radiance(a + b)
    z = np.linspace(-330, -120, 211)
    st = refocus(lf, y_mm=np.linspace(-80, 80, 321), z_mm=z, solvable_domain_rad=SOLV)
    res = theoretical_resolution(12, domain_rad=DOM, distance_mm=224.5, aperture_mm=200.0,
                                 solvable_domain_rad=SOLV)
    for y0, z0 in ((-30.0, -224.5), (30.0, -200.0)):
        prof, _ = depth_profile(st, y0, window_halfwidth_mm=1.5 * res.transverse_mm,
                                max_frequency_per_mm=1 / res.transverse_mm,
                                min_frequency_per_mm=0.1 / res.transverse_mm)
        assert abs(z[np.argmax(prof)] - z0) < 0.5 * res.depth_mm


def test_resolution_scales_with_distance_and_aperture():
    r1 = theoretical_resolution(10, domain_rad=DOM, distance_mm=100, aperture_mm=80)
    r2 = theoretical_resolution(10, domain_rad=DOM, distance_mm=200, aperture_mm=80)
    r3 = theoretical_resolution(10, domain_rad=DOM, distance_mm=200, aperture_mm=160)
    assert r1.angular_rad == pytest.approx(1.2 / 21)
    assert r2.transverse_mm == pytest.approx(2 * r1.transverse_mm)
    assert r2.depth_mm == pytest.approx(4 * r1.depth_mm)
    assert r3.depth_mm == pytest.approx(r2.depth_mm / 2)
    # the aperture is capped at what the solvable domain sees from the object
    r4 = theoretical_resolution(10, domain_rad=DOM, distance_mm=50, aperture_mm=1000,
                                solvable_domain_rad=SOLV)
    assert r4.aperture_mm == pytest.approx(50 * 2 * np.tan(0.45))


def test_reconstruction_is_placed_on_the_object_side_curve():
    brdf = FlatlandBRDF(0.5, np.deg2rad(3.0), 0.1)
    scene = HiddenScene((PointObject(10.0, -150.0, 4.0, 1.0, "gaussian"),),
                        Wall(-100, 100, brdf), d2_mm=50.0)
    y = np.linspace(-160, 160, 321)
    lf = scene.measured_field(y, DOM, N)
    rec = reconstruct(lf, brdf, d2_mm=50.0, points_mm=np.linspace(-80, 80, 161),
                      method="truncation", noise=1e-12, p_max=12)
    y_o, th, vals = rec.object_samples(150.0)
    # on the object-side curves the strongest ray of every row passes the object at y = 10
    # (rows that see the object well inside the angle domain)
    inner = np.abs(th) < 0.4
    rows = np.abs(np.arctan((rec.incident_field.y_mm - 10.0) / 150.0)) < 0.3
    j = np.argmax(vals[rows][:, inner], axis=1)
    assert np.all(np.abs(y_o[rows][:, inner][np.arange(rows.sum()), j] - 10.0) < 3.0)
    obj_plane = rec.object_field(150.0)
    assert obj_plane.z_mm == pytest.approx(-150.0)
    prof = obj_plane.radiance[:, inner].sum(axis=1)
    assert abs(obj_plane.y_mm[np.argmax(prof)] - 10.0) <= 2.0


def test_joint_point_fit_jacobian_and_exact_recovery_of_an_overlapping_pair():
    """The ray-domain model behind detect_objects' joint refit (localize._fit_points).

    Its analytic (y, z) derivatives match central differences, and on the exact field of
    two point responses 1.2 δy apart (δy = 16 mm at P = 8) a fit started from where greedy
    subtraction left them (the shoulders, ±1.8× out) returns the true positions and
    amplitudes; a third component started on the merged peak ends up negligible.
    """
    from analysis.lightfield.localize import _fit_points, _ray_model

    p = 8
    phi = (np.abs(fourier_orders(N)) <= p).astype(float)
    lf0 = empty_wall()
    use = (lf0.theta_rad >= SOLV[0]) & (lf0.theta_rad <= SOLV[1])
    pos = np.array([[3.0, -210.0]])
    _, dy, dz = _ray_model(lf0, use, phi, pos)
    h = 1e-4
    for k, d in enumerate((dy, dz)):
        step = np.zeros((1, 2))
        step[0, k] = h
        num = (_ray_model(lf0, use, phi, pos + step)[0]
               - _ray_model(lf0, use, phi, pos - step)[0]) / (2 * h)
        assert np.max(np.abs(num - d)) < 1e-6 * np.max(np.abs(d))
    truth = np.array([[-10.0, -224.5], [10.0, -224.5]])
    amps = np.array([1.0, 0.7])
    field = sum(a * point_response(lf0, yk, zk, phi).radiance
                for a, (yk, zk) in zip(amps, truth, strict=True))
    g = (field * np.cos(lf0.theta_rad)[None, :])[:, use]
    box = ((-60.0, 60.0), (-330.0, -120.0))
    fit = _fit_points(g, lf0, use, phi, np.array([[-18.0, -226.0], [18.0, -226.0]]), box)
    order = np.argsort(fit.positions[:, 0])
    assert np.allclose(fit.positions[order], truth, atol=0.05)
    assert np.allclose(fit.amplitudes[order], amps, rtol=1e-3)
    assert fit.rss < 1e-8 * np.sum(g**2)
    three = _fit_points(g, lf0, use, phi,
                        np.array([[-18.0, -226.0], [0.0, -226.0], [18.0, -226.0]]), box)
    assert np.sort(np.abs(three.amplitudes))[0] < 0.05 * amps.min()
