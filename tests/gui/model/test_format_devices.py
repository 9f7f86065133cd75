"""Plain unit tests: number formatting and the device-kind registry."""

from __future__ import annotations

import math

import pytest

from drivers.base import Device, DeviceIdentity
from drivers.errors import ConnectionFailed
from gui.model.format import duration, position, si
from hw_mocks.sim.ideal import IdealAxis, IdealPowerMeter, IdealSource
from instrument.bench import device_state as devices


@pytest.mark.parametrize(("value", "unit", "text"), [
    (1.2345e-3, "W", "1.234 mW"), (0.0, "W", "0 W"), (2.5e-7, "W", "250 nW"),
    (999.96e-6, "W", "1 mW"), (math.nan, "W", "—"), (None, "s", "—"), (-3e-3, "A", "-3 mA"),
])
def test_si(value, unit, text):
    assert si(value, unit) == text


@pytest.mark.parametrize(("seconds", "text"), [
    (3.21, "3.2 s"), (42.4, "42 s"), (119.6, "2 min 00 s"), (3725, "1 h 02 min"),
    (math.inf, "—"),
])
def test_duration(seconds, text):
    assert duration(seconds) == text


def test_position_precision_follows_the_units():
    assert position(1.23456, "deg") == "1.235 deg"
    assert position(1.23456, "mm") == "1.2346 mm"
    assert position(None, "mm") == "—"


def test_each_kind_is_read_through_its_abc():
    axis = IdealAxis("sample_theta", soft_limits=(-90, 90))
    axis.move_to(12.5)
    st = devices.read_state("sample_theta", axis, with_info=True)
    assert st.kind == "motion_axis" and st.connected and st.error is None
    assert st.values["position"] == 12.5 and st.values["homed"] is True
    assert st.info["limits"] == (-90.0, 90.0) and st.info["units"] == "deg"
    assert st.info["identity"]["model"] == "ideal-axis"
    pm = devices.read_state("pm", IdealPowerMeter("pm", reading_w=2e-3), with_info=True)
    assert pm.kind == "power_meter" and pm.values == {"power_w": 2e-3, "wavelength_nm": 633.0}
    src = devices.read_state("source", IdealSource(), with_info=True)
    assert src.kind == "light_source" and src.values["on"] is False


class _LockIn(Device):
    """A device of a kind the GUI does not know yet."""

    def __init__(self) -> None:
        super().__init__("lock_in")
        self.fail = False

    @property
    def x_v(self) -> float:
        if self.fail:
            raise ConnectionFailed("unplugged", device=self.name, command="OUTP?1")
        return 1.5e-6

    def _do_identity(self) -> DeviceIdentity:
        return DeviceIdentity("SRS", "SR830", "1234")

    def _do_close(self) -> None:
        pass


def test_an_unknown_kind_is_shown_and_a_registered_one_is_read():
    dev = _LockIn()
    st = devices.read_state("lock_in", dev, with_info=True)
    assert st.kind == devices.UNKNOWN_KIND and st.info["identity"]["model"] == "SR830"
    kind = devices.DeviceKind("lock_in", "Lock-in amplifier", _LockIn, lambda d: {},
                              lambda d: {"x_v": d.x_v}, poll_s=0.2, settings=("x_v",))
    devices.register_kind(kind)
    try:
        st = devices.read_state("lock_in", dev, with_info=False)
        assert st.kind == "lock_in" and st.values == {"x_v": 1.5e-6}
        dev.fail = True
        st = devices.read_state("lock_in", dev, with_info=False, info=st.info)
        assert not st.connected and "unplugged" in st.error
    finally:
        devices._KINDS.remove(kind)
