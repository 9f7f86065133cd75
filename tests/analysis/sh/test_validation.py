"""Validation on simulated spheres: relighting, tamper detection, Wiener K curve,
inverse rendering.

Images come from :mod:`hw_mocks.sim.sphere_scene`, rendered by direct integration over a
much finer direction grid with the physical horizon of the sphere, never through the SH
convolution the analysis inverts; noise is Gaussian with σ = 1 % of the mean radiance
(the camera's sensor model lives elsewhere).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from analysis.sh.consistency import calibrate, check, known_lighting_residual
from analysis.sh.convolve import wiener_deconvolve
from analysis.sh.filters import phong_filter
from analysis.sh.identities import four_images, known_lighting, render_missing_image
from analysis.sh.inverse import fit_diffuse_phong
from analysis.sh.sphere_image import (
    image_fit_operator,
    image_to_sh,
    images_to_sh,
    sh_to_image,
    sphere_geometry,
)
from analysis.sh.transform import directions_to_angles
from hw_mocks.sim.sphere_scene import (
    LambertianMicrofacet,
    Phong,
    environment_coefficients,
    random_environment,
    render_spheres,
)

NOISE = 0.01


def _noisy(img: np.ndarray, mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return img + NOISE * np.mean(img[mask]) * rng.standard_normal(img.shape)


def _relight_l1(seed: int, size: int = 64, lmax: int = 20) -> tuple[float, float]:
    """L1 error of B^{2,2} rendered from the other three images (BRDF-transfer route)."""
    rng = np.random.default_rng(seed)
    envs = [random_environment(rng), random_environment(rng)]
    mats = [Phong(ks=1.0, s=80.0), Phong(ks=0.7, s=30.0)]
    renders = [render_spheres(envs, m, size=size, n_theta=128) for m in mats]
    r0 = renders[0]
    geo = sphere_geometry((size, size), center=r0.center, radius=r0.radius,
                          max_view_angle_deg=85.0)
    truth = {(i, j): renders[j].radiance[i] for i in range(2) for j in range(2)}
    keys = list(truth)
    op = image_fit_operator(geo, lmax=lmax)  # one fit operator for the four images
    stack = np.stack([_noisy(truth[k], geo.observed, rng) for k in keys])
    coeffs = dict(zip(keys, images_to_sh(stack, op, geo).T, strict=True))
    b22 = render_missing_image(coeffs[0, 0], coeffs[0, 1], coeffs[1, 0], route="brdf")
    pred = sh_to_image(b22, geo)
    m = geo.observed
    l1 = float(np.sum(np.abs(pred[m] - truth[1, 1][m])) / np.sum(np.abs(truth[1, 1][m])))
    m21 = four_images(coeffs[0, 0], coeffs[0, 1], coeffs[1, 0], coeffs[1, 1])
    return l1, float(m21.error[0])


# slow: 4.1 s CPU; the cheaper
# test_sphere_capture.py::test_relighting_the_fourth_image_and_consistency checks the same
# relighting bound (L1 ≤ 0.065) on the emulated capture (made once per session) in the default
# run
@pytest.mark.slow
def test_relighting_from_three_images() -> None:
    l1, e0 = _relight_l1(seed=1)
    assert l1 <= 0.065
    assert e0 < 0.05  # the l = 0 four-image identity holds to the noise level


@pytest.mark.slow
def test_relighting_several_scenes() -> None:
    errs = [_relight_l1(seed)[0] for seed in range(2, 6)]
    assert max(errs) <= 0.065, errs


# --- tamper detection -------------------------------------------------------------------

SIZE_T = 48
LMAX_ID = 12  # orders reported for M10
LMAX_LIGHT = 28  # known lighting: beyond the Phong(s=40) band limit ≈ 19
INTERIOR_DEG = 70.0  # image-domain residual only where the horizon does not clip the lobe


def _splice(img: np.ndarray, other: np.ndarray, center_row: float) -> np.ndarray:
    out = img.copy()
    cut = round(center_row)
    out[:cut] = other[:cut]  # top half of the sphere from another lighting
    return out


def _squash(img: np.ndarray, geo, radius: float, factor: float = 2.0) -> np.ndarray:
    """Squash the brightest highlight vertically by ``factor`` with a smooth local warp."""
    m = np.where(geo.observed, img, -np.inf)
    iy, ix = np.unravel_index(np.argmax(m), m.shape)
    yy, xx = np.mgrid[0 : img.shape[0], 0 : img.shape[1]].astype(float)
    rho = 0.12 * radius
    w = np.exp(-((yy - iy) ** 2 + (xx - ix) ** 2) / (2 * rho**2))
    out = map_coordinates(img, [yy + (factor - 1.0) * (yy - iy) * w, xx], order=1,
                          mode="nearest")
    return np.where(geo.on_sphere, out, img)


def _tamper_counts(n_cal: int = 150, n_test: int = 100, false_alarm: float = 0.02):
    """(false alarms, spliced detected, squashed detected, calibration) over n_test cases.

    Known lighting (M10): per-order errors e_1 … e_12 of the fitted B_lm against L_lm, plus
    the image-domain residual of the known-lighting fit on the interior pixels, calibrated
    on n_cal separate consistent cases.
    """
    env_a = [random_environment(np.random.default_rng(1000 + i)) for i in range(n_cal + n_test)]
    env_b = [random_environment(np.random.default_rng(5000 + i)) for i in range(n_test)]
    rend = render_spheres(env_a + env_b, Phong(ks=1.0, s=40.0), size=SIZE_T, n_theta=96)
    geo = sphere_geometry((SIZE_T, SIZE_T), center=rend.center, radius=rend.radius,
                          max_view_angle_deg=85.0)
    lights = environment_coefficients(env_a, LMAX_LIGHT, n_theta=96)
    op = image_fit_operator(geo, lmax=LMAX_ID)
    inner = geo.on_sphere & (geo.cos_view > np.cos(np.deg2rad(INTERIOR_DEG)))
    th, ph = directions_to_angles(geo.reflected[inner])
    rng = np.random.default_rng(7)
    imgs_a = np.stack([_noisy(x, geo.observed, rng) for x in rend.radiance[: len(env_a)]])
    imgs_b = np.stack([_noisy(x, geo.observed, rng) for x in rend.radiance[len(env_a) :]])

    def components(img: np.ndarray, k: int) -> np.ndarray:
        b = images_to_sh(img[None], op, geo)[:, 0]
        m10 = known_lighting(b, lights[k, : (LMAX_ID + 1) ** 2]).error
        res = known_lighting_residual(img[inner], th, ph, lights[k])
        return np.r_[m10, res.relative_rms]

    cal = calibrate(np.array([components(imgs_a[k], k) for k in range(n_cal)]),
                    false_alarm=false_alarm)
    fa = spliced = squashed = 0
    for i in range(n_test):
        k = n_cal + i
        a = imgs_a[k]
        fa += check(components(a, k), cal).inconsistent
        spliced += check(components(_splice(a, imgs_b[i], rend.center[1]), k),
                         cal).inconsistent
        squashed += check(components(_squash(a, geo, rend.radius), k), cal).inconsistent
    return fa, spliced, squashed, cal


@pytest.mark.slow
def test_tamper_detection_splice_and_squash() -> None:
    fa, spliced, squashed, cal = _tamper_counts()
    # the per-component noise level is the measured one, well above zero
    assert np.all(cal.noise_error > 0)
    assert fa <= 5, fa
    assert spliced >= 95, spliced
    assert squashed >= 95, squashed


# --- Wiener curve ---------------------------------------------------------------------


def _lighting_estimation_case(seed: int, lmax: int = 20, s: float = 20.0):
    rng = np.random.default_rng(seed)
    env = random_environment(rng)
    rend = render_spheres([env], Phong(ks=1.0, s=s), size=64, n_theta=128)
    geo = sphere_geometry((64, 64), center=rend.center, radius=rend.radius,
                          max_view_angle_deg=85.0)
    fit = image_to_sh(_noisy(rend.radiance[0], geo.observed, rng), geo, lmax=lmax)
    truth = environment_coefficients(env, lmax, n_theta=128)
    return fit, truth, phong_filter(lmax, s).values


def test_wiener_chosen_k_is_near_the_minimum_of_the_error_curve() -> None:
    fit, truth, a = _lighting_estimation_case(seed=3)
    sigma = float(np.median(fit.coeff_std))
    ks = np.logspace(-8, 1, 37)
    curve = np.array([np.linalg.norm(wiener_deconvolve(fit.coeffs, a, k=k).coeffs - truth)
                      for k in ks]) / np.linalg.norm(truth)
    chosen = wiener_deconvolve(fit.coeffs, a, noise_sigma=sigma)
    err = np.linalg.norm(chosen.coeffs - truth) / np.linalg.norm(truth)
    assert np.all(np.isfinite(chosen.k[~chosen.unobservable]))
    # The curve has a real minimum (tiny K amplifies noise, large K over-smooths)…
    assert curve[0] > 3 * curve.min() and curve[-1] > 1.5 * curve.min()
    # …the per-band choice does within 10 % as well as the best single K on it…
    assert err <= 1.1 * curve.min()
    # …and the best scalar K lies within the range of per-band K it chose (± a decade).
    k_best = ks[int(np.argmin(curve))]
    k_obs = chosen.k[~chosen.unobservable]
    assert k_obs.min() / 10 <= k_best <= k_obs.max() * 10


# --- inverse rendering ------------------------------------------------------------------


TRUE_PHONG = Phong(kd=0.6, ks=0.35, s=45.0)


def _inverse_rendering_case(seed: int = 11):
    rng = np.random.default_rng(seed)
    env = random_environment(rng)
    size = 64
    rend = render_spheres([env], TRUE_PHONG, size=size, n_theta=128)
    geo = sphere_geometry((size, size), center=rend.center, radius=rend.radius,
                          max_view_angle_deg=INTERIOR_DEG)
    img = _noisy(rend.radiance[0], geo.observed, rng)
    light = environment_coefficients(env, LMAX_LIGHT, n_theta=128)
    use = geo.observed
    return fit_diffuse_phong(img[use], directions_to_angles(geo.normals[use]),
                             directions_to_angles(geo.reflected[use]), light)


def test_inverse_rendering_kd_ks_roughness_within_uncertainty() -> None:
    fit = _inverse_rendering_case()
    assert fit.success
    true = TRUE_PHONG
    for est, std, ref in [(fit.kd, fit.kd_std, true.kd), (fit.ks, fit.ks_std, true.ks),
                          (fit.s, fit.s_std, true.s)]:
        assert abs(est - ref) <= 3.0 * std, (est, std, ref)
        assert std < 0.1 * ref  # and the uncertainty is informative


@pytest.mark.slow
def test_microfacet_roughness_matches_the_torrance_sparrow_filter() -> None:
    """Near normal exitance a Beckmann lobe of slope α filters like exp(−α² l(l+1))
    (Ramamoorthi & Hanrahan 2001, refined), i.e. like Phong with s = 1/(2α²): the Phong
    fit's σ = 1/√(2s)
    recovers α from a Lambertian + microfacet sphere (pixels within 40° of the view)."""
    rng = np.random.default_rng(11)
    env = random_environment(rng)
    light = environment_coefficients(env, LMAX_LIGHT, n_theta=128)
    for alpha in (0.1, 0.2):
        rend = render_spheres([env], LambertianMicrofacet(kd=0.6, ks=0.35, alpha=alpha),
                              size=56, n_theta=96)
        geo = sphere_geometry((56, 56), center=rend.center, radius=rend.radius,
                              max_view_angle_deg=40.0)
        use = geo.observed
        img = _noisy(rend.radiance[0], use, rng)
        fit = fit_diffuse_phong(img[use], directions_to_angles(geo.normals[use]),
                                directions_to_angles(geo.reflected[use]), light)
        assert abs(fit.roughness / alpha - 1) < 0.06, (alpha, fit.roughness)
        assert abs(fit.kd - 0.6) < 0.03 and abs(fit.ks - 0.35) < 0.03
