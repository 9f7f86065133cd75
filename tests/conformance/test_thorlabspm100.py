"""ThorlabsPM100 (an independent SCPI client of the PM100 consoles) against the PM100USB
model on the emulated USB bus.

The client needs an instrument object with ``write`` and ``query`` (it ships one for the
Linux usbtmc character device, and accepts a pyvisa resource); neither reaches an
emulated pyusb backend, so it is handed our USBTMC transport
(:class:`drivers.usbtmc.UsbtmcDevice`): the client's side under test is its SCPI, the
USBTMC framing is ours (checked on its own in ``tests/drivers/test_usbtmc.py``).

Quirk of the client: ``measure.scalar.power()`` only sends ``MEAS:SCAL:POW`` (a command
form); the value comes with the next ``read``.

No third-party client exists on the package index for the SC10, the FW102C or the
SMC100 (their conformance rests on the manuals' tables, see their emulator tests).
"""

from __future__ import annotations

import pytest

thorlabs_pm100 = pytest.importorskip("ThorlabsPM100", reason="ThorlabsPM100 not installed")

from drivers.usbtmc import UsbtmcDevice  # noqa: E402
from hw_mocks.usb import backend_from_url, get_firmware  # noqa: E402

URL = "simusb://pm_conformance?serial=P2000000&seed=3&speed=50"


def no_error(pm) -> bool:
    code, _, message = pm.system.error.next.partition(",")
    return int(code) == 0 and message == '"No error"'


@pytest.fixture
def meter():
    backend = backend_from_url(URL)
    firmware = get_firmware("pm_conformance")
    device = UsbtmcDevice(vendor_id=0x1313, product_id=0x8072, backend=backend,
                          timeout_s=10.0, name="pm100")
    yield thorlabs_pm100.ThorlabsPM100(inst=device), device, firmware
    device.close()


def test_identity_and_sensor(meter):
    pm, device, _ = meter
    assert device.query("*IDN?").split(",")[:3] == ["Thorlabs", "PM100USB", "P2000000"]
    sensor = pm.system.sensor.idn.split(",")
    assert sensor[0] == "S120C" and len(sensor) == 6


def test_settings_round_trip(meter):
    pm, _, _ = meter
    pm.sense.correction.wavelength = 633.0
    assert pm.sense.correction.wavelength == 633.0
    pm.sense.average.count = 25
    assert pm.sense.average.count == 25
    pm.sense.power.dc.range.auto = "OFF"
    assert pm.sense.power.dc.range.auto == 0
    pm.sense.power.dc.range.auto = "ON"
    assert pm.sense.power.dc.range.auto == 1
    assert pm.getconfigure == "POW"
    assert no_error(pm)


def test_a_reading_equals_the_light_within_its_noise(meter):
    pm, _, firmware = meter
    firmware.optical_power_w = lambda _nm: 1.0e-3
    pm.sense.average.count = 1
    pm.measure.scalar.power()
    value = float(pm.read)
    # One sample: σ = hypot(0.1 nA, 1e-4 × R·P) in current, 1e-4 relative here; the dark
    # current (2 nA, not zeroed) adds ~5e-6 relative. 1e-3 is ten σ.
    assert value == pytest.approx(1.0e-3, rel=1e-3)


def test_an_out_of_range_setting_is_queued_as_an_error(meter):
    pm, _, _ = meter
    pm.sense.correction.wavelength = 5000.0
    code, _, message = pm.system.error.next.partition(",")
    assert int(code) == -222 and "out of range" in message.lower()
    assert no_error(pm)
