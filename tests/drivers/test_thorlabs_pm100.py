"""Thorlabs PM100USB driver on the emulated console (USBTMC over the pyusb backend).

Power readings are checked against the light the test injects, with tolerances derived
from the firmware's documented noise model: per-sample current noise
``σ_I = sqrt(noise_floor² + (relative_noise·R·P)²)``, averaged over ``n`` samples, read
out as ``(I − I_zero)/R(λ_set)``.
"""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceTimeout,
    ProtocolError,
    StateError,
)
from drivers.thorlabs_pm100 import PM100USB, parse_scpi_error, parse_scpi_number
from hw_mocks.faults import FaultKind
from hw_mocks.firmware.pm100usb import Pm100usbFirmware, ScpiError
from hw_mocks.firmware.pm100usb import parse_scpi_number as firmware_parse_number
from hw_mocks.usb import backend_from_url, get_firmware

URL = "simusb://power_meter?serial=P2000000&seed=3&speed=50"
TIMEOUT_S = 0.25


@pytest.fixture
def firmware() -> Pm100usbFirmware:
    backend_from_url(URL)
    return get_firmware("power_meter")


@pytest.fixture
def meter(firmware):
    pm = PM100USB(name="power_meter", backend=backend_from_url(URL), timeout_s=TIMEOUT_S,
                  zero_poll_s=0.002)
    yield pm
    pm.close()


def reading_sigma_w(fw: Pm100usbFirmware, power_w: float, light_nm: float, set_nm: float,
                    n: int) -> float:
    """Standard deviation of one averaged reading under the firmware's noise model."""
    signal_a = fw.responsivity_a_per_w(light_nm) * power_w
    sigma_a = math.hypot(fw.noise_floor_a, fw.relative_noise * signal_a) / math.sqrt(n)
    return sigma_a / fw.responsivity_a_per_w(set_nm)


def readings(pm: PM100USB, k: int) -> np.ndarray:
    return np.array([pm.read_power_w() for _ in range(k)])


# --------------------------------------------------------------------------- identity

def test_identity_and_sensor(meter):
    ident = meter.identity
    assert (ident.vendor, ident.model, ident.serial) == ("Thorlabs", "PM100USB", "P2000000")
    assert ident.firmware == "1.7.0"
    assert ident.extra["sensor"] == "S120C"
    assert meter.sensor.serial == "200611301"
    assert meter.wavelength_range_nm == (400.0, 1100.0)


def test_open_sends_exactly_the_identification_sequence(firmware):
    PM100USB(name="pm", backend=backend_from_url(URL), timeout_s=TIMEOUT_S).close()
    assert firmware.commands == ["*IDN?", "SYST:SENS:IDN?", "*CLS", "SENS:CORR:WAV? MIN",
                                 "SENS:CORR:WAV? MAX"]


def test_open_by_serial_number(firmware):
    with PM100USB(name="pm", serial_number="P2000000", backend=backend_from_url(URL),
                  timeout_s=TIMEOUT_S) as pm:
        assert pm.identity.serial == "P2000000"
    with pytest.raises(ConnectionFailed, match="not found"):
        PM100USB(name="pm", serial_number="P1234567", backend=backend_from_url(URL))


def test_stale_errors_from_before_are_cleared_on_open(firmware):
    firmware.push_error(-222)
    with PM100USB(name="pm", backend=backend_from_url(URL), timeout_s=TIMEOUT_S) as pm:
        pm.averaging = 3    # would raise ControllerError if the old error were still queued


# --------------------------------------------------------------------------- settings

def test_wavelength_set_and_read_back(meter, firmware):
    meter.wavelength_nm = 850.0
    assert meter.wavelength_nm == 850.0
    assert firmware.commands[-3:-1] == ["SENS:CORR:WAV 850", "SYST:ERR?"]
    meter.wavelength_nm = 1064.5
    assert meter.wavelength_nm == pytest.approx(1064.5, abs=1e-6)


def test_wavelength_outside_the_sensor_range_is_refused_before_sending(meter, firmware):
    sent = len(firmware.commands)
    with pytest.raises(ValueError, match="outside"):
        meter.wavelength_nm = 1550.0
    assert len(firmware.commands) == sent


def test_device_rejection_is_a_controller_error_with_the_scpi_code(meter, firmware):
    meter.wavelength_nm = 850.0
    meter.wavelength_range_nm = (200.0, 2000.0)   # stale: a different head was fitted
    with pytest.raises(ControllerError) as info:
        meter.wavelength_nm = 1550.0
    assert info.value.code == -222
    assert "Data out of range" in str(info.value)
    assert info.value.command == "SENS:CORR:WAV 1550"
    assert meter.wavelength_nm == 850.0            # the setting did not change
    assert firmware.error_queue == []              # the queue was drained


def test_auto_range_and_averaging(meter, firmware):
    meter.auto_range = False
    assert meter.auto_range is False and firmware.auto_range is False
    meter.auto_range = True
    assert meter.auto_range is True
    meter.averaging = 250
    assert meter.averaging == 250 and firmware.average_count == 250
    with pytest.raises(ControllerError) as info:
        meter.averaging = 20000
    assert info.value.code == -222
    with pytest.raises(ValueError):
        meter.averaging = 0


def test_unknown_query_timeout_becomes_the_queued_controller_error(meter):
    with pytest.raises(ControllerError) as info:
        meter.query("SENS:BOGUS?")
    assert info.value.code == -113
    assert isinstance(info.value.__cause__, DeviceTimeout)


# --------------------------------------------------------------------------- readings

def test_dark_offset_then_zeroing_removes_it(meter, firmware):
    n = 10
    meter.averaging = n
    set_nm = meter.wavelength_nm
    r_set = firmware.responsivity_a_per_w(set_nm)
    offset_w = firmware.dark_current_a / r_set
    sigma = reading_sigma_w(firmware, 0.0, set_nm, set_nm, n)
    dark = readings(meter, 40)
    # Before zeroing the dark current shows as an offset of ~4.9 nW (≫ σ ≈ 0.08 nW).
    assert abs(dark.mean() - offset_w) < 5 * sigma / math.sqrt(dark.size)
    meter.zero(timeout=2.0)
    assert firmware.commands.count("SENS:CORR:COLL:ZERO:INIT") == 1
    assert meter.zero_offset_w == pytest.approx(offset_w, rel=1e-3)
    zeroed = readings(meter, 40)
    # The zero's own noise (1000 samples) adds σ/√100 in quadrature: negligible.
    assert abs(zeroed.mean()) < 5 * sigma / math.sqrt(zeroed.size)
    assert 0.6 * sigma < zeroed.std(ddof=1) < 1.5 * sigma


def test_power_reading_matches_the_injected_source(meter, firmware):
    meter.zero(timeout=2.0)            # dark: the source still returns 0 W
    power_w = 1.0e-3
    calls: list[float] = []

    def source(wavelength_nm: float) -> float:
        calls.append(wavelength_nm)
        return power_w

    firmware.optical_power_w = source
    meter.wavelength_nm = 633.0
    meter.averaging = 4
    values = readings(meter, 50)
    sigma = reading_sigma_w(firmware, power_w, 633.0, 633.0, 4)
    assert abs(values.mean() - power_w) < 5 * sigma / math.sqrt(values.size)
    assert 0.6 * sigma < values.std(ddof=1) < 1.5 * sigma
    assert set(calls) == {633.0}       # the bench is asked at the light's wavelength


def test_wrong_wavelength_setting_scales_the_reading_by_the_responsivity_ratio(meter,
                                                                                firmware):
    power_w = 2.0e-4
    firmware.optical_power_w = lambda _wl: power_w
    firmware.light_wavelength_nm = 633.0        # a HeNe laser on the bench
    meter.zero(timeout=2.0)
    firmware.optical_power_w = lambda _wl: power_w
    meter.wavelength_nm = 900.0                 # but the meter is left at 900 nm
    meter.averaging = 4
    wrong = readings(meter, 30).mean()
    ratio = firmware.responsivity_a_per_w(633.0) / firmware.responsivity_a_per_w(900.0)
    assert ratio < 0.8                          # silicon: far less sensitive at 633 nm
    sigma = reading_sigma_w(firmware, power_w, 633.0, 900.0, 4) / math.sqrt(30)
    # The zero was taken with the light on, so it holds R(633)·P as well.
    assert abs(wrong) < 5 * sigma + 1e-12
    firmware.optical_power_w = lambda _wl: 0.0
    meter.zero(timeout=2.0)                     # now a proper dark zero
    firmware.optical_power_w = lambda _wl: power_w
    wrong = readings(meter, 30).mean()
    assert abs(wrong - power_w * ratio) < 5 * sigma
    meter.wavelength_nm = 633.0
    right = readings(meter, 30).mean()
    assert abs(right - power_w) < 5 * reading_sigma_w(firmware, power_w, 633.0, 633.0, 4)


def test_zero_that_never_finishes_times_out_and_aborts(meter, firmware):
    firmware.zero_stuck = True
    with pytest.raises(DeviceTimeout, match="dark zero"):
        meter.zero(timeout=0.1)
    assert firmware.commands[-2:] == ["SENS:CORR:COLL:ZERO:ABOR", "SYST:ERR?"]
    firmware.zero_stuck = False
    assert meter.read_power_w() == pytest.approx(
        firmware.dark_current_a / firmware.responsivity_a_per_w(635.0), rel=0.2)


# --------------------------------------------------------------------------- faults

def test_lost_reply_is_a_timeout_never_a_hang_and_the_next_reading_works(meter, firmware):
    firmware.optical_power_w = lambda _wl: 1e-3
    firmware.faults.schedule(FaultKind.DROP, nth=1)
    with pytest.raises(DeviceTimeout):
        meter.read_power_w()
    assert meter.read_power_w() == pytest.approx(1e-3, rel=1e-2)


def test_disconnect_is_connection_failed(meter, firmware):
    firmware.faults.schedule(FaultKind.DISCONNECT, nth=1)
    with pytest.raises(ConnectionFailed):
        meter.read_power_w()
    meter.close()
    with PM100USB(name="pm", backend=backend_from_url(URL), timeout_s=TIMEOUT_S) as again:
        assert again.identity.serial == "P2000000"


def test_device_error_state_surfaces_on_the_next_setting(meter, firmware):
    firmware.faults.schedule(FaultKind.ERROR_STATE, nth=1, code="-310")
    meter.read_power_w()                 # the reply still arrives
    with pytest.raises(ControllerError) as info:
        meter.averaging = 2
    assert info.value.code == -310


def test_failed_open_leaves_the_device_free(firmware):
    firmware.faults.schedule(FaultKind.DISCONNECT, nth=1)
    with pytest.raises(ConnectionFailed):
        PM100USB(name="pm", backend=backend_from_url(URL), timeout_s=TIMEOUT_S)
    with PM100USB(name="pm", backend=backend_from_url(URL), timeout_s=TIMEOUT_S) as pm:
        assert pm.identity.model == "PM100USB"


def test_closed_meter_refuses_calls(meter):
    meter.close()
    meter.close()
    with pytest.raises(StateError):
        meter.read_power_w()


# --------------------------------------------------------------------------- parsers

@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e30, max_value=1e30))
def test_number_parser_reads_pm100_formatted_values(x):
    assert parse_scpi_number(f"{x:.6E}\n") == pytest.approx(x, rel=1e-6, abs=1e-300)
    assert parse_scpi_number(f" {x!r} ") == x


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=20))
def test_number_parser_accepts_numbers_or_raises_protocol_error(text):
    try:
        value = parse_scpi_number(text)
    except ProtocolError:
        return
    assert math.isfinite(value)
    assert float(text) == value


@pytest.mark.parametrize("text", ["", "nan", "inf", "1e", "1,2", "--1", "9.91E37", "0x10"])
def test_number_parser_rejects(text):
    with pytest.raises(ProtocolError):
        parse_scpi_number(text)


@given(st.integers(-999, 999), st.text(alphabet=st.characters(blacklist_characters='"\n'),
                                        max_size=30))
def test_error_reply_round_trip(code, message):
    assert parse_scpi_error(f'{code:+d},"{message}"\n') == (code, message)


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=20))
def test_firmware_number_parser_accepts_scpi_numbers_or_raises_scpi_error(text):
    try:
        value = firmware_parse_number(text)
    except ScpiError as err:
        assert err.code in (-104, -222)
        return
    # Surrounding white space is dropped first: str.strip's set includes control characters
    # such as 0x1F that float() refuses, and SCPI counts 0x01-0x20 as white space.
    assert value == float(text.strip())


@settings(max_examples=100, deadline=None)
@given(st.floats(min_value=400.0, max_value=1100.0))
def test_any_in_range_wavelength_round_trips_through_the_firmware(wavelength):
    fw = Pm100usbFirmware("fuzz")
    assert fw.receive(f"SENS:CORR:WAV {wavelength:.9g}\n".encode()) == []
    assert fw.error_queue == []
    reply = fw.receive(b"SENS:CORR:WAV?\n")[0]
    assert float(reply) == pytest.approx(float(f"{wavelength:.9g}"), rel=1e-6)


def test_threads_sharing_the_meter_never_interleave_a_setting_and_its_error_check(meter):
    failures: list[BaseException] = []

    def settings_worker() -> None:
        try:
            for k in range(1, 40):
                meter.averaging = k
        except Exception as err:
            failures.append(err)

    def readings_worker() -> None:
        try:
            for _ in range(40):
                parse_scpi_number(f"{meter.read_power_w():.6E}")
        except Exception as err:
            failures.append(err)

    threads = [threading.Thread(target=settings_worker), threading.Thread(target=readings_worker)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert not any(t.is_alive() for t in threads)
    assert failures == []
    assert meter.averaging == 39
