"""The virtual bench: positions from the emulators, kinematics, source, power at the head."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.thorlabs_apt import AptMotor
from hw_mocks import registry
from hw_mocks.sim.goniometer_scene import (
    GoniometerScene,
    aperture_rule,
    brdf_from_model,
    lambertian_brdf,
)
from hw_mocks.sim.source import SimulatedSource
from hw_mocks.sim.source import open_from_url as open_source
from hw_mocks.sim.world import (
    PowerMeterHead,
    VirtualBench,
    configure_world,
    get_world,
    reset_worlds,
)

HEAD = PowerMeterHead(distance_mm=300.0, aperture_diameter_mm=9.5)
OMEGA = math.pi * (4.75e-3) ** 2 / 0.3**2  # head solid angle, sr


@pytest.fixture(autouse=True)
def _fresh_worlds():
    reset_worlds()
    yield
    reset_worlds()


def bench(theta_s=0.0, theta_d=30.0, **kw) -> VirtualBench:
    world = VirtualBench("t", roles={"sample_theta": theta_s, "detector_theta": theta_d},
                         power_meter=HEAD, **kw)
    world.update_source(on=True, power_w=1e-3)
    return world


@pytest.mark.parametrize(
    "positions",
    [{"sample_theta": 20.0, "detector_theta": 40.0},
     {"sample_theta": 35.0, "detector_theta": -50.0},
     {"sample_theta": -10.0, "detector_theta": 120.0, "sample_tilt": 15.0},
     {"sample_theta": 25.0, "detector_theta": 70.0, "sample_tilt": -20.0, "sample_phi": 30.0}],
)
def test_world_angles_agree_with_instrument_kinematics(positions):
    """The world and the instrument's kinematics must describe the same bench."""
    from instrument.bench.kinematics import OutOfPlaneKinematics

    angles = OutOfPlaneKinematics(source_theta_deg=0.0).angles(
        {"sample_theta": 0.0, "detector_theta": 0.0, "sample_tilt": 0.0, "sample_phi": 0.0,
         **positions})
    pose = VirtualBench("k", roles=positions).pose()
    ti, pi = (float(np.degrees(a)) for a in pose.local_angles(pose.source_dir))
    tr, pr = (float(np.degrees(a)) for a in pose.local_angles(pose.detector_dir))
    assert ti == pytest.approx(angles.theta_i, abs=1e-9)
    assert tr == pytest.approx(angles.theta_r, abs=1e-9)
    for mine, theirs, theta in ((pi, angles.phi_i, ti), (pr, angles.phi_r, tr)):
        if theta > 1e-6:
            assert math.cos(math.radians(mine - theirs)) == pytest.approx(1.0, abs=1e-9)


def test_kinematics_theta_two_theta_is_specular():
    world = bench(20.0, 40.0)
    pose = world.pose()
    assert pose.incidence_deg == pytest.approx(20.0)
    assert pose.scatter_deg == pytest.approx(20.0)
    _ti, pi = pose.local_angles(pose.source_dir)
    _tr, pr = pose.local_angles(pose.detector_dir)
    # analysis.brdf convention: the specular direction is φr = φi + π.
    assert math.cos(pr - pi) == pytest.approx(-1.0)
    world.set_role("sample_tilt", 10.0)
    _tr, pr = world.pose().local_angles(world.pose().detector_dir)
    assert abs(math.sin(pr)) > 0.05  # out of the plane of incidence now


@pytest.mark.parametrize("theta_d", [10.0, 30.0, 60.0])
def test_power_on_head_lambertian(theta_d):
    """f = ρ/π: P = ρ/π · P_i · cos θr · Ω (Nicodemus et al. 1977), within 0.5 %."""
    world = bench(0.0, theta_d)
    expected = 0.5 / math.pi * 1e-3 * math.cos(math.radians(theta_d)) * OMEGA
    assert world.optical_power_w(633.0) == pytest.approx(expected, rel=5e-3)


def test_power_follows_source_and_reference_swap():
    world = bench(30.0, 75.0)
    p_sample = world.optical_power_w(633.0)
    world.update_source(power_w=2e-3)
    assert world.optical_power_w(633.0) == pytest.approx(2 * p_sample, rel=1e-9)
    world.scene = GoniometerScene(target="reference")
    p_ref = world.optical_power_w(633.0)
    assert p_ref / (2 * p_sample) == pytest.approx(0.99 / 0.5, rel=1e-6)
    world.update_source(on=False)
    assert world.optical_power_w(633.0) == 0.0


def test_direct_beam_reaches_head_without_sample():
    world = bench(0.0, 180.0)
    world.scene = GoniometerScene(target="none")
    # The head (9.5 mm) takes the whole 2 mm Gaussian beam: 1 − exp(−2 a²/w²) ≈ 1.
    assert world.optical_power_w(633.0) == pytest.approx(1e-3, rel=0.02)
    world.scene = GoniometerScene(target="sample")
    assert world.optical_power_w(633.0) == 0.0  # the sample blocks it


def test_ggx_specular_peak_and_signature_and_ambient():
    brdf = brdf_from_model("lambert+ggx", {"lambert.rho": 0.2, "ggx.ks": 0.5,
                                           "ggx.alpha": 0.2})
    world = bench(30.0, 60.0, scene=GoniometerScene(brdf=brdf))
    spec = world.optical_power_w(633.0)
    expected = float(brdf(math.radians(30), math.pi, math.radians(30), 0.0)) * 1e-3 * \
        math.cos(math.radians(30)) * OMEGA
    assert spec == pytest.approx(expected, rel=0.02)
    world.set_role("detector_theta", 100.0)
    assert world.optical_power_w(633.0) < 0.2 * spec  # off-specular
    world.scene = GoniometerScene(target="none", signature_sr=1e-4, signature_width_deg=5.0,
                                  ambient_radiance=0.01)
    world.set_role("detector_theta", 175.0)  # 5° from the forward beam
    sig = 1e-4 / 2.0 * 1e-3 * OMEGA
    amb = math.pi * 0.01 * math.pi * (4.75e-3) ** 2
    assert world.optical_power_w(633.0) == pytest.approx(sig + amb, rel=1e-6)


def test_positions_come_from_the_emulators_moved_by_the_real_driver():
    url = "simapt://sample_theta?model=K10CR1&speed=200"
    world = VirtualBench("t", roles={"sample_theta": url, "detector_theta": 50.0,
                                     "source_theta": {"value": 0.0}},
                         power_meter=HEAD)
    first = world.position("sample_theta")  # creates the emulator through its URL handler
    stage = registry.get("simapt", "sample_theta").stage
    assert first == pytest.approx(stage.physical_position())
    with AptMotor(url, name="sample_theta", rts_settle_s=0.0, flush_s=0.0) as axis:
        axis.enable()
        axis.home(timeout=30.0)
        axis.move_to(25.0, wait=True, timeout=30.0)
        assert world.position("sample_theta") == pytest.approx(25.0, abs=0.01)
        assert world.pose().incidence_deg == pytest.approx(25.0, abs=0.01)
        assert world.pose().scatter_deg == pytest.approx(25.0, abs=0.01)


def test_role_offset_and_scale():
    url = "simapt://tilt?model=K10CR1"
    world = VirtualBench("t", roles={"sample_tilt": {"url": url, "scale": -1.0,
                                                     "offset": 0.5}})
    world.position("sample_tilt")
    registry.get("simapt", "tilt").stage.teleport(2.0)
    assert world.position("sample_tilt") == pytest.approx(-1.5)
    with pytest.raises(ValueError):
        VirtualBench("t", roles={"sample_tilt": {"url": url, "gain": 2}})
    with pytest.raises(KeyError):
        VirtualBench("t", roles={"camera_z": "nosuch://x"}).position("camera_z")


def test_world_registry_and_config():
    assert get_world() is get_world("sim")
    cfg = {
        "roles": {"sample_theta": 10.0, "detector_theta": 20.0},
        "scene": {"brdf": "lambert", "params": [0.8], "ambient_radiance": 0.0},
        "source": {"power_w": 2e-3, "wavelength_nm": 532.0},
        "arm_length_mm": 250.0,
        "power_meter": {"distance_mm": 250.0, "aperture_diameter_mm": 9.5},
    }
    world = configure_world("sim", cfg)
    assert get_world("sim") is world
    assert world.source.wavelength_nm == 532.0
    world.update_source(on=True)
    omega = math.pi * (4.75e-3) ** 2 / 0.25**2
    expected = 0.8 / math.pi * 2e-3 * math.cos(math.radians(10.0)) * omega
    assert world.optical_power_w(532.0) == pytest.approx(expected, rel=5e-3)
    # Reconfiguring keeps the object that devices already hold.
    again = configure_world("sim", {**cfg, "scene": {"brdf": "lambert", "params": [0.4]}})
    assert again is world
    assert not world.source.on  # the configured source state (off) applies again
    world.update_source(on=True)
    assert world.optical_power_w(532.0) == pytest.approx(expected * 0.4 / 0.8, rel=5e-3)
    with pytest.raises(ValueError):
        configure_world("sim", {"rolls": {}})
    with pytest.raises(ValueError):
        world.update_source(power_w=1.0)  # beyond max_power_w


def test_power_meter_emulator_reads_the_world():
    from hw_mocks import usb

    world = configure_world("sim", {
        "roles": {"detector_theta": 30.0},
        "power_meter": {"url": "simusb://power_meter?seed=1"},
    })
    world.update_source(on=True, power_w=1e-3)
    firmware = usb.get_firmware("power_meter")
    expected = 0.5 / math.pi * 1e-3 * math.cos(math.radians(30.0)) * OMEGA
    assert firmware.true_power_w() == pytest.approx(expected, rel=5e-3)
    assert firmware._light_wavelength() == 633.0
    # A source opened later with another wavelength re-tunes the light the head sees.
    open_source("simsource://laser?world=sim&wavelength_nm=532").close()
    assert firmware._light_wavelength() == 532.0


def test_simulated_source_drives_the_world():
    world = get_world("sim")
    src = open_source("simsource://laser?world=sim&power_w=0.002&wavelength_nm=532")
    assert isinstance(src, SimulatedSource)
    assert world.source.power_w == 0.002 and src.wavelength_nm == 532.0
    assert not src.is_on
    src.turn_on()
    assert world.source.on and src.is_on
    src.power_w = 0.003
    assert world.source.power_w == 0.003
    with pytest.raises(ValueError):
        src.power_w = 1.0
    src.close()
    assert not world.source.on  # closing leaves the light off
    src.turn_off()  # a no-op on a closed device
    with pytest.raises(ValueError):
        open_source("simsource://laser?colour=red")
    with pytest.raises(ValueError, match="power_w='bright'"):
        open_source("simsource://laser?power_w=bright")


def test_scene_validation():
    with pytest.raises(ValueError):
        GoniometerScene(target="mirror")
    with pytest.raises(ValueError):
        lambertian_brdf(1.5)
    with pytest.raises(ValueError):
        brdf_from_model("lambert", {"rho": 0.5, "sigma": 1.0})
    assert np.allclose(brdf_from_model("lambert", [0.3])(0.1, 0.0, 0.2, 1.0), 0.3 / math.pi)


@pytest.mark.parametrize("m", [3, 9, 27])
def test_aperture_rule_is_exact_for_polynomials_up_to_its_degree(m):
    """The mean of x^a y^b over the unit disk, a + b ≤ 4⌈m/3⌉ − 1, is
    2 Γ((a+1)/2) Γ((b+1)/2) / (π (a+b+2) Γ((a+b+2)/2)) for even a, b and 0 otherwise."""
    nodes, weights = aperture_rule(m)
    degree = 4 * math.ceil(m / 3) - 1
    assert weights.sum() == pytest.approx(1.0, abs=1e-14)
    assert np.all(weights > 0) and np.all(np.hypot(*nodes.T) < 1.0)
    for a in range(degree + 1):
        for b in range(degree + 1 - a):
            exact = 0.0 if a % 2 or b % 2 else (
                2.0 * math.gamma((a + 1) / 2) * math.gamma((b + 1) / 2)
                / (math.pi * (a + b + 2) * math.gamma((a + b + 2) / 2)))
            got = float(weights @ (nodes[:, 0] ** a * nodes[:, 1] ** b))
            assert got == pytest.approx(exact, abs=1e-14), (a, b)


@pytest.mark.parametrize(("theta_s", "theta_d"), [(20.0, 40.0), (50.0, 100.0), (50.0, 120.0)])
def test_aperture_integral_is_converged_far_below_the_lock_ins_noise(theta_s, theta_d):
    """A GGX α = 0.2 lobe on a 5 mm photodiode at 300 mm (the sim-spectral bench): the
    default rule (36 nodes) agrees with a 1,600-node rule to < 1e-9 of the power, where
    the lock-in's relative noise over four snapshots is 5e-5 (BENCHMARKS.md)."""
    brdf = brdf_from_model("lambert+ggx", {"lambert.rho": 0.3, "ggx.ks": 0.5,
                                           "ggx.alpha": 0.2})
    world = VirtualBench("t", roles={"sample_theta": theta_s, "detector_theta": theta_d},
                         power_meter=PowerMeterHead(distance_mm=300.0,
                                                    aperture_diameter_mm=5.0))
    world.update_source(on=True, power_w=1e-3)
    powers = []
    for m in (9, 60):
        world.scene = GoniometerScene(brdf=brdf, aperture_samples=m)
        powers.append(world.optical_power_w(633.0))
    assert powers[0] == pytest.approx(powers[1], rel=1e-9)
