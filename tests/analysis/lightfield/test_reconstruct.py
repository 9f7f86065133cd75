"""Reconstruction solvers, regularisation methods, diagnostics and the diffuse limit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.lightfield import (
    FlatlandBRDF,
    SpatiallyVaryingBRDF,
    coefficients,
    noise_psd_from_coefficients,
    noise_psd_from_frames,
    reconstruct,
    regularize,
    solve_curves,
    theta_grid,
)
from hw_mocks.sim.lightfield_scene import HiddenScene, PointObject, Wall

DOM = (-0.6, 0.6)
N = 128
GLOSSY = FlatlandBRDF(0.5, np.deg2rad(3.0), 0.1)


def curves(brdf, points, objects, normal=0.0, d2=100.0):
    scene = HiddenScene(tuple(objects), Wall(-100, 100, brdf, normal), d2_mm=d2)
    th = theta_grid(DOM, N)
    c = np.asarray(points, float)[:, None]
    return scene, scene.radiance(c + d2 * np.tan(th)[None, :], th[None, :])


OBJ = [PointObject(5.0, -224.5, 4.0, 1.0, "gaussian")]


def test_closed_form_equals_general_solve_on_the_same_model():
    pts = np.linspace(-40, 40, 41)
    _, m = curves(GLOSSY, pts, OBJ)
    noisy = m + np.random.default_rng(2).normal(0, 0.003 * m.max(), m.shape)
    psd = (0.003 * m.max()) ** 2 / N
    cf = solve_curves(noisy, GLOSSY, DOM, method="truncation", noise=psd, p_max=8)
    ge = solve_curves(noisy, GLOSSY, DOM, method="truncation", noise=psd, solver="general",
                      p_max=16)
    assert cf.solver == "closed_form" and ge.solver == "general"
    # truncation by |p| vs by singular-value rank (2·8 + 1 = 17 modes, rank index ≤ 16)
    assert np.allclose(cf.radiance, ge.radiance, atol=1e-6 * np.abs(cf.radiance).max())


def test_general_solver_handles_a_window_and_an_arbitrary_callable():
    windowed = FlatlandBRDF(0.5, np.deg2rad(3.0), 0.1, window_exponent=2.0)
    pts = np.linspace(-30, 30, 31)
    scene, m = curves(windowed, pts, OBJ)
    th = theta_grid(DOM, N)
    truth = coefficients(np.cos(th) * scene.incident_radiance(pts[:, None], th))
    res = solve_curves(m, windowed, DOM, method="truncation", noise=1e-14, p_max=20)
    assert res.solver == "general"

    def plain(ti, to):  # same BRDF as a bare callable: the dense 2-D Fourier route
        return windowed(ti, to)

    res2 = solve_curves(m, plain, DOM, method="truncation", noise=1e-14, p_max=20)
    low = np.abs(np.rint(np.fft.fftfreq(N) * N)) <= 3
    err1 = np.linalg.norm(res.coefficients[:, low] - truth[:, low]) / np.linalg.norm(truth[:, low])
    err2 = np.linalg.norm(res2.coefficients[:, low] - truth[:, low]) / np.linalg.norm(truth[:, low])
    assert err1 < 0.05 and err2 < 0.05


def test_purely_diffuse_wall_reports_no_recoverable_information():
    diffuse = FlatlandBRDF(0.0, np.deg2rad(3.0), 0.8)
    scene = HiddenScene(tuple(OBJ), Wall(-100, 100, diffuse), d2_mm=100.0)
    y = np.linspace(-180, 180, 181)
    lf = scene.measured_field(y, DOM, N)
    noisy = lf.with_radiance(lf.radiance + np.random.default_rng(0).normal(0, 1e-3, lf.shape))
    for method in ("wiener", "truncation", "gcv", "discrepancy"):
        rec = reconstruct(noisy, diffuse, d2_mm=100.0, method=method)
        assert not rec.recoverable
        assert "no recoverable object information" in rec.message
        assert np.all(rec.incident_field.radiance == 0.0)
        assert np.all(np.isfinite(rec.regularization.filter_factors))


def test_purely_diffuse_callable_through_the_general_solver_has_no_information():
    def lambert(ti, to):
        return np.full(np.broadcast_shapes(np.shape(ti), np.shape(to)), 0.4)

    pts = np.linspace(-60, 60, 61)
    _, m = curves(FlatlandBRDF(0.0, 0.05, 0.8), pts, OBJ)
    noisy = m + np.random.default_rng(3).normal(0, 1e-4, m.shape)
    for method in ("wiener", "truncation", "gcv"):
        res = solve_curves(noisy, lambert, DOM, method=method)
        assert res.solver == "general"
        assert not res.recoverable and "no recoverable" in res.message
        assert np.all(res.radiance == 0.0)


def test_nearly_diffuse_wall_at_low_snr_is_not_presented_as_an_object():
    weak = FlatlandBRDF(0.002, np.deg2rad(3.0), 0.8)
    pts = np.linspace(-60, 60, 61)
    _, m = curves(weak, pts, OBJ)
    noisy = m + np.random.default_rng(4).normal(0, 0.05 * m.max(), m.shape)
    res = solve_curves(noisy, weak, DOM, method="wiener")
    assert res.diagnostics.gamma[0] < 0.02
    assert not res.recoverable and "no recoverable" in res.message


@pytest.mark.parametrize("method", ["wiener", "truncation", "gcv", "discrepancy"])
def test_every_method_reports_parameter_filter_dof_and_residual(method):
    pts = np.linspace(-60, 60, 61)
    _, m = curves(GLOSSY, pts, OBJ)
    sigma = 0.01 * m.max()
    noisy = m + np.random.default_rng(7).normal(0, sigma, m.shape)
    reg = solve_curves(noisy, GLOSSY, DOM, method=method).regularization
    assert reg.method == method
    assert np.isfinite(reg.parameter)
    expected_name = {"wiener": "noise_psd", "truncation": "p_max"}.get(method, "lambda")
    assert reg.parameter_name == expected_name
    assert f"{method}: {expected_name}=" in reg.message
    assert reg.filter_factors.shape[-1] == N
    assert np.all((reg.filter_factors >= 0) & (reg.filter_factors <= 1))
    assert 3 < reg.effective_dof < 60
    # the residual of a sensible fit is of the order of the noise
    assert 0.5 < reg.residual_ratio < 2.0
    if method == "discrepancy":
        assert reg.residual_ratio == pytest.approx(1.0, rel=1e-3)


def test_noise_psd_estimates_from_tail_and_from_frames():
    pts = np.linspace(-60, 60, 61)
    _, m = curves(GLOSSY, pts, OBJ)
    sigma = 0.01 * m.max()
    rng = np.random.default_rng(8)
    noisy = m + rng.normal(0, sigma, m.shape)
    est = noise_psd_from_coefficients(coefficients(noisy))
    assert est.sigma_per_sample == pytest.approx(sigma, rel=0.05)
    frames = m[None] + rng.normal(0, sigma, (8, *m.shape))
    est2 = noise_psd_from_frames(frames)
    assert np.sqrt(est2.psd.mean() * N) == pytest.approx(sigma, rel=0.05)


def test_tilted_and_inhomogeneous_walls_reconstruct_the_object():
    tilt = 0.05
    pts = np.linspace(-40, 40, 41)
    scene, m = curves(GLOSSY, pts, OBJ, normal=tilt)
    th = theta_grid(DOM, N)
    truth = scene.incident_radiance(pts[:, None], th)
    res = solve_curves(m, GLOSSY, DOM, method="truncation", noise=1e-14, p_max=15,
                       normal_angle_rad=np.full(pts.size, tilt))
    sv = SpatiallyVaryingBRDF(GLOSSY, lambda y: 1.0 + 0.004 * y, lambda y: np.ones_like(y))
    _, m2 = curves(sv, pts, OBJ)
    res2 = solve_curves(m2, sv, DOM, method="truncation", noise=1e-14, p_max=15,
                        points_mm=pts)
    inner = np.abs(th) < 0.4
    for r in (res, res2):
        peak_est = r.radiance[:, inner].max(axis=1)
        peak_true = truth[:, inner].max(axis=1)
        # the band limit p = 15 blurs a 4 mm source at 224.5 mm by about a factor 0.6
        assert np.all(peak_est > 0.4 * peak_true)
        assert np.all(np.abs(th[inner][np.argmax(r.radiance[:, inner], axis=1)]
                             - th[inner][np.argmax(truth[:, inner], axis=1)]) <= 0.02)


def test_unobservable_modes_give_zero_not_nan():
    data = np.ones((4, 6), dtype=complex)
    gains = np.array([1.0, 0.5, 0.0, 0.0, 0.25, 0.0])
    for method in ("none", "wiener", "truncation", "gcv", "discrepancy"):
        reg = regularize(data, gains, 1e-3, method=method, levels=[0, 1, 1, 2, 2, 3])
        assert np.all(np.isfinite(reg.solution))
        assert np.all(reg.solution[:, gains == 0] == 0)
        if method == "none":
            assert "none: no filter," in reg.message and "nan" not in reg.message


@settings(max_examples=40, deadline=None)
@given(
    st.integers(1, 6),
    st.integers(2, 12),
    st.floats(1e-8, 1e2),
    st.sampled_from(["none", "wiener", "truncation", "gcv", "discrepancy"]),
    st.integers(0, 2**31 - 1),
)
def test_regularize_invariants(n_r, n_k, noise, method, seed):
    rng = np.random.default_rng(seed)
    gains = np.abs(rng.normal(size=n_k)) * (rng.random(n_k) > 0.2)
    data = rng.normal(size=(n_r, n_k)) + 1j * rng.normal(size=(n_r, n_k))
    levels = np.arange(n_k) // 2
    reg = regularize(data, gains, noise, method=method, levels=levels)
    phi = np.broadcast_to(reg.filter_factors, (n_r, n_k))
    assert np.all(np.isfinite(reg.solution))
    assert np.all((phi >= 0) & (phi <= 1))
    assert 0 <= reg.effective_dof <= n_k
    assert np.all(phi[:, gains == 0] == 0)
    if method == "truncation":
        kept = phi[0] > 0
        # a truncation keeps whole levels from 0 up to p_max (observable modes only)
        assert np.all(kept == ((levels <= reg.parameter) & (gains > 0)))
