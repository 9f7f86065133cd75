"""Every model: reciprocity, positivity, finiteness at grazing, analytic Jacobians, limits,
energy bound and the known integrals of the models' papers."""

import numpy as np
import pytest

from analysis.brdf import available_models, get_model
from analysis.brdf.diffuse import (
    chandrasekhar_h,
    hapke,
    hapke_h1981,
    hapke_h2002,
    lommel_seeliger_dhr,
)
from analysis.brdf.geometry import make_geometry
from analysis.brdf.integrate import dhr, flatland_reflectance
from analysis.brdf.lightfield import flatland_brdf
from analysis.brdf.rough_surface import (
    abc_sigma2,
    bennett_porteus_tis,
    psd_abc,
    psd_gaussian,
    rayleigh_rice,
)
from analysis.brdf.specular import cook_torrance

# physical parameters per model (scales at 1 where the model promises DHR ≤ scale)
PARAMS = {
    "lambert": [0.8],
    "oren_nayar": [0.8, 0.3],
    "lommel_seeliger": [0.9],
    "hapke": [0.9],
    "hapke_opposition": [0.9, 0.5, 0.05],
    "phong": [1.0, 30.0],
    "blinn_phong": [1.0, 60.0],
    "ggx": [1.0, 0.25],
    "beckmann": [1.0, 0.25],
    "ggx_vcavity": [1.0, 0.25],
    "beckmann_vcavity": [1.0, 0.25],
    "ggx_fresnel": [2.5, 0.25],  # R(0) = 0.18: above the test's 0.05 floor
    "ggx_conductor": [1.37, 7.6, 0.25],
    "ward": [1.0, 0.2],
    "ward_aniso": [1.0, 0.1, 0.3],
    "beckmann_kirchhoff": [1.0, 0.3],
    "rayleigh_rice_gauss": [2.0, 3.0],
    "rayleigh_rice_abc": [1e-3, 20.0, 3.0],
    "lightfield_separable": [0.3, 0.5, 0.05, 0.0],
}

ALL = available_models()


def test_every_registered_model_has_test_parameters() -> None:
    assert set(ALL) == set(PARAMS)


def _grid(n: int = 13):
    t = np.linspace(0.0, np.pi / 2, n)  # 0° … 90° inclusive
    p = np.linspace(-np.pi, np.pi, 9)
    ti, pi_, tr, pr = np.meshgrid(t, p[:3], t, p, indexing="ij")
    return ti.ravel(), pi_.ravel(), tr.ravel(), pr.ravel()


@pytest.mark.parametrize("name", ALL)
def test_finite_and_positive_on_closed_hemisphere(name: str) -> None:
    m = get_model(name)
    f = m.evaluate(PARAMS[name], *_grid())
    assert np.all(np.isfinite(f)), name
    assert np.all(f >= 0.0), name


@pytest.mark.parametrize("name", ALL)
def test_reciprocity(name: str) -> None:
    m = get_model(name)
    ti, pi_, tr, pr = _grid(9)
    g = make_geometry(ti, pi_, tr, pr)
    a = m.evaluate_geometry(PARAMS[name], g)
    b = m.evaluate_geometry(PARAMS[name], g.swapped())
    # exclude the doubly grazing corner, where values are set by the μ floor
    ok = (g.mu_i > 1e-6) | (g.mu_r > 1e-6)
    if m.reciprocal:
        np.testing.assert_allclose(a[ok], b[ok], rtol=1e-10, atol=1e-300)
    else:
        # documented exception: the flatland window breaks reciprocity unless q = 0
        assert name == "lightfield_separable"
        np.testing.assert_allclose(a[ok], b[ok], rtol=1e-10)
        p = list(PARAMS[name])
        p[3] = 2.0
        a2 = m.evaluate_geometry(p, g)
        b2 = m.evaluate_geometry(p, g.swapped())
        assert np.max(np.abs(a2 - b2)) > 1e-3


@pytest.mark.parametrize("name", [n for n in ALL if get_model(n).has_analytic_jacobian])
def test_analytic_jacobian_matches_finite_differences(name: str) -> None:
    from analysis.brdf.model import numeric_jacobian

    m = get_model(name)
    t = np.radians(np.linspace(0, 80, 9))
    ti, tr, pr = np.meshgrid(t, t, [np.pi, 2.5, 0.4], indexing="ij")
    g = make_geometry(ti.ravel(), 0.1, tr.ravel(), pr.ravel())
    p = np.asarray(PARAMS[name], dtype=float)
    if name == "lightfield_separable":
        p = np.array([0.3, 0.5, 0.2, 1.5])
    ana = m.jacobian_geometry(p, g)
    num = numeric_jacobian(m.value_fn, p, g, rel_step=1e-6)
    scale = np.maximum(np.abs(num).max(axis=0), 1e-12)
    np.testing.assert_allclose(ana / scale, num / scale, atol=2e-6)


def test_oren_nayar_sigma_zero_is_lambertian() -> None:
    on, lam = get_model("oren_nayar"), get_model("lambert")
    ti, pi_, tr, pr = _grid(7)
    np.testing.assert_allclose(on.evaluate([0.7, 0.0], ti, pi_, tr, pr), 0.7 / np.pi, rtol=1e-15)
    np.testing.assert_allclose(lam.evaluate([0.7], ti, pi_, tr, pr), 0.7 / np.pi, rtol=1e-15)


def test_oren_nayar_backscatter_exceeds_forward_at_grazing() -> None:
    on = get_model("oren_nayar")
    back = on.evaluate([0.8, 0.4], 1.3, 0.0, 1.0, 0.0)
    fwd = on.evaluate([0.8, 0.4], 1.3, 0.0, 1.0, np.pi)
    assert back > 1.3 * fwd


def test_anisotropic_ward_with_equal_widths_is_isotropic_ward() -> None:
    ti, pi_, tr, pr = _grid(9)
    iso = get_model("ward").evaluate([0.6, 0.15], ti, pi_, tr, pr)
    aniso = get_model("ward_aniso").evaluate([0.6, 0.15, 0.15], ti, pi_, tr, pr)
    np.testing.assert_allclose(aniso, iso, rtol=1e-12, atol=1e-300)


def test_hapke_tends_to_lommel_seeliger_for_dark_surfaces() -> None:
    # H(x, w) − 1 ≈ (w/2)·x·ln((1+x)/x) ≤ (w/2)·ln 2 (at x = 1), so the product of the two
    # H factors departs from 1 by at most ≈ w·ln 2: Hapke → Lommel–Seeliger as w → 0
    ti, pi_, tr, pr = _grid(9)
    for w in (1e-2, 1e-4):
        ratio = get_model("hapke").evaluate([w], ti, pi_, tr, pr) / get_model(
            "lommel_seeliger").evaluate([w], ti, pi_, tr, pr)
        np.testing.assert_allclose(ratio, 1.0, atol=1.05 * w * np.log(2.0))


@pytest.mark.parametrize("alpha", [0.01, 0.2])
def test_microfacet_variants_agree_at_normal_mirror(alpha: float) -> None:
    # at θi = θr = 0 the half vector is the normal: D_GGX = D_Beckmann = 1/(πα²) and both
    # masking terms are exactly 1, so f = ks/(4πα²) for all four variants (F ≡ 1)
    vals = [get_model(n).evaluate([1.0, alpha], 0.0, 0.0, 0.0, np.pi)
            for n in ("ggx", "beckmann", "ggx_vcavity", "beckmann_vcavity")]
    np.testing.assert_allclose(vals, 1.0 / (4.0 * np.pi * alpha**2), rtol=1e-12)


# ------------------------------------------------------------------------ energy bound
ENERGY_ANGLES = np.radians([0.0, 30.0, 60.0, 80.0, 89.0])


@pytest.mark.parametrize("name", [n for n in ALL if get_model(n).energy_bounded])
def test_energy_bound(name: str) -> None:
    m = get_model(name)
    p = PARAMS[name]
    rho = np.maximum(
        dhr(m, p, ENERGY_ANGLES, n_mu=64, n_phi=128),
        dhr(m, p, ENERGY_ANGLES, method="mirror", lobe_width=0.05, n_per_panel=16, n_chi=64),
    )
    assert np.all(rho <= 1.0 + 2e-3), (name, rho)
    assert np.all(rho > 0.05), (name, rho)


def test_original_oren_nayar_exceeds_one_documented() -> None:
    # independent quadrature: ρ=1, σ=0.3 → DHR 1.004 at 89°; σ=0.5 → 0.78 at 0°
    m = get_model("oren_nayar")
    assert not m.energy_bounded
    assert dhr(m, [1.0, 0.3], np.radians(89.0)) == pytest.approx(1.004, abs=2e-3)
    assert dhr(m, [1.0, 0.5], 0.0) == pytest.approx(0.78, abs=5e-3)


@pytest.mark.parametrize("theta", np.radians([0.0, 45.0, 89.9]))
def test_lambertian_dhr_equals_rho(theta: float) -> None:
    assert dhr(get_model("lambert"), [0.63], theta) == pytest.approx(0.63, rel=1e-12)


@pytest.mark.parametrize("mu0", [1.0, 0.5, 0.1])
def test_lommel_seeliger_dhr_closed_form(mu0: float) -> None:
    w = 0.8
    num = dhr(get_model("lommel_seeliger"), [w], np.arccos(mu0), n_mu=200)
    assert num == pytest.approx(lommel_seeliger_dhr(mu0, w), rel=1e-7)


def test_chandrasekhar_h_and_hapke_dhr_identity() -> None:
    # DHR(μ0) = 1 − √(1−w) H(μ0) for isotropic scattering with exact H (Hapke 2012)
    w, mu0 = 0.9, 0.5
    h_exact = chandrasekhar_h(mu0, w)
    assert 1 - np.sqrt(1 - w) * h_exact == pytest.approx(0.507939, abs=2e-6)
    # the model uses Hapke 2002's H, within 1 %
    num = dhr(hapke(), [w], np.arccos(mu0))
    assert num == pytest.approx(1 - np.sqrt(1 - w) * h_exact, rel=0.015)


def test_h_function_approximation_errors() -> None:
    x = np.linspace(0.0, 1.0, 41)
    for w in (0.3, 0.9, 0.99):
        ex = chandrasekhar_h(x, w)
        assert np.max(np.abs(hapke_h2002(x, w) / ex - 1)) < 0.0097
        assert np.max(np.abs(hapke_h1981(x, w) / ex - 1)) < 0.041  # 4.0 % at w = 0.99


@pytest.mark.parametrize(("alpha", "expect"), [(1.0, 0.31), (0.5, 0.69)])
def test_ggx_single_scatter_loss(alpha: float, expect: float) -> None:
    assert dhr(get_model("ggx"), [1.0, alpha], 0.0) == pytest.approx(expect, abs=0.01)


@pytest.mark.parametrize(
    ("alpha", "theta", "expect"),
    [(0.05, 0.0, 0.998), (0.05, 45.0, 0.996), (0.05, 70.0, 0.988), (0.5, 0.0, 0.7546)],
)
def test_ward_gmd_albedo_table(alpha: float, theta: float, expect: float) -> None:
    got = dhr(get_model("ward"), [1.0, alpha], np.radians(theta), method="mirror",
              lobe_width=alpha / 2)
    assert got == pytest.approx(expect, abs=3e-3)


def test_phong_albedo_at_normal_incidence() -> None:
    for s in (5.0, 50.0, 500.0):
        got = dhr(get_model("phong"), [0.7, s], 0.0, method="mirror",
                  lobe_width=1 / np.sqrt(s))
        assert got == pytest.approx(0.7, rel=1e-6)


def test_fresnel_microfacet_below_unit_albedo() -> None:
    m = cook_torrance(n=1.5)
    r = dhr(m, [1.0, 0.2], np.radians([0.0, 60.0]))
    assert r[0] == pytest.approx(0.04, rel=0.05)
    assert r[1] > r[0]


def test_beckmann_kirchhoff_matches_bare_formula_away_from_grazing() -> None:
    # Beckmann–Kirchhoff form (Beckmann & Spizzichino 1963); shadowing ≈ 1 for small slope
    # and moderate angles
    m = 0.05
    ti, tr, dphi = np.radians(20.0), np.radians(22.0), np.pi - 0.03
    ci, cr, si, sr = np.cos(ti), np.cos(tr), np.sin(ti), np.sin(tr)
    cp = np.cos(dphi)
    bare = (1 + ci * cr + si * sr * cp) ** 2 / (np.pi * m**2 * ci * cr * (ci + cr) ** 4) * np.exp(
        -(si**2 + sr**2 + 2 * si * sr * cp) / (m**2 * (ci + cr) ** 2)
    )
    got = get_model("beckmann_kirchhoff").evaluate([1.0, m], ti, 0.0, tr, dphi)
    assert got == pytest.approx(bare, rel=1e-4)


# ------------------------------------------------------------------- Rayleigh–Rice / PSDs
def test_gaussian_psd_integrates_to_sigma2() -> None:
    f = np.linspace(0, 5, 20001)
    s2 = np.trapezoid(2 * np.pi * f * psd_gaussian(f, 0.002, 3.0), f)
    assert s2 == pytest.approx(0.002**2, rel=1e-6)


def test_abc_sigma2_closed_form() -> None:
    f = np.linspace(0, 50, 200001)
    num = np.trapezoid(2 * np.pi * f * psd_abc(f, 1e-3, 20.0, 3.5), f)
    assert num == pytest.approx(abc_sigma2(1e-3, 20.0, 3.5, f_max=50.0), rel=1e-5)


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0])
def test_rayleigh_rice_tis(theta_deg: float) -> None:
    # Bennett–Porteus TIS, independent quadrature: σ = 2 nm, ℓ = 10 µm, λ = 0.6328 µm,
    # Q = 1: ratio 0.998–0.9998
    m = rayleigh_rice(psd="gaussian", wavelength_um=0.6328, q=1.0)
    ti = np.radians(theta_deg)
    tis = dhr(m, [2.0, 10.0], ti, method="mirror", lobe_width=0.004, n_per_panel=32, n_chi=128)
    assert tis / bennett_porteus_tis(ti, 0.002, 0.6328) == pytest.approx(1.0, abs=4e-3)


def test_rayleigh_rice_loses_evanescent_power_for_short_correlation() -> None:
    m = rayleigh_rice(psd="gaussian")
    tis = dhr(m, [2.0, 0.5], 0.0, n_mu=128, n_phi=128)
    assert tis / bennett_porteus_tis(0.0, 0.002, 0.6328) == pytest.approx(0.91, abs=0.01)


# ---------------------------------------------------------------- flatland separable model
def test_flatland_model_structure_and_energy() -> None:
    m = get_model("lightfield_separable")
    p = [0.3, 0.5, 0.05, 0.0]
    to = np.radians(20.0)
    r = flatland_reflectance(m, p, to)
    # diffuse part integrates to ρd exactly; the Gaussian lobe (well inside the range) to ks·cos
    expect = 0.3 + 0.5 * np.cos(to) * np.exp(-0.5 * 0.05**2)
    assert r == pytest.approx(expect, rel=1e-4)
    assert r <= 1.0
    # shift invariance of the specular part
    a = flatland_brdf(0.1, 0.15, rho_d=0.0, ks=1.0, width=0.05, q=0.0)
    b = flatland_brdf(-0.3, -0.25, rho_d=0.0, ks=1.0, width=0.05, q=0.0)
    assert a == pytest.approx(b, rel=1e-12)


def test_fitted_dhr_with_uncertainty() -> None:
    from analysis.brdf.fit import fit_brdf
    from analysis.brdf.integrate import fitted_dhr

    from .synth import noisy, scan_angles

    angles = scan_angles(15, out_of_plane=False)
    lam = get_model("lambert")
    y, sig, _ = noisy(lam, [0.8], angles, seed=3, rel=0.02)
    fit = fit_brdf(lam, y, *angles, sigma=sig)
    res = fitted_dhr(lam, fit, np.radians([0.0, 60.0]), n_mu=16, n_phi=16)
    np.testing.assert_allclose(res.value, fit.params[0], rtol=1e-12)
    np.testing.assert_allclose(res.stderr, fit.stderr[0], rtol=1e-6)
    assert not np.any(res.exceeds_one)
    # a bright original Oren–Nayar fit is flagged near grazing (documented exception)
    on = get_model("oren_nayar")
    y, sig, _ = noisy(on, [1.0, 0.3], angles, seed=4, rel=0.002)
    fit = fit_brdf(on, y, *angles, sigma=sig)
    res = fitted_dhr(on, fit, np.radians([0.0, 89.0]))
    assert res.value[1] > 1.0 and res.value[0] < 1.0


def test_flatland_model_agrees_with_the_lightfield_package() -> None:
    # one implementation of eq. 2-14: analysis.lightfield's FlatlandBRDF (the scene renderer)
    # evaluates this module's functions; the numbers must stay identical, window included
    from analysis.lightfield import FlatlandBRDF

    rng = np.random.default_rng(11)
    to = rng.uniform(-np.pi / 2, np.pi / 2, 200)
    tm = rng.uniform(-np.pi / 2, np.pi / 2, 200)
    to[:2], tm[:2] = np.pi / 2, -np.pi / 2  # grazing ends of the closed range
    for rho_d, ks, width, q in [(0.3, 0.5, 0.05, 0.0), (0.8, 0.04, 0.1, 2.5)]:
        lf = FlatlandBRDF(ks, width, rho_d, q)
        np.testing.assert_allclose(
            flatland_brdf(to, tm, rho_d=rho_d, ks=ks, width=width, q=q), lf(to, tm),
            rtol=1e-14, atol=1e-300,
        )
