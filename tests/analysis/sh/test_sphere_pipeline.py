"""Sphere-image geometry and the simulated sphere renderer against the theory."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.sh.convolve import convolve
from analysis.sh.filters import lambertian_filter, phong_filter
from analysis.sh.sphere_image import (
    image_to_sh,
    irradiance_image,
    mirror_sphere_lighting,
    sh_to_image,
    sphere_geometry,
    sphere_samples,
)
from hw_mocks.sim.sphere_scene import (
    AreaLight,
    EnvironmentMap,
    EquirectEnvironment,
    Lambertian,
    LambertianMicrofacet,
    Mirror,
    Phong,
    environment_coefficients,
    random_environment,
    render_sphere,
    render_spheres,
)


def test_orthographic_geometry() -> None:
    geo = sphere_geometry((41, 41), center=(20.0, 20.0), radius=15.0, max_view_angle_deg=90)
    assert abs(geo.on_sphere.sum() - np.pi * 15**2) < 2 * np.pi * 15
    np.testing.assert_allclose(geo.normals[20, 20], [0, 0, 1])
    np.testing.assert_allclose(geo.reflected[20, 20], [0, 0, 1])
    on = geo.on_sphere
    n, r, v = geo.normals[on], geo.reflected[on], geo.view[on]
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), 1.0, atol=1e-12)
    # mirror law: R·n = v·n and R, n, v coplanar
    np.testing.assert_allclose(np.sum(r * n, 1), np.sum(v * n, 1), atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", np.cross(n, v), r), 0.0, atol=1e-12)
    assert geo.normals[6, 20, 1] > 0.9  # image up (above the centre) is world +y
    grazing = sphere_geometry((41, 41), center=(20.0, 20.0), radius=15.0,
                              max_view_angle_deg=60)
    assert grazing.observed.sum() < geo.observed.sum()
    assert np.all(grazing.cos_view[grazing.observed] > 0.5)


def test_perspective_geometry_tends_to_orthographic() -> None:
    k = np.array([[1e4, 0, 20.0], [0, 1e4, 20.0], [0, 0, 1]])
    ortho = sphere_geometry((41, 41), center=(20.0, 20.0), radius=15.0)
    persp = sphere_geometry((41, 41), center=(20.0, 20.0), radius=15.0, intrinsics=k)
    # pixels exactly on the rim may fall either way; everything else agrees
    assert np.sum(ortho.on_sphere != persp.on_sphere) <= 8
    on = ortho.on_sphere & persp.on_sphere & (ortho.cos_view > 0.2)
    # the perspective tilt is of order radius/f = 1.5e−3
    np.testing.assert_allclose(persp.normals[on], ortho.normals[on], atol=5e-3)
    # a near camera sees less than a hemisphere: the silhouette normals tilt away
    near = sphere_geometry((41, 41), center=(20.0, 20.0), radius=15.0,
                           intrinsics=np.array([[30.0, 0, 20], [0, 30.0, 20], [0, 0, 1]]))
    assert np.all(near.cos_view[near.on_sphere] > -1e-9)
    assert near.on_sphere.sum() <= ortho.on_sphere.sum()


def test_hdr_input_ignores_invalid_pixels() -> None:
    geo = sphere_geometry((32, 32), center=(15.5, 15.5), radius=14.0)
    img = np.ones((32, 32))
    img[10, 10] = np.nan
    sat = np.ones((32, 32), dtype=bool)
    sat[16:, :] = False
    _, _, vals = sphere_samples(img, geo, valid=sat)
    assert np.all(np.isfinite(vals)) and vals.size < geo.observed.sum() / 2 + 1
    fit = image_to_sh(img, geo, lmax=2, valid=sat)
    assert abs(fit.coeffs[0] - np.sqrt(4 * np.pi)) < 1e-8
    with pytest.raises(ValueError):
        sphere_samples(np.ones((8, 8)), geo)


def _furnace() -> EnvironmentMap:
    return EnvironmentMap(zenith=1.0, horizon=1.0, ground=1.0)


def test_white_furnace() -> None:
    env = _furnace()
    lam = render_sphere(env, Lambertian(albedo=1.0), size=24, n_theta=64)
    on = lam.coverage == 1
    # the horizon kink of the clamped cosine limits the product quadrature to ~1e−4
    np.testing.assert_allclose(lam.radiance[on], 1.0, atol=2e-4)
    ph = render_sphere(env, Phong(ks=1.0, s=30.0, clip_horizon=False), size=24, n_theta=64)
    np.testing.assert_allclose(ph.radiance[on], 1.0, atol=1e-4)
    mf = render_sphere(env, LambertianMicrofacet(kd=0.0, ks=1.0, alpha=0.3), size=24,
                       n_theta=96)
    assert np.all(mf.radiance[on] <= 1.0 + 1e-3)  # single scattering loses energy
    assert mf.radiance[12, 12] > 0.9
    eq = render_sphere(EquirectEnvironment(np.ones((32, 64))), Lambertian(1.0), size=24,
                       n_theta=64)
    np.testing.assert_allclose(eq.radiance[on], 1.0, atol=2e-4)


def test_renderer_agrees_with_the_convolution_theory() -> None:
    """Direct integration (renderer) against B = A_l L_lm (analysis): independent routes."""
    env = random_environment(np.random.default_rng(21), n_sharp=1)
    size, lmax = 48, 48
    lig = environment_coefficients(env, lmax, n_theta=160)
    rend = render_spheres([env], Phong(ks=1.0, s=20.0, clip_horizon=False), size=size,
                          n_theta=128)
    geo = sphere_geometry((size, size), center=rend.center, radius=rend.radius)
    pred = sh_to_image(convolve(lig, phong_filter(lmax, 20.0).values), geo)
    m = rend.coverage == 1
    assert np.max(np.abs(pred[m] - rend.radiance[0][m])) < 5e-3 * np.max(rend.radiance[0])
    lam = render_spheres([env], Lambertian(albedo=0.7), size=size, n_theta=128)
    irr = irradiance_image(lig, geo) * 0.7 / np.pi
    assert np.max(np.abs(irr[m] - lam.radiance[0][m])) < 5e-3 * np.max(lam.radiance[0])


def test_mirror_sphere_gives_the_lighting() -> None:
    env = EnvironmentMap(area_lights=(AreaLight((0.3, 0.5, 0.8), 0.6, 1.0, 0.2),))
    size, lmax = 96, 4
    rend = render_sphere(env, Mirror(reflectance=0.9), size=size, supersample=2)
    geo = sphere_geometry((size, size), center=rend.center, radius=rend.radius,
                          max_view_angle_deg=85)
    est = mirror_sphere_lighting(rend.radiance, geo, lmax=lmax, reflectance=0.9)
    truth = environment_coefficients(env, lmax)
    assert np.linalg.norm(est.coeffs - truth) < 0.03 * np.linalg.norm(truth)
    with pytest.raises(ValueError):
        mirror_sphere_lighting(rend.radiance, geo, lmax=2, reflectance=0.0)
    assert lambertian_filter(2).values[0] == pytest.approx(np.pi)


def test_m12_on_a_rendered_diffuse_plus_specular_sphere() -> None:
    """M12 recovers K_s·A_l of the specular lobe with K_d unknown, D_lm from the lighting."""
    from analysis.sh.identities import diffuse_plus_specular
    from analysis.sh.sphere_image import image_fit_operator, images_to_sh

    env = random_environment(np.random.default_rng(31))
    size, lmax, s, ks = 48, 24, 40.0, 0.5
    rend = render_spheres([env], Phong(kd=0.5, ks=ks, s=s, clip_horizon=False), size=size,
                          n_theta=128)
    geo = sphere_geometry((size, size), center=rend.center, radius=rend.radius,
                          max_view_angle_deg=85.0)
    lig = environment_coefficients(env, 30, n_theta=96)
    op = image_fit_operator(geo, lmax=lmax)
    d_img = irradiance_image(lig, geo)  # E(n) per pixel, fitted in the reflected domain
    b, d = images_to_sh(np.stack([rend.radiance[0], d_img]), op, geo).T
    res = diffuse_plus_specular(b, lig[: (lmax + 1) ** 2], d)
    a = phong_filter(lmax, s).values
    np.testing.assert_allclose(res.estimate[:10], ks * a[1:11], rtol=0.03)
    assert np.all(res.error[:10] < 0.03)


def test_environment_helpers() -> None:
    a = random_environment(np.random.default_rng(3))
    b = random_environment(np.random.default_rng(3))
    assert a == b  # seeded, reproducible scenes
    d = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    sky = EnvironmentMap(zenith=1.0, horizon=0.5, ground=0.2, up=(0.0, 1.0, 0.0))
    np.testing.assert_allclose(sky.radiance(d), [1.0, 0.2])
    # equirectangular lookup: row 0 is the +y pole, column 0 starts at +z towards +x
    img = np.zeros((8, 16))
    img[:, 4] = 1.0  # azimuth ≈ 90°–112°: the +x side
    eq = EquirectEnvironment(img)
    x_dir = np.array([[np.sin(np.deg2rad(101.25)), 0.0, np.cos(np.deg2rad(101.25))]])
    assert eq.radiance(x_dir)[0] == pytest.approx(1.0)
    assert eq.radiance(np.array([[0.0, 0.0, -1.0]]))[0] == 0.0
    sd, sw, sv = a.sharp_samples()
    caps = [2 * np.pi * (1 - np.cos(s.angular_radius)) for s in a.sharp_sources]
    assert sw.sum() == pytest.approx(sum(caps))
    assert np.all(sv > 0) and np.allclose(np.linalg.norm(sd, axis=1), 1.0)


def test_hdr_variance_weights_the_fit() -> None:
    rng = np.random.default_rng(41)
    geo = sphere_geometry((40, 40), center=(19.5, 19.5), radius=18.0)
    c = np.zeros(9)
    c[0], c[3], c[8] = 1.0, 0.3, -0.2
    clean = sh_to_image(c, geo)
    # HDR: the top half of the sphere is 100× noisier (short exposure only)
    sigma = np.where(np.arange(40)[:, None] < 20, 0.1, 0.001) * np.ones((40, 40))
    noisy = clean + sigma * rng.standard_normal(clean.shape)
    plain = image_to_sh(noisy, geo, lmax=2).coeffs
    weighted = image_to_sh(noisy, geo, lmax=2, variance=sigma**2).coeffs
    assert np.linalg.norm(weighted - c) < 0.5 * np.linalg.norm(plain - c)
