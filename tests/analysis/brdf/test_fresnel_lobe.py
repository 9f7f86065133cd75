"""The microfacet lobe with the index as a parameter: Fresnel identities, the analytic
Jacobian, the energy bound, and that n is recovered from absolute BRDF values."""

import numpy as np
import pytest

from analysis.brdf import fit_brdf, get_model
from analysis.brdf.fresnel import fresnel, fresnel_unpolarized, fresnel_unpolarized_dn
from analysis.brdf.geometry import make_geometry
from analysis.brdf.integrate import dhr


@pytest.mark.parametrize(("n", "k"), [(1.5, 0.0), (2.4, 0.0), (1.37, 7.6), (0.2, 3.5)])
def test_lobe_at_normal_mirror_is_normal_incidence_reflectance(n: float, k: float) -> None:
    # θi = θr = 0: h = normal, D = 1/(πα²), G₂ = 1, so f = R(0)/(4πα²) with
    # R(0) = ((n−1)² + k²)/((n+1)² + k²)
    alpha = 0.2
    m = get_model("ggx_conductor")
    r0 = ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)
    f = m.evaluate([n, k, alpha], 0.0, 0.0, 0.0, np.pi)
    assert f == pytest.approx(r0 / (4 * np.pi * alpha**2), rel=1e-12)


def test_brewster_angle_of_the_facet_fresnel_factor() -> None:
    # k = 0: R_p vanishes at tan θB = n, so there R = R_s/2
    n = 1.52
    cb = np.cos(np.arctan(n))
    res = fresnel(cb, n)
    assert res.Rp == pytest.approx(0.0, abs=1e-15)
    assert fresnel_unpolarized(cb, n) == pytest.approx(0.5 * res.Rs, rel=1e-12)
    # and the derivative of R with respect to n is that of R_s/2 there (R_p is at a minimum)
    _, dn, _ = fresnel_unpolarized_dn(cb, n)
    h = 1e-6
    drs = (fresnel(cb, n + h).Rs - fresnel(cb, n - h).Rs) / (2 * h)
    assert dn == pytest.approx(0.5 * drs, rel=1e-6)


@pytest.mark.parametrize("index", [1.5, 2.1 + 0.4j, 0.96 + 6.69j])
def test_fresnel_derivatives_match_finite_differences(index: complex) -> None:
    c = np.linspace(0.02, 1.0, 25)
    _, dn, dk = fresnel_unpolarized_dn(c, index)
    h = 1e-6
    fd_n = (fresnel_unpolarized(c, index + h) - fresnel_unpolarized(c, index - h)) / (2 * h)
    fd_k = (fresnel_unpolarized(c, index + 1j * h)
            - fresnel_unpolarized(c, index - 1j * h)) / (2 * h)
    np.testing.assert_allclose(dn, fd_n, atol=1e-8)
    np.testing.assert_allclose(dk, fd_k, atol=1e-8)


@pytest.mark.parametrize(("name", "params"), [("ggx_fresnel", [1.6, 0.3]),
                                              ("ggx_conductor", [1.2, 2.5, 0.15])])
def test_analytic_jacobian_matches_finite_differences(name: str, params: list) -> None:
    m = get_model(name)
    rng = np.random.default_rng(3)
    ti, tr = rng.uniform(0, 1.3, 40), rng.uniform(0, 1.3, 40)
    pr = rng.uniform(0, 2 * np.pi, 40)
    g = make_geometry(ti, np.zeros(40), tr, pr)
    jac = m.jacobian_geometry(params, g)
    p = np.array(params, dtype=float)
    for j in range(p.size):
        h = 1e-6 * max(abs(p[j]), 1.0)
        up, dn = p.copy(), p.copy()
        up[j] += h
        dn[j] -= h
        fd = (m.evaluate_geometry(up, make_geometry(ti, np.zeros(40), tr, pr))
              - m.evaluate_geometry(dn, make_geometry(ti, np.zeros(40), tr, pr))) / (2 * h)
        np.testing.assert_allclose(jac[:, j], fd, rtol=1e-5, atol=1e-9 * np.abs(fd).max())


@pytest.mark.parametrize(("params", "name"), [([1.5, 0.3], "ggx_fresnel"),
                                              ([0.2, 3.5, 0.3], "ggx_conductor")])
def test_energy_bound_by_the_fresnel_reflectance(params: list, name: str) -> None:
    # single scattering loses energy, so DHR ≤ max over β of R, and R ≤ 1 for any index
    m = get_model(name)
    theta = np.radians([0.0, 40.0, 75.0])
    rho = dhr(m, params, theta, n_mu=64, n_phi=128)
    index = complex(params[0], params[1] if len(params) == 3 else 0.0)
    r_max = fresnel_unpolarized(np.linspace(0, 1, 2001), index).max()
    assert np.all(rho <= r_max + 1e-3)
    assert np.all(rho > 0)


def test_index_is_recovered_from_absolute_values() -> None:
    # an in-plane scan of lambert + ggx_fresnel with 1 % noise: n within 2σ
    m = get_model("lambert+ggx_fresnel")
    truth = np.array([0.3, 1.62, 0.15])
    ti = np.repeat(np.radians([10.0, 30.0, 50.0]), 25)
    tr = np.tile(np.radians(np.linspace(2, 80, 25)), 3)
    pr = np.full(ti.shape, np.pi)
    f = m.evaluate(truth, ti, 0 * ti, tr, pr)
    sigma = 0.01 * f
    rng = np.random.default_rng(11)
    fit = fit_brdf(m, f + sigma * rng.standard_normal(f.shape), ti, 0 * ti, tr, pr,
                   sigma=sigma, n_starts=4, seed=1)
    assert fit.converged
    assert np.all(np.abs(fit.params - truth) < 2 * fit.stderr), (fit.params, fit.stderr)
