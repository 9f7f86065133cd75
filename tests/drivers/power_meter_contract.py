"""The contract every :class:`drivers.base.PowerMeter` implementation keeps.

Subclass :class:`PowerMeterContract` and provide a fixture ``meter_factory`` returning a
freshly opened meter whose light can be switched with the fixture ``light`` (a callable
taking True/False), so that readings can be checked against darkness.
"""

from __future__ import annotations

import math

import pytest

from drivers.base import DeviceIdentity, PowerMeter
from drivers.errors import StateError


class PowerMeterContract:
    @pytest.fixture
    def meter(self, meter_factory):
        meter = meter_factory()
        yield meter
        meter.close()

    def test_identity(self, meter):
        assert isinstance(meter, PowerMeter)
        ident = meter.identity
        assert isinstance(ident, DeviceIdentity) and ident.model and ident.serial

    def test_wavelength_round_trip_and_range(self, meter):
        low, high = meter.wavelength_range_nm
        assert 0 < low < high
        target = round((low + high) / 2)
        meter.wavelength_nm = target
        assert meter.wavelength_nm == pytest.approx(target, abs=0.5)
        with pytest.raises(ValueError):
            meter.wavelength_nm = high + 100.0
        with pytest.raises(ValueError):
            meter.wavelength_nm = math.nan
        assert meter.wavelength_nm == pytest.approx(target, abs=0.5)

    def test_averaging_and_auto_range_round_trip(self, meter):
        meter.averaging = 7
        assert meter.averaging == 7
        with pytest.raises(ValueError):
            meter.averaging = 0
        meter.auto_range = False
        assert meter.auto_range is False
        meter.auto_range = True
        assert meter.auto_range is True

    def test_light_reads_more_than_dark_after_zeroing(self, meter, light):
        light(False)
        meter.zero(timeout=10.0)
        dark = [meter.read_power_w() for _ in range(5)]
        light(True)
        lit = [meter.read_power_w() for _ in range(5)]
        assert all(math.isfinite(x) for x in dark + lit)
        spread = max(abs(x) for x in dark)
        assert min(lit) > 10 * max(spread, 1e-15)

    def test_close_is_idempotent_and_closed_meter_refuses(self, meter_factory):
        meter = meter_factory()
        meter.close()
        meter.close()
        with pytest.raises(StateError):
            meter.read_power_w()
