"""Reduction from frames to BRDF with uncertainty (analysis.brdf.reduction).

Physics checks on the simulated bench (hw_mocks.sim, rendered without motion emulators by
tests/instrument/sim_scan.py): a Lambertian ρ = 0.8 sample reduces to 0.8/π within the
propagated uncertainty, the uncertainty predicts the scatter over sensor seeds, and the
absolute and relative methods agree; plus the pure pieces against closed forms.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from analysis.brdf import get_model
from analysis.brdf.fit import fit_brdf
from analysis.brdf.reduction import (
    BRDFPoints,
    DetectorNoise,
    ReceiverGeometry,
    ReferenceStandard,
    absolute_brdf,
    angular_uncertainty,
    camera_signal,
    camera_solid_angle_sr,
    pixel_response_covariance,
    receiver_factor,
    receiver_model,
    reciprocity_check,
    relative_brdf,
    scale_sensitivity,
    solid_angle_sr,
    subtract_signature,
    with_correlated_uncertainty,
    with_scale_uncertainty,
)
from tests.instrument.sim_scan import (
    SAMPLES,
    Sample,
    ScanSetup,
    receiver,
    reduce_seed,
    render,
)

LAMBERT = SAMPLES[0]


@pytest.fixture(scope="module")
def lambert_scan():
    return render(ScanSetup(), LAMBERT)


def test_difference_noise_formula() -> None:
    n = DetectorNoise(0.2, 2.5, 4000.0, dark_current_e_per_s=100.0)
    # two frames, each K²(σ² + i t) + 1/12, with t = 0.1 s → μ_d = 10 e⁻
    want = math.sqrt(2 * (0.04 * (6.25 + 10.0) + 1 / 12))
    assert n.difference_noise_dn(1e5) == pytest.approx(want, rel=1e-12)
    assert n.difference_noise_dn(1e5, n_averaged=4, n_dark_averaged=4) == pytest.approx(
        want / 2, rel=1e-12)
    with pytest.raises(ValueError):
        DetectorNoise(0.0, 2.5, 4000.0)


def _synthetic_frames(rng, lam_e, k, read_e, black=40.0, sat=4095):
    e = rng.poisson(lam_e) + read_e * rng.standard_normal(lam_e.shape)
    return np.clip(np.rint(k * e + black), 0, sat)


def test_camera_signal_unbiased_and_variance_predicts_scatter() -> None:
    rng = np.random.default_rng(5)
    k, read = 0.25, 3.0
    yy, xx = np.mgrid[:24, :24]
    lam = 3000.0 * np.exp(-((xx - 11.5) ** 2 + (yy - 12.0) ** 2) / 18.0)  # e⁻ in 1000 µs
    noise = DetectorNoise(k, read, 4095.0)
    truth = lam.sum() * k / 1000.0  # DN/µs
    z = []
    for _ in range(300):
        light = _synthetic_frames(rng, lam, k, read)
        dark = _synthetic_frames(rng, np.zeros_like(lam), k, read)
        s = camera_signal(light[None], [1000.0], dark[None], noise=noise)
        z.append((s.rate_dn_per_us - truth) / s.sigma)
    z = np.array(z)
    # 300 draws: the mean of z has σ 0.058, its std a relative σ of 4 %
    assert abs(z.mean()) < 0.2
    assert 0.88 < z.std() < 1.12


def test_camera_signal_hdr_brackets_and_mask() -> None:
    rng = np.random.default_rng(6)
    k, read = 0.25, 3.0
    lam_rate = np.full((8, 8), 2.0)  # e⁻/µs
    lam_rate[3:5, 3:5] = 20.0  # saturates the long bracket only
    noise = DetectorNoise(k, read, 4095.0)
    t = np.array([1000.0, 125.0])
    light = np.array([_synthetic_frames(rng, lam_rate * ti, k, read) for ti in t])
    dark = np.array([_synthetic_frames(rng, np.zeros((8, 8)), k, read) for _ in t])
    s = camera_signal(light, t, dark, noise=noise)
    truth = lam_rate.sum() * k
    assert s.saturated_pixels == 0
    assert abs(s.rate_dn_per_us - truth) < 4 * s.sigma
    mask = np.zeros((8, 8), bool)
    mask[3:5, 3:5] = True
    m = camera_signal(light, t, dark, noise=noise, mask=mask)
    assert m.n_pixels == 4
    assert abs(m.rate_dn_per_us - 4 * 20.0 * k) < 4 * m.sigma
    before = light.copy()
    camera_signal(light, t, dark, noise=noise, flat=np.full((8, 8), 2.0))
    np.testing.assert_array_equal(light, before)  # inputs never modified


def test_solid_angle_exact_cone_and_propagation() -> None:
    om, u = solid_angle_sr(5.0, 300.0, u_diameter_mm=0.01, u_distance_mm=0.5)
    assert om == pytest.approx(math.pi * 2.5**2 / 300.0**2, rel=1e-4)  # A/R² to (a/2R)²
    # first-order propagation against finite differences
    h = 1e-2  # central differences: O(h²) truncation, no cancellation trouble
    dd = (solid_angle_sr(5.0 + h, 300.0)[0] - solid_angle_sr(5.0 - h, 300.0)[0]) / (2 * h)
    dr = (solid_angle_sr(5.0, 300.0 + h)[0] - solid_angle_sr(5.0, 300.0 - h)[0]) / (2 * h)
    assert u == pytest.approx(math.hypot(dd * 0.01, dr * 0.5), rel=1e-5)
    assert u / om == pytest.approx(math.hypot(2 * 0.01 / 5, 2 * 0.5 / 300), rel=1e-3)


def test_lambertian_sample_reduces_to_rho_over_pi(lambert_scan) -> None:
    pts = reduce_seed(lambert_scan, seed=11)
    truth = 0.8 / math.pi
    z = (pts.brdf - truth) / pts.u_point
    assert np.all(np.abs(z) < 4.5)
    # inverse-variance mean of 57 points: 0.8/π within 3σ of its propagated uncertainty
    w = 1 / pts.u_point**2
    mean = np.sum(w * pts.brdf) / w.sum()
    assert abs(mean - truth) < 3 / math.sqrt(w.sum())
    assert pts.method == "absolute" and not pts.cosine_corrected


def test_uncertainty_predicts_scatter_over_seeds(lambert_scan) -> None:
    runs = np.array([reduce_seed(lambert_scan, seed=s).brdf for s in range(24)])
    pred = reduce_seed(lambert_scan, seed=99).u_point
    ratio = runs.std(axis=0, ddof=1) / pred
    # 24 seeds: each ratio has a relative σ ≈ 15 %; the median over 57 points is tight
    assert 0.85 < np.median(ratio) < 1.15
    assert np.all((ratio > 0.45) & (ratio < 1.7))


def test_cosine_corrected_flag(lambert_scan) -> None:
    plain = reduce_seed(lambert_scan, seed=3)
    cc = absolute_brdf(
        plain.brdf * np.cos(plain.theta_r), plain.u_stat * np.cos(plain.theta_r),
        plain.theta_i, plain.phi_i, plain.theta_r, plain.phi_r,
        incident_power_w=1.0, solid_angle=1.0, cosine_corrected=True)
    np.testing.assert_allclose(cc.brdf, plain.brdf * np.cos(plain.theta_r), rtol=1e-12)
    f, u = cc.plain_brdf()
    np.testing.assert_allclose(f, plain.brdf, rtol=1e-12)
    np.testing.assert_allclose(u, plain.u_stat, rtol=1e-12)


def _signals(rendered, seed):
    """(signal, σ) in W from the reduction's absolute-method output (undo P_i Ω cos θr)."""
    pts = reduce_seed(rendered, seed=seed)
    s = rendered.setup
    om, _ = solid_angle_sr(s.aperture_mm, s.distance_mm)
    c = s.power_w * om * np.cos(pts.theta_r)
    return pts, pts.brdf * c, pts.u_stat * c


def test_relative_and_absolute_methods_agree(lambert_scan) -> None:
    ref = render(ScanSetup(), Sample("ptfe", "lambert", (0.99,)))
    pts, s, us = _signals(lambert_scan, 21)
    _, r, ur = _signals(ref, 22)
    rel = relative_brdf(s, us, r, ur, pts.theta_i, pts.phi_i, pts.theta_r, pts.phi_r,
                        reference=ReferenceStandard.uniform("ptfe", 0.99))
    assert rel.method == "relative"
    # the two differ only by the reference's own noise: z over 57 points ~ N(0, 1)
    z = (rel.brdf / pts.brdf - 1) / (ur / r)
    assert abs(z.mean()) < 0.5 and 0.7 < z.std() < 1.3
    assert np.all(rel.u_stat > pts.u_stat)  # both signals' noise


def test_relative_method_uses_the_reference_table_not_rho_over_pi(lambert_scan) -> None:
    # a non-Lambertian "PTFE": Oren–Nayar σ = 0.5, i.e. 10-40 % off ρ/π at large angles
    ptfe = Sample("ptfe-on", "oren_nayar", (0.99, 0.5))
    ref = render(ScanSetup(), ptfe)
    pts, s, us = _signals(lambert_scan, 31)
    _, r, ur = _signals(ref, 32)
    ti = np.arange(0.0, 90.0, 2.0)
    tr = np.arange(-88.0, 89.0, 2.0)
    tig, trg = np.meshgrid(np.radians(ti), np.radians(tr), indexing="ij")
    table = get_model("oren_nayar").evaluate(
        [0.99, 0.5], tig, 0.0, np.abs(trg), np.where(trg >= 0, np.pi, 0.0))
    std = ReferenceStandard("ptfe-on", ti, tr, table, np.full(table.shape, 0.0))
    good = relative_brdf(s, us, r, ur, pts.theta_i, pts.phi_i, pts.theta_r, pts.phi_r,
                         reference=std)
    naive = relative_brdf(s, us, r, ur, pts.theta_i, pts.phi_i, pts.theta_r, pts.phi_r,
                          reference=ReferenceStandard.uniform("ρ/π", 0.99))
    truth = 0.8 / math.pi
    z_good = (good.brdf - truth) / good.u_point
    z_naive = (naive.brdf - truth) / naive.u_point
    # the 2° bilinear table adds < 0.3 % interpolation error; the ρ/π shortcut is far off
    assert np.mean(np.abs(z_good) < 3.5) > 0.95
    assert np.max(np.abs(z_naive)) > 8


def test_signature_subtraction_recovers_the_sample() -> None:
    from hw_mocks.sim.goniometer_scene import GoniometerScene

    setup = ScanSetup(theta_i_deg=(30.0,), specular_half_width_deg=0.0, fill=0.05)
    # the veil adds to every pixel; render sample-with-veil and the no-sample veil alone
    with_sig = _render_scene(setup, GoniometerScene(
        brdf=_truth(LAMBERT), signature_sr=0.05, signature_width_deg=20.0))
    sig_only = _render_scene(setup, GoniometerScene(
        brdf=_truth(LAMBERT), target="none", signature_sr=0.05, signature_width_deg=20.0))
    a = reduce_seed(with_sig, seed=1)
    b = reduce_seed(sig_only, seed=2)
    assert np.max(b.brdf / b.u_point) > 10  # the signature is well above the noise
    clean = subtract_signature(a, b.brdf, b.u_point)
    z = (clean.brdf - 0.8 / math.pi) / clean.u_point
    assert np.all(np.abs(z) < 4) and clean.method == "absolute-signature"
    assert np.mean((a.brdf - 0.8 / math.pi) / a.u_point) > 3  # not subtracting is biased


def _truth(sample):
    from hw_mocks.sim.goniometer_scene import brdf_from_model

    return brdf_from_model(sample.model, sample.params)


def _render_scene(setup, scene):
    return render(setup, LAMBERT, scene=scene)


def test_angular_uncertainty_from_local_slope() -> None:
    tr = np.radians(np.array([10.0, 20.0, 30.0, 40.0, 10.0, 20.0, 30.0]))
    ti = np.radians(np.array([30.0, 30.0, 30.0, 30.0, 50.0, 50.0, 50.0]))
    f = 0.1 + 0.5 * tr + 0.2 * ti  # slopes: 0.5 /rad in θr, 0.2 /rad in θi
    u = angular_uncertainty(f, ti, tr, sigma_theta_r=0.01)
    np.testing.assert_allclose(u, 0.005, rtol=1e-9)
    # θi 20° apart: not differenced by default (a coarse grid's difference is no local
    # slope; the instrument-aware fit takes it from the model), but when allowed
    u_coarse = angular_uncertainty(f, ti, tr, sigma_theta_r=0.01, sigma_theta_i=0.02)
    np.testing.assert_allclose(u_coarse, 0.005, rtol=1e-9)
    u2 = angular_uncertainty(f, ti, tr, sigma_theta_r=0.01, sigma_theta_i=0.02,
                             max_step_i_rad=math.radians(25.0))
    np.testing.assert_allclose(u2[:3], math.hypot(0.005, 0.004), rtol=1e-9)
    assert u2[3] == pytest.approx(0.005)  # θr = 40° measured at one θi only
    assert np.all(angular_uncertainty(f, ti, tr) == 0.0)


def test_angular_uncertainty_out_of_plane_with_read_back_jitter() -> None:
    # a hemisphere scan: two receiver rings (θr = 50°, 60°) at one incidence, stage
    # read-backs jittering by ~10⁻⁵ rad. The θr slope is 0.5 /rad at every azimuth; there is
    # no θi slope to measure (one incidence). Differencing across azimuths or over the jitter
    # would give |Δf|/10⁻⁵ rad ≈ 10⁴ /rad instead.
    rng = np.random.default_rng(21)
    phr = np.radians(np.arange(100.0, 261.0, 20.0))
    tr = np.radians(np.repeat([50.0, 60.0], phr.size))
    pr = np.tile(phr, 2)
    ti = np.full(tr.size, np.radians(30.0))
    ti, tr = ti + 1e-5 * rng.standard_normal(ti.size), tr + 1e-5 * rng.standard_normal(tr.size)
    f = 0.1 + 0.5 * tr + 0.2 * np.cos(pr)
    u = angular_uncertainty(f, ti, tr, sigma_theta_i=0.01, sigma_theta_r=0.01,
                            phi_i=np.zeros_like(ti), phi_r=pr)
    np.testing.assert_allclose(u, 0.5 * 0.01, rtol=1e-3)


def test_reciprocity_pairs_and_z() -> None:
    deg = np.radians
    # in-plane, specular side (φr = φi + π): (20→40) and (40→20) are reciprocal
    ti = deg(np.array([20.0, 40.0, 20.0, 60.0]))
    tr = deg(np.array([40.0, 20.0, 60.0, 30.0]))
    pi_ = np.zeros(4)
    pr = np.full(4, np.pi)
    f = np.array([0.30, 0.31, 0.2, 0.1])
    u = np.full(4, 0.01)
    pts = BRDFPoints(ti, pi_, tr, pr, f, u, np.zeros(4), np.zeros(4), 0.0, False, "absolute")
    chk = reciprocity_check(pts)
    assert chk.n_pairs == 1 and tuple(chk.pairs[0]) == (0, 1)
    assert chk.z[0] == pytest.approx(-0.01 / math.hypot(0.01, 0.01))
    assert chk.fraction_within_2sigma == 1.0
    # the same pair written with the reciprocal's azimuths (φi = π, φr = 0): found with and
    # without the isotropy assumption
    pts2 = replace(pts, phi_i=np.array([0.0, np.pi, 0.0, 0.0]),
                   phi_r=np.array([np.pi, 0.0, np.pi, np.pi]))
    assert reciprocity_check(pts2, isotropic=False).n_pairs == 1
    assert reciprocity_check(pts, isotropic=False).n_pairs == 0


def test_scale_uncertainty_goes_to_amplitudes_only() -> None:
    rng = np.random.default_rng(2)
    model = get_model("lambert+ggx")
    truth = np.array([0.3, 0.5, 0.2])
    ti = np.radians(np.repeat([20.0, 40.0, 60.0], 30))
    tr = np.radians(np.tile(np.linspace(0.0, 80.0, 30), 3))
    pr = np.full(ti.shape, np.pi)
    f = model.evaluate(truth, ti, 0.0, tr, pr)
    sig = 0.01 * f
    y = f + sig * rng.standard_normal(f.shape)
    fit = fit_brdf(model, y, ti, 0.0, tr, pr, sigma=sig)
    dp = scale_sensitivity(model, fit.params, ti, 0.0, tr, pr, sigma=sig)
    np.testing.assert_allclose(dp[:2], fit.params[:2], rtol=1e-6)
    assert abs(dp[2]) < 1e-6 * fit.params[2]
    out = with_scale_uncertainty(fit, model, ti, 0.0, tr, pr, sigma=sig, scale_rel=0.02)
    np.testing.assert_allclose(out.stderr[:2] ** 2,
                               fit.stderr[:2] ** 2 + (0.02 * fit.params[:2]) ** 2, rtol=1e-6)
    assert out.stderr[2] == pytest.approx(fit.stderr[2], rel=1e-6)
    assert with_scale_uncertainty(fit, model, ti, 0.0, tr, pr, sigma=sig,
                                  scale_rel=0.0) is fit


def test_reference_table_interpolation_and_limits() -> None:
    ti = np.array([0.0, 40.0, 80.0])
    tr = np.array([-80.0, 0.0, 80.0])
    table = 0.3 + 0.001 * ti[:, None] + 0.0005 * tr[None, :]  # bilinear exactly
    std = ReferenceStandard("lin", ti, tr, table, 0.01)
    f, u = std.evaluate(np.radians([20.0, 20.0]), [0.0, 0.0], np.radians([30.0, 30.0]),
                        [np.pi, 0.0])
    np.testing.assert_allclose(f, [0.3 + 0.02 + 0.015, 0.3 + 0.02 - 0.015], rtol=1e-12)
    np.testing.assert_allclose(u, 0.01 * f, rtol=1e-12)
    with pytest.raises(ValueError, match="outside"):
        std.evaluate(np.radians(85.0), 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="increasing"):
        ReferenceStandard("bad", ti[::-1], tr, table, 0.0)


def test_absolute_scale_budget_and_validation() -> None:
    t = np.radians([10.0, 20.0, 30.0])
    pts = absolute_brdf([1e-9, 2e-9, 3e-9], 1e-11, t, 0.0, t, np.pi,
                        incident_power_w=1e-3, u_incident_power_w=1e-5,
                        solid_angle=2e-4, u_solid_angle=4e-6, u_responsivity_rel=0.02)
    assert pts.u_scale_rel == pytest.approx(math.sqrt(0.01**2 + 0.02**2 + 0.02**2))
    np.testing.assert_allclose(pts.u_total, np.hypot(pts.u_point,
                                                     pts.brdf * pts.u_scale_rel))
    sub = pts.take([0, 2])
    assert sub.n == 2 and sub.brdf[1] == pts.brdf[2]
    with pytest.raises(ValueError):
        absolute_brdf([1.0], 0.1, [0.1, 0.2], 0.0, 0.1, 0.0, incident_power_w=1.0,
                      solid_angle=1.0)
    with pytest.raises(ValueError):
        absolute_brdf([1.0], 0.1, 0.1, 0.0, 0.1, 0.0, incident_power_w=0.0, solid_angle=1.0)
    assert replace(pts, method="x").method == "x"  # frozen dataclass, copied with replace


# ------------------------------------------------------------------------ receiver geometry
def _noise_free(setup: ScanSetup, sample: Sample):
    """(angles (n, 4), collected power (n,) W) of a noise-free rendering."""
    r = render(setup, sample)
    photon_j = 6.62607015e-34 * 299792458.0 / 633e-9
    power = r.photon_rate.reshape(len(r.photon_rate), -1).sum(axis=1) * photon_j
    return r.angles_rad, power


def test_receiver_model_reproduces_the_simulated_camera() -> None:
    """Noise-free camera rendering (the footprint seen through the whole pupil, pixels
    integrated over their area) against the receiver model: equal to 10⁻⁸ at quadrature
    level 2 (10⁻⁶ already at level 0 for this broad lobe), where the point-sample
    reduction (cone Ω, G = 1, f at the nominal angles) is off by +3…+4·10⁻⁴ on the diffuse
    side and −4·10⁻³ on the specular peak (the camera-method bias and
    the pupil's average)."""
    setup = ScanSetup()
    sample = SAMPLES[1]
    a, power = _noise_free(setup, sample)
    rg = receiver(setup)
    pts = absolute_brdf(power, 1e-3 * power, *a.T, incident_power_w=setup.power_w,
                        solid_angle=rg.solid_angle_sr, receiver=rg)
    model = get_model(sample.model)
    seen = receiver_model(model, rg, level=2).evaluate(np.array(sample.params), *a.T)
    np.testing.assert_allclose(pts.brdf, seen, rtol=1e-8)
    coarse = receiver_model(model, rg, level=0).evaluate(np.array(sample.params), *a.T)
    np.testing.assert_allclose(pts.brdf, coarse, rtol=1e-6)
    assert pts.receiver == rg
    # the old reduction: exact-cone Ω, no receiver factor, the BRDF at the nominal angles
    cone, _ = solid_angle_sr(setup.aperture_mm, setup.distance_mm)
    old = absolute_brdf(power, 1e-3 * power, *a.T, incident_power_w=setup.power_w,
                        solid_angle=cone).brdf
    nominal = model.evaluate(np.array(sample.params), *a.T)
    bias = old / nominal - 1
    assert np.max(bias) > 3e-4 and np.min(bias) < -3e-3


def test_receiver_factor_limits() -> None:
    """G for a tiny beam: 1 for the pinhole with Ω = A/R² (camera equation); the disk's
    projected solid angle π sin²a = πρ²/(R² + ρ²) over Ω for an integrated aperture (the
    tilted-cone identity ∫ cos θ dω = cos θr π sin²a, Nicodemus' projected solid angle)."""
    ti, tr = np.radians([0.0, 30.0, 60.0]), np.radians([0.0, 45.0, 80.0])
    zero, pi_ = np.zeros(3), np.full(3, np.pi)
    om, _ = camera_solid_angle_sr(12.5, 300.0)
    assert om == pytest.approx(math.pi * 6.25**2 / 300.0**2, rel=1e-12)
    pin = ReceiverGeometry(1e-4, 300.0, 12.5, om, sample_aperture=False)
    np.testing.assert_allclose(receiver_factor(ti, zero, tr, pi_, receiver=pin), 1.0,
                               rtol=1e-9)
    cone, _ = solid_angle_sr(12.5, 300.0)
    disk = ReceiverGeometry(1e-4, 300.0, 12.5, cone, sample_aperture=True)
    proj = math.pi * 6.25**2 / (300.0**2 + 6.25**2)
    np.testing.assert_allclose(receiver_factor(ti, zero, tr, pi_, receiver=disk) * cone,
                               proj, rtol=1e-9)
    # a 2 mm beam: the footprint's 1/r² and obliquities, a few 10⁻⁴ at most here
    wide = replace(pin, beam_radius_mm=2.0)
    g = receiver_factor(ti, zero, tr, pi_, receiver=wide)
    assert np.all(np.abs(g - 1) < 5e-4) and np.any(np.abs(g - 1) > 1e-5)
    with pytest.raises(ValueError):
        ReceiverGeometry(0.0, 300.0, 12.5, om)


def test_receiver_model_jacobian_and_subsets() -> None:
    rg = ReceiverGeometry(2.0, 300.0, 12.5, camera_solid_angle_sr(12.5, 300.0)[0],
                          sample_aperture=True)
    m = receiver_model(get_model("lambert+ggx"), rg)
    a = (np.radians([20.0, 40.0, 60.0]), np.zeros(3), np.radians([20.0, 44.0, 10.0]),
         np.array([np.pi, np.pi, 0.0]))
    p = np.array([0.3, 0.5, 0.2])
    from analysis.brdf.geometry import make_geometry
    from analysis.brdf.model import numeric_jacobian

    g = make_geometry(*a)
    np.testing.assert_allclose(m.jacobian_geometry(p, g),
                               numeric_jacobian(m.value_fn, p, g, rel_step=1e-6), rtol=1e-5)
    # a Lambertian is unchanged by the averaging (normalised weights)
    lam = receiver_model(get_model("lambert"), rg)
    np.testing.assert_allclose(lam.evaluate([0.8], *a), 0.8 / np.pi, rtol=1e-12)
    # subsets of a geometry (cross-validation folds) evaluate the same points
    full = m.evaluate_geometry(p, g)
    np.testing.assert_allclose(m.evaluate_geometry(p, g.take(np.array([2, 0]))),
                               full[[2, 0]], rtol=1e-12)


def test_pixel_response_covariance_against_monte_carlo() -> None:
    """Σ s_j(1 + ε)/Σ s_j over random PRNU maps: the sample covariance of three overlapping
    spot images against u² Σ s_j s_k/(S_j S_k), per pixel and from 4 × 4 block sums."""
    rng = np.random.default_rng(11)
    y, x = np.mgrid[0:64, 0:64]

    def spot(cx, cy, sx, sy):
        return np.exp(-0.5 * (((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))

    imgs = np.array([spot(32, 32, 6, 6), spot(34, 31, 3, 7), spot(20, 40, 5, 4)])
    u = 0.01
    want = pixel_response_covariance(imgs, u_response_rel=u)
    eps = u * rng.standard_normal((4000, 64, 64))
    err = np.einsum("kij,nij->nk", imgs, eps) / imgs.sum(axis=(1, 2))
    got = np.cov(err, rowvar=False)
    # 4000 draws: entries known to about ±2.5 % of the diagonal scale
    scale = np.sqrt(np.outer(np.diag(want), np.diag(want)))
    assert np.all(np.abs(got - want) < 0.07 * scale)
    blocks = imgs.reshape(3, 16, 4, 16, 4).sum(axis=(2, 4))
    sq = np.sum(imgs**2, axis=(1, 2))
    approx = pixel_response_covariance(blocks, u_response_rel=u, block=4, sq_sums=sq)
    np.testing.assert_allclose(np.diag(approx), np.diag(want), rtol=1e-12)
    # off the diagonal only the correlation comes from the blocks (σ = 3 px spot: 10 %)
    assert np.all(np.abs(approx - want) < 0.1 * scale)


def test_correlated_uncertainty_reduces_to_the_scale_case(lambert_scan) -> None:
    pts = reduce_seed(lambert_scan, seed=4)
    model = get_model("lambert")
    a = (pts.theta_i, pts.phi_i, pts.theta_r, pts.phi_r)
    fit = fit_brdf(model, pts.brdf, *a, sigma=pts.u_point)
    s = with_scale_uncertainty(fit, model, *a, sigma=pts.u_point, scale_rel=0.01)
    fm = model.evaluate(fit.params, *a)  # the scale acts on the model's values
    c = with_correlated_uncertainty(fit, model, *a, sigma=pts.u_point,
                                    cov=1e-4 * np.outer(fm, fm))
    np.testing.assert_allclose(c.covariance, s.covariance, rtol=1e-9)
    sub = replace(pts, cov_corr=np.outer(pts.brdf, pts.brdf)).take(np.array([3, 1]))
    np.testing.assert_allclose(sub.cov_corr, np.outer(pts.brdf[[3, 1]], pts.brdf[[3, 1]]))
