"""The virtual bench's light path: a shutter gates the light, a filter wheel shapes it.

Light at the sample = source on AND shutter open AND the wheel standing at a slot; its
power and spectrum are those the filter in that slot passes. The shutter and the wheel are
the firmware emulators, moved by the real drivers over their URLs.
"""

from __future__ import annotations

import math

import pytest

from drivers.thorlabs_fw102c import Fw102cWheel
from drivers.thorlabs_sc10 import Sc10Shutter
from hw_mocks import registry
from hw_mocks.clock import ManualClock
from hw_mocks.firmware.fw102c import Fw102cEmulator
from hw_mocks.firmware.sc10 import Sc10Emulator
from hw_mocks.sim.filters import FilterBand, parse_bands, transmit
from hw_mocks.sim.world import (
    LightPath,
    PowerMeterHead,
    SourceState,
    VirtualBench,
    configure_world,
    find_world,
)

HEAD = PowerMeterHead(distance_mm=300.0, aperture_diameter_mm=9.5)
OMEGA = math.pi * (4.75e-3) ** 2 / 0.3**2  # head solid angle, sr
LASER = SourceState(on=True, power_w=1e-3, wavelength_nm=633.0)
FILTERS = {2: {"center_nm": 633.0, "bandwidth_nm": 10.0, "peak_transmission": 0.9,
               "blocking": 1e-5},
           3: {"center_nm": 532.0, "bandwidth_nm": 10.0, "peak_transmission": 0.8}}


def lit_bench(**kw) -> VirtualBench:
    """A Lambertian sample (ρ = 0.5) seen at 30° by the meter head, source on."""
    world = VirtualBench("lp", roles={"sample_theta": 0.0, "detector_theta": 30.0},
                         power_meter=HEAD, **kw)
    world.update_source(on=True, power_w=1e-3)
    return world


def lambert_power(power_w: float) -> float:
    """f = ρ/π: P = ρ/π · P_i · cos θr · Ω (Nicodemus et al. 1977)."""
    return 0.5 / math.pi * power_w * math.cos(math.radians(30.0)) * OMEGA


# --------------------------------------------------------------------------- filters


def test_laser_line_passes_inside_the_band_and_is_blocked_outside():
    band = FilterBand(633.0, 10.0, peak_transmission=0.9, blocking=1e-5)
    inside = transmit(LASER, band)
    assert inside.power_w == pytest.approx(0.9e-3) and inside.wavelength_nm == 633.0
    assert inside.bandwidth_nm == 0.0
    outside = transmit(LASER, FilterBand(532.0, 10.0, blocking=1e-5))
    assert outside.power_w == pytest.approx(1e-8) and outside.wavelength_nm == 633.0
    assert transmit(LASER, None) is LASER


def test_broadband_source_takes_the_centre_and_width_of_the_overlap():
    lamp = SourceState(on=True, power_w=3e-3, wavelength_nm=550.0, bandwidth_nm=300.0)
    narrow = transmit(lamp, FilterBand(532.0, 10.0, peak_transmission=0.8))
    assert narrow.wavelength_nm == pytest.approx(532.0)
    assert narrow.bandwidth_nm == pytest.approx(10.0)
    assert narrow.power_w == pytest.approx(3e-3 * 0.8 * 10.0 / 300.0)
    edge = transmit(lamp, FilterBand(700.0, 20.0))  # the lamp ends at 700 nm
    assert edge.wavelength_nm == pytest.approx(695.0) and edge.bandwidth_nm == pytest.approx(10)
    assert edge.power_w == pytest.approx(3e-3 * 10.0 / 300.0)
    beyond = transmit(lamp, FilterBand(900.0, 20.0, blocking=1e-4))
    assert beyond.power_w == pytest.approx(3e-7) and beyond.wavelength_nm == 550.0


@pytest.mark.parametrize("kw", [
    {"center_nm": 0.0, "bandwidth_nm": 10.0},
    {"center_nm": 500.0, "bandwidth_nm": math.nan},
    {"center_nm": 500.0, "bandwidth_nm": 10.0, "peak_transmission": 1.2},
    {"center_nm": 500.0, "bandwidth_nm": 10.0, "blocking": 0.5, "peak_transmission": 0.4},
])
def test_filter_band_is_validated(kw):
    with pytest.raises(ValueError):
        FilterBand(**kw)


def test_parse_bands_from_plain_tables():
    bands = parse_bands({"2": {"center_nm": 633, "bandwidth_nm": 10, "label": "red"},
                         3: {}, "4": {"label": "clear"}})
    assert bands == {2: FilterBand(633.0, 10.0)}
    for bad in ({"0": {"center_nm": 1, "bandwidth_nm": 1}}, {"x": {}},
                {1: {"center_nm": 500, "bandwidth_nm": 10, "od": 6}}):
        with pytest.raises(ValueError):
            parse_bands(bad)
    with pytest.raises(TypeError):
        parse_bands({1: 633.0})


# --------------------------------------------------------------------------- shutter


def test_light_is_off_while_the_shutter_is_shut():
    emulator = Sc10Emulator("sh")
    world = lit_bench(light_path=LightPath(shutter="simsc10://sh"))
    registry.get_or_create("simsc10", "sh", lambda n, o: emulator)
    assert not world.light_at_sample().on
    assert not world.snapshot().source.on
    assert world.optical_power_w() == 0.0  # no ambient light in this scene
    emulator.press_enable_button()
    assert world.light_at_sample().on
    assert world.optical_power_w() == pytest.approx(lambert_power(1e-3), rel=5e-3)


def test_the_real_driver_gates_the_light_through_the_world_option():
    world = configure_world("sim", {"roles": {"detector_theta": 30.0},
                                    "power_meter": {"distance_mm": 300.0,
                                                    "aperture_diameter_mm": 9.5}})
    world.update_source(on=True)
    with Sc10Shutter("simsc10://shutter?world=sim", name="shutter") as shutter:
        assert world.light_path.shutter == "simsc10://shutter"
        assert world.optical_power_w() == 0.0
        shutter.turn_on()
        lit = world.optical_power_w()
        assert lit == pytest.approx(lambert_power(1e-3), rel=5e-3)
        shutter.turn_off()
        assert world.optical_power_w() == 0.0
        shutter.turn_on()
    # closing the driver closes the shutter: the sample is dark again
    assert not world.light_at_sample().on
    world.update_source(on=False)
    registry.get("simsc10", "shutter").press_enable_button()
    assert not world.light_at_sample().on  # shutter open, source off: still dark


def test_world_configured_with_a_shutter_url_creates_and_reads_it():
    world = configure_world("cfg", {"shutter": "simsc10://cfg_shutter?interlock=1"})
    world.update_source(on=True)
    assert not world.light_at_sample().on
    emulator = registry.get("simsc10", "cfg_shutter")
    assert emulator.interlock  # created with the URL's options
    world.bind_shutter(None)
    assert world.light_at_sample().on


def test_world_option_without_a_world_binds_nothing():
    with Sc10Shutter("simsc10://lonely?world=nowhere", name="lonely") as shutter:
        shutter.turn_on()
    assert find_world("nowhere") is None


# --------------------------------------------------------------------------- filter wheel


def test_wavelength_and_power_follow_the_filter_moved_by_the_real_driver():
    configure_world("sim", {"roles": {"detector_theta": 30.0},
                            "power_meter": {"distance_mm": 300.0, "aperture_diameter_mm": 9.5},
                            "filter_wheel": {"url": "simfw102c://wheel", "filters": FILTERS}})
    world = find_world("sim")
    world.update_source(on=True)
    described = {slot: {k: band[k] for k in ("center_nm", "bandwidth_nm")}
                 for slot, band in FILTERS.items()}  # what the driver is told
    with Fw102cWheel("simfw102c://wheel?speed=100&world=sim", name="wheel",
                     filters=described) as wheel:
        assert wheel.filter_at(2).center_nm == 633.0
        assert world.optical_power_w() == pytest.approx(lambert_power(1e-3), rel=5e-3)
        wheel.move_to(2)
        assert world.snapshot().source.wavelength_nm == 633.0
        assert world.optical_power_w() == pytest.approx(lambert_power(0.9e-3), rel=5e-3)
        wheel.move_to(3)  # a green filter in a red beam: dark
        assert world.light_at_sample().power_w == 0.0
        assert world.optical_power_w() == 0.0
        world.update_source(wavelength_nm=550.0, bandwidth_nm=300.0)  # a lamp instead
        light = world.light_at_sample()
        assert (light.wavelength_nm, light.bandwidth_nm) == pytest.approx((532.0, 10.0))
        assert light.power_w == pytest.approx(1e-3 * 0.8 * 10.0 / 300.0)


def test_beam_is_blocked_while_the_wheel_turns_or_is_jammed():
    clock = ManualClock()
    emulator = Fw102cEmulator("turning", clock=clock)
    registry.get_or_create("simfw102c", "turning", lambda n, o: emulator)
    world = lit_bench()
    world.bind_filter_wheel(emulator, filters=FILTERS)
    assert world.light_path.filter_wheel == "simfw102c://turning"
    assert world.light_at_sample().on
    emulator.receive(b"pos=2\r")
    assert not world.light_at_sample().on and world.optical_power_w() == 0.0
    clock.advance(emulator.move_duration_s(1, 2))
    light = world.light_at_sample()
    assert light.on and light.power_w == pytest.approx(0.9e-3)
    emulator.jam("silent")
    emulator.receive(b"pos=4\r")
    clock.advance(60.0)
    assert not world.light_at_sample().on


def test_shutter_and_wheel_together():
    shutter, wheel = Sc10Emulator("s2"), Fw102cEmulator("w2", start=2)
    registry.get_or_create("simsc10", "s2", lambda n, o: shutter)
    registry.get_or_create("simfw102c", "w2", lambda n, o: wheel)
    world = lit_bench(light_path=LightPath.from_config(
        "simsc10://s2", {"url": "simfw102c://w2", "filters": FILTERS}))
    assert not world.light_at_sample().on
    shutter.press_enable_button()
    light = world.light_at_sample()
    assert light.on and light.power_w == pytest.approx(0.9e-3)


@pytest.mark.parametrize("config, error", [
    ({"shutter": "not a url"}, ValueError),
    ({"filter_wheel": {"url": "simfw102c://w", "slots": 6}}, ValueError),
    ({"filter_wheel": 6}, TypeError),
    ({"filter_wheel": {"filters": {"1": {"center_nm": -5, "bandwidth_nm": 1}}}}, ValueError),
])
def test_light_path_configuration_is_validated(config, error):
    with pytest.raises(error):
        configure_world("bad", config)


def test_reconfiguring_a_world_keeps_its_light_path_from_the_new_table():
    world = configure_world("re", {"shutter": "simsc10://re_shutter"})
    configure_world("re", {"filter_wheel": "simfw102c://re_wheel"})
    assert world.light_path == LightPath(filter_wheel="simfw102c://re_wheel")
