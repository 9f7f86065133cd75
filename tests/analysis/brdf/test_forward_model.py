"""The instrument function (analysis.brdf.reduction.receiver) and the forward fit
(analysis.brdf.reduction.forward): checked against the simulated camera, which integrates
the same physics from the image side, and against closed forms."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import integrate

from analysis.brdf import get_model
from analysis.brdf.geometry import make_geometry
from analysis.brdf.reduction import (
    LEVELS,
    ReceiverGeometry,
    fit_forward,
    forward_model,
    forward_slopes,
    receiver_factor,
    receiver_model,
)
from analysis.brdf.reduction.receiver import _aspect, _disk, _unit_vectors
from tests.instrument.sim_scan import Sample, ScanSetup, noise_free, receiver, reduce_seed, render

OMEGA = math.pi * 6.25**2 / 300.0**2


@pytest.mark.parametrize(("n_x", "n_y"), [(2, 2), (3, 3), (3, 12), (5, 5)])
def test_disk_rule_is_exact_to_its_degree(n_x: int, n_y: int) -> None:
    """Mean of x^a y^b over the unit disk: 0 unless both even, then
    Γ((a+1)/2)Γ((b+1)/2)/(π Γ((a+b)/2 + 2)) (the disk's moments), for a + b < 2 min(n)."""
    x, y, w = _disk(n_x, n_y)
    assert w.sum() == pytest.approx(1.0, abs=1e-15)
    for a in range(2 * min(n_x, n_y)):
        for b in range(2 * min(n_x, n_y) - a):
            exact = 0.0
            if a % 2 == 0 and b % 2 == 0:
                exact = (math.gamma((a + 1) / 2) * math.gamma((b + 1) / 2)
                         / (math.pi * math.gamma((a + b) / 2 + 2)))
            assert np.sum(w * x**a * y**b) == pytest.approx(exact, abs=1e-14), (a, b)


def test_lobe_aspect_grows_towards_grazing_specular() -> None:
    ti = np.radians([20.0, 60.0, 80.0])
    g = make_geometry(ti, 0.0, ti, np.pi)
    assert _aspect(*_unit_vectors(g)).tolist() == [1, 2, 8]  # 1/cos θ: 1.06, 2, 5.8


def test_receiver_factor_with_the_sample_edge_is_the_beam_on_the_sample() -> None:
    """At 80° incidence the footprint (σ_u = w/(2 cos θi) = 5.8 mm) overfills a 12.5 mm
    sample: G drops by the fraction of the Gaussian beam that misses the disk, computed
    here by an independent 2-D integral."""
    w, rs = 2.0, 12.5
    rg = ReceiverGeometry(w, 300.0, 12.5, OMEGA, sample_radius_mm=rs)
    free = replace(rg, sample_radius_mm=None)
    ti, tr = np.radians([80.0, 80.0, 30.0]), np.radians([60.0, 10.0, 30.0])
    ratio = (receiver_factor(ti, 0.0, tr, np.pi, receiver=rg)
             / receiver_factor(ti, 0.0, tr, np.pi, receiver=free))
    c = math.cos(math.radians(80.0))

    def density(u: float, v: float) -> float:
        return 2.0 / (math.pi * w * w) * c * math.exp(-2.0 * (u * u * c * c + v * v) / (w * w))

    on_sample, _ = integrate.dblquad(density, -rs, rs, lambda v: -math.sqrt(rs * rs - v * v),
                                     lambda v: math.sqrt(rs * rs - v * v), epsabs=1e-12)
    np.testing.assert_allclose(ratio[:2], on_sample, rtol=5e-4)  # the 1/r² tilt across it
    assert ratio[2] == pytest.approx(1.0, abs=1e-9)  # 30°: the footprint fits


def test_forward_model_matches_the_simulated_camera_on_a_sharp_lobe() -> None:
    """GGX α = 0.02 seen by the camera integrating its pupil (the image side) against the
    forward model (the sample side) at the levels the fit's rule picks: within 0.1σ of a
    high-SNR acquisition (80 % of full well, 4 frames) at every point of a ±4° specular
    scan at 40°, where the chief ray alone is tens of σ off (the test can fail)."""
    setup = ScanSetup(theta_i_deg=(40.0,), theta_r_start=30.0, theta_r_stop=50.0,
                      theta_r_step=10.0, sensor_px=48)
    sample = Sample("sharp", "lambert+ggx", (0.3, 0.5, 0.02))
    r = render(setup, sample)
    a = r.angles_rad
    rg = receiver(setup)
    data = noise_free(r).brdf
    hi = replace(r, setup=replace(setup, fill=0.8, frames=4, min_exposure_us=1e-3))
    sigma = reduce_seed(hi, 0).u_point
    model = get_model(sample.model)
    p = np.array(sample.params)
    ff = fit_forward(model, data, *a.T, sigma=sigma, receiver=rg, start=p)
    seen = ff.model.evaluate(p, *a.T)
    assert np.max(np.abs(data - seen) / sigma) < 0.1
    assert ff.quadrature_converged and max(ff.levels.values()) >= 2  # the peak refined
    chief = receiver_model(model, replace(rg, sample_aperture=False), level=3).evaluate(
        p, *a.T)
    assert np.max(np.abs(data - chief) / sigma) > 10.0


def test_fit_forward_refines_only_where_the_lobe_needs_it() -> None:
    """A Lambertian stays at level 0 everywhere; a sharp lobe moves its peak points up and
    leaves the diffuse wings at level 0; the finest level bounds the error by its change."""
    rg = ReceiverGeometry(2.0, 300.0, 12.5, OMEGA, sample_radius_mm=12.5)
    tr = np.radians(np.concatenate([np.arange(-70.0, 81.0, 10.0), [38.0, 39.0, 41.0, 42.0]]))
    ti = np.full(tr.size, math.radians(40.0))
    pi_, pr = np.zeros(tr.size), np.where(tr >= 0, np.pi, 0.0)
    offset = np.abs(tr - ti)  # from the mirror direction (θr signed: > 0 specular side)
    tr = np.abs(tr)
    for name, p, peak_levels in (("lambert", [0.5], 0), ("lambert+ggx", [0.3, 0.5, 0.02], 2)):
        model = get_model(name)
        y = forward_model(model, rg, default_level=len(LEVELS) - 1).evaluate(p, ti, pi_, tr, pr)
        ff = fit_forward(model, y, ti, pi_, tr, pr, sigma=1e-4 * y, receiver=rg, start=p)
        # noise-free data: the quadrature bias allowed (≤ 0.1σ per point) moves the
        # parameters by a small fraction of their standard errors
        assert np.all(np.abs(ff.fit.params - p) <= 0.2 * ff.fit.stderr)
        near = offset < math.radians(3.0)
        levels = np.array([ff.levels.get(k, 0) for k in _keys(ti, pi_, tr, pr)])
        assert np.all(levels[offset > math.radians(15)] == 0)
        assert levels[near].min() >= peak_levels
        assert ff.quadrature_converged


def _keys(*angles):
    from analysis.brdf.reduction.forward import point_keys

    return point_keys(make_geometry(*angles))


def test_effective_variance_uses_the_model_slopes() -> None:
    """σ_eff² = σ² + (∂F/∂θi σθ)² + (∂F/∂θr σθ)² (Orear 1982): larger on the lobe's flanks
    than σ, equal to σ where the BRDF is flat; the slopes match finite differences of the
    forward model taken by hand."""
    st = math.radians(0.05)
    rg = ReceiverGeometry(2.0, 300.0, 12.5, OMEGA, sigma_theta_i_rad=st, sigma_theta_r_rad=st)
    model = get_model("lambert+ggx")
    p = np.array([0.3, 0.5, 0.05])
    tr = np.radians([-60.0, 2.0, 30.0, 36.0, 40.0, 44.0, 50.0, 70.0])
    ti, pi_ = np.full(tr.size, math.radians(40.0)), np.zeros(tr.size)
    pr = np.where(tr >= 0, np.pi, 0.0)
    tr = np.abs(tr)
    g = make_geometry(ti, pi_, tr, pr)
    _, d_r = forward_slopes(model, rg, p, g, np.full(tr.size, 2))
    fm = forward_model(model, rg, default_level=2)
    h = 1e-4
    by_hand = (fm.evaluate(p, ti, pi_, tr + h, pr) - fm.evaluate(p, ti, pi_, tr - h, pr)) / (2 * h)
    np.testing.assert_allclose(d_r, by_hand, rtol=1e-6, atol=1e-9)
    y = fm.evaluate(p, ti, pi_, tr, pr)
    sig = 1e-3 * y
    ff = fit_forward(model, y, ti, pi_, tr, pr, sigma=sig, receiver=rg, start=p)
    flank = (np.abs(np.degrees(tr) - 40.0) > 2.0) & (np.abs(np.degrees(tr) - 40.0) < 8.0)
    assert np.all(ff.sigma[flank] > 3.0 * sig[flank])
    assert ff.sigma[0] == pytest.approx(sig[0], rel=1e-3)


def test_beam_divergence_averages_the_lobe_over_incident_directions() -> None:
    """A 1/e² divergence half-angle θ spreads the incident direction as a Gaussian of σ =
    θ/2 per axis: the forward model with divergence equals the collimated one averaged by
    hand over a 9 × 9 Gauss–Hermite grid of incident offsets (in and across the plane of
    incidence) to 10⁻³ on a GGX α = 0.05 lobe, broadens the peak, and leaves a Lambertian
    unchanged."""
    div = 0.01  # rad
    base = ReceiverGeometry(2.0, 300.0, 12.5, OMEGA)
    wide = replace(base, beam_divergence_rad=div)
    model = get_model("lambert+ggx")
    p = np.array([0.3, 0.5, 0.05])
    ti = np.radians([40.0, 40.0, 40.0])
    tr = np.radians([40.0, 43.0, 50.0])
    pi_, pr = np.zeros(3), np.full(3, np.pi)
    with_div = forward_model(model, wide, default_level=3).evaluate(p, ti, pi_, tr, pr)
    collimated = forward_model(model, base, default_level=3)
    x, w = np.polynomial.hermite_e.hermegauss(9)
    w = w / w.sum()
    by_hand = np.zeros(3)
    for a, wa in zip(x, w, strict=True):
        for b, wb in zip(x, w, strict=True):
            # offsets of σ = div/2 in the plane of incidence (θi) and across it (φi)
            t_off = ti + a * div / 2
            p_off = pi_ + b * div / 2 / np.sin(ti)
            by_hand += wa * wb * collimated.evaluate(p, t_off, p_off, tr, pr)
    # the effect is −1.2 % at the peak; by hand the footprint follows each offset direction
    # (a 0.4 % wider or narrower 1/cos θi), the model keeps the beam's own footprint: 3e-4
    np.testing.assert_allclose(with_div, by_hand, rtol=1e-3)
    assert with_div[0] < collimated.evaluate(p, ti, pi_, tr, pr)[0]  # the peak broadens
    lam = forward_model(get_model("lambert"), wide, default_level=3)
    np.testing.assert_allclose(lam.evaluate([0.5], ti, pi_, tr, pr), 0.5 / np.pi, rtol=1e-12)
