"""The virtual bench with Stokes vectors: Mueller algebra, the pBRDF, the hidden train."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hw_mocks.sim.goniometer_scene import GoniometerScene, lambertian_brdf
from hw_mocks.sim.polarimetric_scene import PolarimetricScene
from hw_mocks.sim.polarisation import (
    HiddenElement,
    HiddenTrain,
    jones_to_mueller,
    polariser_mueller,
    retarder_mueller,
)
from hw_mocks.sim.polarised_sample import MicrofacetPolarisedSample, reference_mueller
from hw_mocks.sim.world import PowerMeterHead, VirtualBench

HEAD = PowerMeterHead(distance_mm=300.0, aperture_diameter_mm=9.5)
UP = np.array([0.0, -1.0, 0.0])  # the lab +y in the sample frame at sample_phi = 0
MOUNTS = ("psg_polariser", "psg_retarder", "psa_retarder", "psa_polariser")


def goldstein_retarder(theta, delta):
    """Goldstein, Polarized Light, 3rd ed., the rotated linear retarder (written out)."""
    c, s = math.cos(2 * theta), math.sin(2 * theta)
    cd, sd = math.cos(delta), math.sin(delta)
    return np.array([[1, 0, 0, 0],
                     [0, c * c + s * s * cd, c * s * (1 - cd), -s * sd],
                     [0, c * s * (1 - cd), s * s + c * c * cd, c * sd],
                     [0, s * sd, -c * sd, cd]])


@pytest.mark.parametrize(("theta", "delta"), [(0.0, math.pi / 2), (0.3, 1.1), (-1.2, 2.9)])
def test_the_retarder_from_its_jones_matrix_is_the_textbook_one(theta, delta):
    np.testing.assert_allclose(retarder_mueller(theta, delta), goldstein_retarder(theta, delta),
                               atol=1e-12)


def test_malus_law_and_a_quarter_wave_plate_makes_circular_light():
    horizontal = np.array([1.0, 1.0, 0.0, 0.0])
    for deg in (0.0, 30.0, 45.0, 90.0):
        out = polariser_mueller(math.radians(deg)) @ horizontal
        assert out[0] == pytest.approx(math.cos(math.radians(deg)) ** 2, abs=1e-12)
    circular = retarder_mueller(math.radians(45.0), math.pi / 2) @ horizontal
    np.testing.assert_allclose(circular, [1.0, 0.0, 0.0, 1.0], atol=1e-12)
    # the Mueller matrix of a product of Jones matrices is the product of theirs
    j1 = np.array([[1.0, 0.2j], [0.3, 0.5 - 0.1j]])
    j2 = np.array([[0.7, -0.4], [0.1j, 1.0]])
    np.testing.assert_allclose(jones_to_mueller(j1 @ j2),
                               jones_to_mueller(j1) @ jones_to_mueller(j2), atol=1e-12)


def specular(theta_deg):
    t = math.radians(theta_deg)
    return (np.array([math.sin(t), 0.0, math.cos(t)]),
            np.array([-math.sin(t), 0.0, math.cos(t)]))


def fresnel_unpolarised(cos_b, n):
    """(Rs + Rp)/2 and (Rs − Rp)/2 of a dielectric, from Snell's law (Hecht §4.6.2)."""
    sin_t = math.sqrt(1 - cos_b**2) / n
    cos_t = math.sqrt(1 - sin_t**2)
    rs = ((cos_b - n * cos_t) / (cos_b + n * cos_t)) ** 2
    rp = ((n * cos_b - cos_t) / (n * cos_b + cos_t)) ** 2
    return 0.5 * (rs + rp), 0.5 * (rs - rp)


@pytest.mark.parametrize("theta", [20.0, 50.0, 70.0])
def test_the_facet_term_in_the_specular_direction(theta):
    sample = MicrofacetPolarisedSample(n=1.5, slope_rms=0.2)
    wi, wr = specular(theta)
    m = sample.mueller(wi, wr, UP)
    mu = math.cos(math.radians(theta))
    # the half vector is the normal: D = 1/(π m²); Smith G₁ from its definition
    a = 1.0 / (0.2 * math.tan(math.radians(theta)))
    lam = 0.5 * (math.exp(-a * a) / (a * math.sqrt(math.pi)) - math.erfc(a))
    geometry = (1.0 / (math.pi * 0.04)) / (1 + lam) ** 2 / (4 * mu * mu)
    mean, half_diff = fresnel_unpolarised(mu, 1.5)
    assert m[0, 0] == pytest.approx(geometry * mean, rel=1e-9)
    # h is p (in the plane of incidence): S1 = Ip − Is, so m01 = (Rp − Rs)/2
    assert m[0, 1] == pytest.approx(-geometry * half_diff, rel=1e-9)
    assert abs(m[0, 2]) < 1e-12 * m[0, 0] and abs(m[2, 0]) < 1e-12 * m[0, 0]


def test_brewster_angle_shows_in_m01():
    sample = MicrofacetPolarisedSample(n=1.5, slope_rms=0.1)
    brewster = math.degrees(math.atan(1.5))
    ratios = {}
    for theta in (brewster - 10, brewster, brewster + 10):
        m = sample.mueller(*specular(theta), UP)
        ratios[theta] = m[0, 1] / m[0, 0]
    assert ratios[brewster] == pytest.approx(-1.0, abs=1e-9)
    assert ratios[brewster - 10] > -0.95 and ratios[brewster + 10] > -0.95
    # a mirror near normal incidence: diag(1, 1, −1, −1) in the beams' bases
    m = sample.mueller(*specular(0.5), UP)
    np.testing.assert_allclose(m / m[0, 0], np.diag([1.0, 1.0, -1.0, -1.0]), atol=1e-3)


def test_a_metal_retards_and_a_dielectric_does_not():
    wi, wr = specular(60.0)
    glass = MicrofacetPolarisedSample(n=1.5).mueller(wi, wr, UP)
    gold = MicrofacetPolarisedSample(n=0.18, k=3.4).mueller(wi, wr, UP)
    assert abs(glass[2, 3]) < 1e-12 * glass[0, 0]
    assert abs(gold[2, 3]) > 0.1 * gold[0, 0]
    # non-depolarising: the facet term is a pure Mueller matrix (Gil–Bernabeu: tr MᵀM = 4 m00²)
    for m in (glass, gold):
        assert np.trace(m.T @ m) == pytest.approx(4 * m[0, 0] ** 2, rel=1e-9)


def test_the_diffuse_layer_depolarises():
    sample = MicrofacetPolarisedSample(albedo=0.4, specular=0.0)
    wi, _ = specular(30.0)
    wr = np.array([[0.3, 0.2, math.sqrt(1 - 0.13)], [-0.5, 0.0, math.sqrt(0.75)]])
    m = sample.mueller(wi, wr, UP)
    np.testing.assert_allclose(m, np.broadcast_to(np.diag([0.4 / math.pi, 0, 0, 0]), m.shape),
                               atol=1e-15)
    with pytest.raises(ValueError, match="depolarisation_keep"):
        MicrofacetPolarisedSample(depolarisation_keep=0.5)


def world(scene, mounts, *, optics=True, sample_theta=0.0, detector_theta=180.0, extinction=0.0,
          laser=(1.0, 1.0, 0.0, 0.0)):
    roles = {"sample_theta": sample_theta, "detector_theta": detector_theta,
             **dict(zip(MOUNTS, mounts, strict=True))}
    train = HiddenTrain(
        source_stokes=laser,
        source=(HiddenElement("polariser", "psg_polariser", extinction=extinction),
                HiddenElement("retarder", "psg_retarder", retardance_deg=(90.0,))),
        detector=(HiddenElement("retarder", "psa_retarder", retardance_deg=(90.0,)),
                  HiddenElement("polariser", "psa_polariser", extinction=extinction)),
    ) if optics else None
    bench = VirtualBench("pol", roles=roles, scene=scene, power_meter=HEAD, optics=train)
    bench.update_source(on=True, power_w=1e-3)
    return bench


def air(kind="air", **cfg):
    return PolarimetricScene(sample=None, reference=reference_mueller(kind, cfg))


def test_straight_through_follows_malus_and_the_references():
    open_power = world(air(), (0, 0, 0, 0)).optical_power_w()
    # the whole beam on the head (its clipped-grid quadrature of the beam: within 1 %)
    assert open_power == pytest.approx(1e-3, rel=0.015)
    for deg in (30.0, 45.0, 90.0):
        crossed = world(air(), (0, 0, 0, deg)).optical_power_w()
        assert crossed / open_power == pytest.approx(math.cos(math.radians(deg)) ** 2,
                                                     abs=1e-12)
    # a polariser at 30° between parallel polarisers: cos⁴ 30°
    p30 = world(air("polariser", orientation_deg=30.0), (0, 0, 0, 0)).optical_power_w()
    assert p30 / open_power == pytest.approx(math.cos(math.radians(30)) ** 4, rel=1e-9)
    # a quarter-wave plate at 45° between crossed polarisers passes half
    qwp = world(air("retarder", orientation_deg=45.0), (0, 0, 0, 90)).optical_power_w()
    assert qwp / open_power == pytest.approx(0.5, rel=1e-9)


def open_power_of(bench):
    """The reading with the analyser turned back parallel (the same quadrature)."""
    angle = bench.position("psa_polariser")
    bench.set_role("psa_polariser", 0.0)
    power = bench.optical_power_w()
    bench.set_role("psa_polariser", angle)
    return power


def test_turning_a_mount_changes_the_reading_and_the_cache_key():
    bench = world(air(), (0, 0, 0, 0))
    key = bench.snapshot().key
    bench.set_role("psa_polariser", 60.0)
    assert bench.snapshot().key != key
    assert bench.optical_power_w() / open_power_of(bench) == pytest.approx(0.25, rel=1e-9)


def test_without_optics_the_scene_renders_the_unpolarised_brdf():
    rho = 0.4
    diffuse = PolarimetricScene(sample=MicrofacetPolarisedSample(albedo=rho, specular=0.0))
    scalar = GoniometerScene(brdf=lambertian_brdf(rho))
    roles = {"sample_theta": 20.0, "detector_theta": 60.0}
    pol = VirtualBench("a", roles=roles, scene=diffuse, power_meter=HEAD)
    ref = VirtualBench("b", roles=roles, scene=scalar, power_meter=HEAD)
    for bench in (pol, ref):
        bench.update_source(on=True)
    assert pol.snapshot().optics is None
    assert pol.optical_power_w() == pytest.approx(ref.optical_power_w(), rel=1e-12)
    # a depolariser behind the train: the reading is g0 · a0 of the unpolarised one
    lit = world(diffuse, (0, 10, 20, 90), sample_theta=20.0, detector_theta=60.0)
    state = lit.snapshot().optics
    assert lit.optical_power_w() == pytest.approx(
        ref.optical_power_w() * state.generator[0] * state.analyser[0], rel=1e-12)


def test_the_specular_reading_follows_the_sample_mueller_matrix():
    sample = MicrofacetPolarisedSample(n=1.5, slope_rms=0.3)
    scene = PolarimetricScene(sample=sample)
    theta = 50.0
    readings = {}
    # source polariser at 0° (p) or 90° (s), analyser open to the same: Rp against Rs
    for name, angle in (("p", 0.0), ("s", 90.0)):
        # an unpolarised laser; a retarder along the polariser does nothing
        bench = world(scene, (angle, angle, angle, angle), sample_theta=theta,
                      detector_theta=2 * theta, laser=(1.0, 0.0, 0.0, 0.0))
        readings[name] = bench.optical_power_w()
    _, half_diff = fresnel_unpolarised(math.cos(math.radians(theta)), 1.5)
    mean, _ = fresnel_unpolarised(math.cos(math.radians(theta)), 1.5)
    rs, rp = mean + half_diff, mean - half_diff
    # the aperture averages the lobe over facets a little off the specular one
    assert readings["p"] / readings["s"] == pytest.approx(rp / rs, rel=0.05)


def test_the_hidden_train_from_its_table():
    train = HiddenTrain.from_config({
        "source_stokes": [2.0, 2.0, 0.0, 0.0],
        "source": [{"kind": "retarder", "mount": "psg_retarder", "retardance_deg": [92.0, 88.0],
                    "retardance_nm": [500.0, 700.0]}],
    })
    assert train.source_stokes == (1.0, 1.0, 0.0, 0.0)
    m = train.source[0].mueller(0.0, 600.0)
    assert m[3, 3] == pytest.approx(math.cos(math.radians(90.0)), abs=1e-12)
    with pytest.raises(ValueError, match="retardance_deg is required"):
        HiddenTrain.from_config({"detector": [{"kind": "retarder", "mount": "x"}]})
    with pytest.raises(ValueError, match="source_stokes"):
        HiddenTrain.from_config({"source_stokes": [1.0, 1.0, 1.0, 0.0]})


def test_the_scene_from_its_table():
    scene = PolarimetricScene.from_config({"kind": "polarimetric", "sample": "polariser",
                                           "polariser": {"orientation_deg": 30.0}})
    assert scene.sample is None
    np.testing.assert_allclose(scene.reference, polariser_mueller(math.radians(30.0)))
    glass = PolarimetricScene.from_config({"kind": "polarimetric",
                                           "pbrdf": {"n": 1.5, "albedo": 0.2},
                                           "aperture_samples": 6})
    assert glass.sample == MicrofacetPolarisedSample(n=1.5, albedo=0.2)
    assert glass.base.aperture_samples == 6
    with pytest.raises(ValueError, match="tables \\['pbrdf'\\]"):
        PolarimetricScene.from_config({"sample": "air", "pbrdf": {"n": 1.5}})
    with pytest.raises(ValueError, match="ambient light"):
        PolarimetricScene.from_config({"ambient_radiance": 1.0})
    with pytest.raises(ValueError, match="reference sample must be one of"):
        PolarimetricScene.from_config({"sample": "mirror"})
    with pytest.raises(ValueError, match="unknown keys"):
        PolarimetricScene.from_config({"pbrdf": {"roughness": 0.1}})
