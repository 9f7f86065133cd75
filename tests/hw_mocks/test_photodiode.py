"""The chopped photodiode binding: the emulated SR830 reads the virtual bench's light.

Checks the conversion (rms fundamental of a 50 % chopped signal, DC of the rest), the
split of source-borne and ambient light at the detector, and, end to end through the real
driver over ``simsr830://…?world=sim``, that the lock-in reads the chopped scattered light
and rejects the ambient light.
"""

from __future__ import annotations

import math

import pytest

from drivers.errors import ConnectionFailed
from drivers.stanford_sr830 import Sr830LockIn
from hw_mocks import registry
from hw_mocks.sim.photodiode import (
    ELEMENTARY_CHARGE_C,
    ChoppedPhotodiode,
    LockInBinding,
    split_power_w,
)
from hw_mocks.sim.world import configure_world

CHOPPER_HZ = 137.0
#: Ambient radiance (W m^-2 sr^-1) giving ~10x the scattered power on the detector.
AMBIENT = 5e-3


def world_config(ambient: float = 0.0, detector_deg: float = 30.0) -> dict:
    return {
        "roles": {"detector_theta": detector_deg},
        "scene": {"brdf": "lambert", "params": [0.5], "ambient_radiance": ambient},
        "source": {"power_w": 1e-3, "wavelength_nm": 633.0},
    }


def test_chopped_signal_is_the_rms_fundamental_and_the_rest_is_dc():
    diode = ChoppedPhotodiode(responsivity_a_per_w=0.5, transimpedance_v_per_a=1e5)
    signal = diode.signal(2e-6, 1e-6, chopper_hz=CHOPPER_HZ)
    peak_to_peak = 0.5 * 1e5 * 2e-6  # 0.1 V
    # a 0..V square wave: fundamental 2V/pi peak, V*sqrt(2)/pi rms (manual p. 3-3 scaled)
    assert signal.ac_rms_v == pytest.approx(peak_to_peak * math.sqrt(2) / math.pi)
    assert signal.ac_rms_v == pytest.approx(1.273 / 2 * peak_to_peak / math.sqrt(2), rel=1e-3)
    assert signal.dc_v == pytest.approx(0.5 * 1e5 * (1e-6 + 1e-6))
    assert signal.frequency_hz == CHOPPER_HZ and signal.phase_deg == 0.0
    current = 0.5 * (1e-6 + 1e-6)
    assert signal.noise_v_per_rthz == pytest.approx(
        1e5 * math.sqrt(2 * ELEMENTARY_CHARGE_C * current))
    assert diode.signal(2e-6, 0.0, chopper_hz=None).frequency_hz == 0.0  # not modulated
    with pytest.raises(ValueError):
        ChoppedPhotodiode(responsivity_a_per_w=0.0)
    with pytest.raises(ValueError):
        ChoppedPhotodiode(aperture_diameter_mm=-1.0)
    with pytest.raises(ValueError):
        diode.signal(-1.0, 0.0, chopper_hz=CHOPPER_HZ)


def test_split_separates_source_borne_and_ambient_light():
    plain = configure_world("sim", world_config())
    plain.update_source(on=True)
    source_only, ambient_none = split_power_w(plain)
    assert ambient_none == 0.0
    assert source_only == pytest.approx(plain.optical_power_w())
    lit = configure_world("sim", world_config(ambient=AMBIENT))
    lit.update_source(on=True)
    source_w, ambient_w = split_power_w(lit)
    assert source_w == pytest.approx(source_only, rel=1e-9)
    assert ambient_w > 10 * source_w
    assert source_w + ambient_w == pytest.approx(lit.optical_power_w())
    lit.update_source(on=False)
    assert split_power_w(lit) == (0.0, pytest.approx(ambient_w))


@pytest.fixture
def detector():
    """The world with strong ambient light, and a lock-in whose photodiode sits on the
    detector arm, opened through the real driver."""
    world = configure_world("sim", world_config(ambient=AMBIENT))
    world.update_source(on=True)
    lockin = Sr830LockIn(
        f"simsr830://det?world=sim&chopper={CHOPPER_HZ:g}&speed=20&seed=4&gain=1e6",
        name="det", reply_timeout=0.3)
    lockin.time_constant_s = 0.01
    lockin.sensitivity_v = 0.05
    lockin.reference_source = "external"
    yield world, lockin
    lockin.close()


def expected_rms(world) -> float:
    source_w, _ = split_power_w(world)
    return math.sqrt(2) / math.pi * 0.4 * 1e6 * source_w


def noise_sigma_v() -> float:
    """Standard deviation of X (and Y) of the ``detector`` lock-in: input noise density
    (amplifier and shot noise) times the square root of the ENBW, 1/(8 tau) at 12 dB/oct."""
    density = registry.get("simsr830", "det").input_signal().noise_v_per_rthz
    return density * math.sqrt(1 / (8 * 0.01))


def test_lock_in_reads_the_chopped_scattered_light(detector):
    world, lockin = detector
    assert lockin.reference_frequency_hz == pytest.approx(CHOPPER_HZ)
    lockin.settle(20)
    reading = lockin.snapshot()
    assert 5e-3 < expected_rms(world) < 0.05
    assert reading.r_v == pytest.approx(expected_rms(world), rel=1e-3)
    binding = registry.get("simsr830", "det").input_signal
    assert isinstance(binding, LockInBinding)
    assert binding().dc_v > 10 * reading.r_v  # the DC, mostly ambient, is rejected
    assert not lockin.overload_status().overloaded


def test_reading_follows_the_detector_position_and_the_source(detector):
    world, lockin = detector
    lockin.settle(20)
    at_30 = lockin.snapshot().r_v
    world.set_role("detector_theta", 60.0)  # Lambertian: power follows cos(theta)
    lockin.settle(20)
    at_60 = lockin.snapshot().r_v
    assert at_60 == pytest.approx(expected_rms(world), rel=1e-3)
    assert at_60 / at_30 == pytest.approx(math.cos(math.radians(60)) /
                                          math.cos(math.radians(30)), rel=1e-2)
    world.update_source(on=False)  # only ambient light: nothing at the chopper frequency
    lockin.settle(20)
    assert lockin.snapshot().r_v < 5 * noise_sigma_v()


def test_internal_reference_away_from_the_chopper_reads_only_noise(detector):
    _world, lockin = detector
    lockin.reference_source = "internal"  # 1 kHz, the light is chopped at 137 Hz
    lockin.settle(20)
    assert lockin.snapshot().r_v < 5 * noise_sigma_v()


def test_lock_in_made_before_its_world_reads_darkness_then_light():
    lockin = Sr830LockIn(f"simsr830://early?world=later&chopper={CHOPPER_HZ:g}&speed=20",
                         name="early", reply_timeout=0.3)
    lockin.time_constant_s = 0.01
    lockin.reference_source = "external"
    lockin.settle(20)
    assert lockin.snapshot().r_v < 1e-6
    world = configure_world("later", world_config())
    world.update_source(on=True)
    lockin.settle(20)
    assert lockin.snapshot().r_v == pytest.approx(expected_rms(world), rel=1e-3)
    lockin.close()


def test_world_option_needs_a_chopper_and_known_options():
    with pytest.raises(ConnectionFailed, match="chopper"):
        Sr830LockIn("simsr830://nochop?world=sim", name="x", reply_timeout=0.05)
    with pytest.raises(ConnectionFailed, match="unknown simsr830 options"):
        Sr830LockIn("simsr830://typo?wrold=sim", name="x", reply_timeout=0.05)
