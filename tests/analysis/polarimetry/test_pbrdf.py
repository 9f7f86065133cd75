"""pBRDF: frames checked against an independent 3-D Jones calculation, Fresnel identities,
and recovery of the hidden parameters from noisy Mueller data with full covariance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.brdf.fresnel import fresnel
from analysis.polarimetry import (
    PolarimetryInputError,
    drr_angles,
    instrument_matrix,
    linear_retarder,
    reduce,
)
from analysis.polarimetry.elements import rotated
from analysis.polarimetry.pbrdf import PBRDF_PARAMS, fit_pbrdf, fresnel_mueller, pbrdf


def _stokes(e: np.ndarray) -> np.ndarray:
    """Stokes vector of a Jones vector with V = 2 Im(E1 E2*) (exp(−iωt), the module's)."""
    e1, e2 = e
    return np.array([abs(e1) ** 2 + abs(e2) ** 2, abs(e1) ** 2 - abs(e2) ** 2,
                     2 * (e1 * np.conj(e2)).real, 2 * (e1 * np.conj(e2)).imag])


def test_stokes_convention_matches_the_retarder_matrix():
    # fast axis x, retardance δ: the slow y component lags, Jones diag(1, e^{iδ}) with
    # exp(i(kz − ωt)); the Stokes transform must be elements.linear_retarder(0, δ)
    delta = 0.8
    for e in ([1, 1], [1, 1j], [0.3, 0.7 - 0.2j]):
        e_in = np.array(e, dtype=complex)
        e_out = np.array([e_in[0], np.exp(1j * delta) * e_in[1]])
        np.testing.assert_allclose(linear_retarder(0.0, delta) @ _stokes(e_in),
                                   _stokes(e_out), atol=1e-14)


def _jones_3d(theta_i, phi_i, theta_r, phi_r, n):
    """The specular-facet Mueller matrix by propagating 3-D fields (no rotation matrices)."""
    wi = np.array([math.sin(theta_i) * math.cos(phi_i), math.sin(theta_i) * math.sin(phi_i),
                   math.cos(theta_i)])
    wr = np.array([math.sin(theta_r) * math.cos(phi_r), math.sin(theta_r) * math.sin(phi_r),
                   math.cos(theta_r)])
    h = (wi + wr) / np.linalg.norm(wi + wr)
    k_in, k_out = -wi, wr

    def frame(phi, k):
        s_g = np.array([-math.sin(phi), math.cos(phi), 0.0])
        return np.cross(k, s_g), -s_g

    s = np.cross(wi, wr)
    s /= np.linalg.norm(s)
    res = fresnel(float(wi @ h), n)
    rs, rp = complex(res.rs), complex(res.rp)
    e1i, e2i = frame(phi_i, k_in)
    e1o, e2o = frame(phi_r, k_out)
    m = np.zeros((4, 4))
    # four input states; M from their Stokes vectors (least squares, exact here)
    states = [np.array(v, dtype=complex) for v in ([1, 0], [0, 1], [1, 1], [1, 1j])]
    s_in, s_out = [], []
    for jv in states:
        e3 = jv[0] * e1i + jv[1] * e2i
        es, ep = e3 @ s, e3 @ np.cross(k_in, s)
        out3 = rs * es * s + rp * ep * np.cross(k_out, s)
        s_in.append(_stokes(jv))
        s_out.append(_stokes(np.array([out3 @ e1o, out3 @ e2o])))
    m = np.linalg.solve(np.array(s_in), np.array(s_out)).T
    return m


@pytest.mark.parametrize(("ti", "pi_", "tr", "pr"), [
    (0.5, 0.0, 0.5, math.pi), (0.3, 0.2, 0.9, 2.0), (1.1, -0.4, 0.2, 0.7),
    (0.7, 1.0, 0.7, 1.0 + 2.5),
])
def test_rotated_fresnel_matches_3d_jones(ti, pi_, tr, pr):
    n = complex(1.4, 3.2)
    alpha = 0.3
    spec = pbrdf([n.real, n.imag, alpha, 0.0], ti, pi_, tr, pr)[0]
    ref = _jones_3d(ti, pi_, tr, pr, n)
    # the scalar factor D·V is common: compare shapes after normalising by m00
    np.testing.assert_allclose(spec / spec[0, 0], ref / ref[0, 0], atol=1e-12)


def test_normal_incidence_specular_has_no_diattenuation():
    m = pbrdf([1.5, 0.0, 0.2, 0.0], 0.0, 0.0, 0.0, 0.0)[0]
    assert m[0, 1] == pytest.approx(0.0, abs=1e-14 * m[0, 0])


def test_brewster_angle_reflects_only_s():
    n = 1.5
    tb = math.atan(n)
    m = pbrdf([n, 0.0, 0.05, 0.0], tb, 0.0, tb, math.pi)[0]
    # in-plane, x = p: s light is −Q, so m01 = −m00 (and m10 = −m00)
    assert m[0, 1] == pytest.approx(-m[0, 0], rel=1e-12)
    assert m[1, 0] == pytest.approx(-m[0, 0], rel=1e-12)


def test_m00_is_the_scalar_microfacet_brdf_plus_lambert():
    from analysis.brdf.microfacet import beckmann_d, smith_visibility
    ti, tr = 0.4, 0.6
    m = pbrdf([1.6, 0.0, 0.25, 0.3], ti, 0.0, tr, math.pi)[0]
    h_angle = 0.5 * (tr - ti)  # in-plane: half vector tilted by (θr − θi)/2
    cos_beta = math.cos(0.5 * (ti + tr))
    vis = smith_visibility(math.cos(ti), math.cos(tr), 0.25, distribution="beckmann")
    f = beckmann_d(math.cos(h_angle), 0.25) * vis * fresnel(cos_beta, 1.6).R + 0.3 / math.pi
    assert m[0, 0] == pytest.approx(float(f), rel=1e-12)


def test_diffuse_term_is_an_ideal_depolariser():
    m = pbrdf([1.5, 0.0, 0.01, 0.5], 0.3, 0.0, 1.2, 0.0)[0]  # far from the lobe
    assert m[0, 0] == pytest.approx(0.5 / math.pi, rel=1e-9)
    np.testing.assert_allclose(m.ravel()[1:], 0.0, atol=1e-12)


def test_fresnel_mueller_is_non_depolarising():
    f = fresnel_mueller(np.linspace(0.05, 1.0, 7), complex(0.2, 3.0))
    # a pure Mueller matrix keeps tr(MᵀM) = 4 m00² (Gil–Bernabeu criterion)
    for m in f:
        assert np.trace(m.T @ m) == pytest.approx(4 * m[0, 0] ** 2, rel=1e-12)


def _synthetic(truth, seed, noise_rel=0.01):
    rng = np.random.default_rng(seed)
    g, a = drr_angles(36)
    w = instrument_matrix(g, a, psg_retardance=math.radians(127),
                          psa_retardance=math.radians(127))
    geos = [(ti, 0.0, tr, math.pi) for ti in (0.35, 0.87, 1.22)
            for tr in np.linspace(0.1, 1.3, 9)]
    ti, pi_, tr, pr = (np.array(v) for v in zip(*geos, strict=True))
    true_m = pbrdf(truth, ti, pi_, tr, pr)
    ms, covs = [], []
    for mt in true_m:
        sigma = noise_rel * mt[0, 0] + 1e-4
        est = reduce(w @ mt.ravel() + sigma * rng.standard_normal(36), sigma, w)
        ms.append(est.m)
        covs.append(est.cov)
    return np.array(ms), np.array(covs), ti, pi_, tr, pr


@pytest.mark.parametrize(("truth", "fixed", "start"), [
    # rough metal (aluminium-like index at 633 nm) with a weak diffuse layer
    ((1.4, 7.6, 0.2, 0.05, 0.0), (), (1.8, 6.0, 0.3, 0.1, 0.0)),
    # dielectric (k held at 0) with a depolarising diffuse layer
    ((1.5, 0.0, 0.3, 0.4, 0.0), ("k",), (1.3, 0.0, 0.2, 0.2, 0.0)),
    # the same in a polarimeter frame 2° off the plane of incidence
    ((1.5, 0.0, 0.3, 0.4, 2.0), ("k",), (1.3, 0.0, 0.2, 0.2, 0.0)),
])
def test_parameters_recovered_within_2_sigma(truth, fixed, start):
    pulls = []
    for seed in range(4):
        m, cov, ti, pi_, tr, pr = _synthetic(truth, seed)
        fit = fit_pbrdf(m, cov, ti, pi_, tr, pr, start=start, fixed=fixed)
        assert fit.goodness.adequate
        free = [i for i, name in enumerate(PBRDF_PARAMS) if name not in fixed]
        pulls.append((fit.params[free] - np.array(truth)[free]) / fit.sigma[free])
    p = np.abs(np.array(pulls))
    # 4 seeds × ≤5 parameters at 2σ: ~1 of 20 exceeds by chance; none beyond 3.5σ
    assert np.sum(p > 2.0) <= 3 and np.all(p < 3.5)


def test_the_frame_parameter_turns_the_matrix_about_the_beam():
    # measured in a frame at φ_f from the plane of incidence: R(φ_f) F R(−φ_f)
    ti, tr = np.array([0.6, 0.9]), np.array([0.8, 0.7])
    plain = pbrdf((1.5, 0.0, 0.2, 0.1), ti, 0.0, tr, math.pi)
    turned = pbrdf((1.5, 0.0, 0.2, 0.1, 3.0), ti, 0.0, tr, math.pi)
    for f, g in zip(plain, turned, strict=True):
        np.testing.assert_allclose(g, rotated(f, -math.radians(3.0)), atol=1e-15)
    # a turned frame moves m01 into m02 by −sin 2φ_f
    assert turned[0, 0, 2] == pytest.approx(-plain[0, 0, 1] * math.sin(math.radians(6.0)),
                                            rel=1e-12)


def test_frame_left_out_of_the_fit_leaves_chi2_at_zero_noise():
    # noise-free data 0.3° turned: with the frame held at 0 the residual χ² is the
    # systematic alone (the example's failing gate, ADR 0107); fitted, it vanishes
    truth = (1.5, 0.0, 0.15, 0.3, 0.3)
    m, cov, ti, pi_, tr, pr = _synthetic(truth, 0, noise_rel=0.0)
    m = pbrdf(truth, ti, pi_, tr, pr)
    held = fit_pbrdf(m, cov, ti, pi_, tr, pr, start=(1.5, 0, 0.2, 0.1, 0.0),
                     fixed=("k", "frame_deg"))
    fitted = fit_pbrdf(m, cov, ti, pi_, tr, pr, start=(1.5, 0, 0.2, 0.1, 0.0), fixed=("k",))
    assert held.goodness.chi2 > 1.0
    assert fitted.goodness.chi2 < 1e-8
    assert fitted.params[4] == pytest.approx(0.3, abs=1e-6)


def test_fit_input_checks():
    m = np.zeros((2, 4, 4))
    cov = np.tile(np.eye(16), (2, 1, 1))
    with pytest.raises(PolarimetryInputError) as err:
        fit_pbrdf(m, cov, [0.1, 0.2], 0.0, [0.1, 0.2], math.pi, start=(1.5, 0, 0.2, 0.1),
                  fixed=("roughness",))
    assert err.value.argument == "fixed"
    with pytest.raises(PolarimetryInputError) as err:
        fit_pbrdf(m, cov[:1], [0.1, 0.2], 0.0, [0.1, 0.2], math.pi, start=(1.5, 0, 0.2, 0.1))
    assert err.value.argument == "cov"
    with pytest.raises(PolarimetryInputError) as err:
        pbrdf((0.5, 0.0, 0.2, 0.1), 0.1, 0.0, 0.1, math.pi)
    assert err.value.argument == "params"
    with pytest.raises(PolarimetryInputError) as err:
        pbrdf((1.5, 0.0, 0.2, 0.1), 2.0, 0.0, 0.1, math.pi)
    assert err.value.argument == "theta_i"
    with pytest.raises(PolarimetryInputError, match="4 or 5 values") as err:
        pbrdf((1.5, 0.0, 0.2), 0.1, 0.0, 0.1, math.pi)
    assert err.value.argument == "params"


def test_ggx_m00_is_the_registry_model_ggx_conductor_plus_lambert():
    # the scalar route (fit_brdf, select_model) already fits m00 with this registry name
    from analysis.brdf import get_model, make_geometry
    rng = np.random.default_rng(4)
    ti, tr = rng.uniform(0.05, 1.4, 20), rng.uniform(0.05, 1.4, 20)
    pi_, pr = rng.uniform(-math.pi, math.pi, 20), rng.uniform(-math.pi, math.pi, 20)
    p = np.array([1.4, 7.6, 0.2, 0.3])
    m = pbrdf(p, ti, pi_, tr, pr, distribution="ggx")
    scalar = get_model("ggx_conductor+lambert").value_fn(p, make_geometry(ti, pi_, tr, pr))
    np.testing.assert_allclose(m[:, 0, 0], scalar, rtol=1e-10)
