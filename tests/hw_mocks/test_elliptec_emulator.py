"""The Elliptec bus emulator on its own: raw bytes in, raw bytes out, manual time.

These tests pin the emulator to the protocol facts (the *ELLx modules protocol manual* and
its docstring's assumptions) without the driver, so the driver's tests test the driver
against an independent reading.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from hw_mocks import registry
from hw_mocks.clock import ManualClock
from hw_mocks.firmware.elliptec import ElliptecEmulator
from tests.hw_mocks.purity import assert_imports_nothing_forbidden

DEG = 360.0 / 143360


@pytest.fixture
def clock():
    return ManualClock()


@pytest.fixture
def bus(clock):
    return ElliptecEmulator("bus", addresses="02", start_positions=[10.0, 0.0], clock=clock)


def test_info_status_and_position(bus):
    assert bus.receive(b"0in") == [b"0IN0E11400000202317010168" + b"00023000\r\n"]
    assert bus.receive(b"2gs") == [b"2GS00\r\n"]
    assert bus.receive(b"0gp\r\n") == [b"0PO00000000\r\n"]  # CR LF between packets ignored
    assert bus.receive(b"5gs") == []  # nobody at address 5
    assert bus.receive(b"0gv") == [b"0GV64\r\n"]


def test_packets_may_arrive_in_pieces(bus):
    assert bus.receive(b"0m") == []
    assert bus.receive(b"a0000") == []
    assert bus.receive(b"0100") == []  # the move started; its reply comes when it ends
    assert bus.receive(b"0gs") == [b"0GS09\r\n"]


def test_move_replies_when_it_ends_and_reports_busy_meanwhile(bus, clock):
    assert bus.receive(b"2ma00004600") == []  # 17920 pulses = 45 deg
    assert bus.receive(b"2gs") == [b"2GS09\r\n"]
    assert bus.receive(b"2sv32") == [b"2GS09\r\n"]  # refused while moving
    clock.advance(1.0)
    assert bus.receive(b"2gs") == [b"2PO00004600\r\n", b"2GS00\r\n"]
    assert bus.modules["2"].stage.physical_position() == pytest.approx(45.0)
    assert bus.receive(b"2mrFFFFB9FF") == []  # -17921 pulses
    clock.advance(1.0)
    assert bus.poll() == [b"2POFFFFFFFF\r\n"]


def test_home_references_the_physical_index(bus, clock):
    assert bus.receive(b"0ho0") == []
    clock.advance(1.0)
    assert bus.poll() == [b"0PO00000000\r\n"]
    assert bus.modules["0"].stage.physical_position() == pytest.approx(0.0)


def test_stop_velocity_and_refusals(bus, clock):
    assert bus.receive(b"0sv19") == [b"0GS00\r\n"]  # 25 %
    assert bus.receive(b"0sv65") == [b"0GS04\r\n"]  # above 100 %
    assert bus.receive(b"0ma0000460G") == [b"0GS04\r\n"]  # not hex digits
    assert bus.receive(b"0ho7") == [b"0GS04\r\n"]  # no such direction
    bus.receive(b"0ma00008C00")
    clock.advance(0.1)
    out = bus.receive(b"0st")
    assert out[-1] == b"0GS00\r\n" and out[0].startswith(b"0PO")
    assert bus.receive(b"0zz") == [b"0GS03\r\n"]  # unknown mnemonic: command error


def test_error_state_answers_the_motion_and_latches_once(bus, clock):
    bus.receive(b"0ma00008C00")
    clock.advance(0.05)
    bus.enter_error_state("0:02")
    assert bus.poll() == [b"0GS02\r\n"]
    assert bus.receive(b"0gs") == [b"0GS02\r\n"]  # read once...
    assert bus.receive(b"0gs") == [b"0GS00\r\n"]  # ...then cleared
    with pytest.raises(ValueError):
        bus.enter_error_state("09")
    with pytest.raises(ValueError):
        bus.enter_error_state("7:02")


def test_url_options_and_reconnect_stale_bytes():
    registry.remove("simell", "urlbus")
    port = serial.serial_for_url("simell://urlbus?addresses=13&start=5,6&step=0.001",
                                 baudrate=9600, timeout=0.2)
    emulator = registry.get("simell", "urlbus")
    assert isinstance(emulator, ElliptecEmulator) and set(emulator.modules) == {"1", "3"}
    assert emulator.modules["3"].stage.physical_position() == pytest.approx(6.0)
    port.close()
    port = serial.serial_for_url("simell://urlbus", baudrate=9600, timeout=0.2)
    assert port.read(64).endswith(b"\r\n")  # an old reply left in the pipe
    port.close()
    with pytest.raises(ValueError):
        serial.serial_for_url("simell://bad?addresses=01&start=1,2,3", baudrate=9600)
    registry.remove("simell", "urlbus")


def test_wrong_baud_rate_sees_nothing():
    port = serial.serial_for_url("simell://baud", baudrate=115200, timeout=0.05)
    port.write(b"0in")
    assert port.read(10) == b""
    port.close()
    registry.remove("simell", "baud")


def test_firmware_emulator_imports_nothing_from_drivers():
    root = Path(__file__).resolve().parents[2] / "hw_mocks"
    assert_imports_nothing_forbidden(root / "firmware" / "elliptec.py",
                                     root / "urlhandler" / "protocol_simell.py")


# --------------------------------------------------------------------------- fuzzing

_REPLY = re.compile(rb"[02](IN[0-9A-F]{30}|GS[0-9A-F]{2}|PO[0-9A-F]{8}|GV[0-9A-F]{2}"
                    rb"|GJ[0-9A-F]{8})\r\n")
_packets = st.one_of(
    st.tuples(st.sampled_from("0257"), st.sampled_from(
        ["in", "gs", "gp", "gv", "gj", "st", "fw", "bw", "ho", "ma", "mr", "sj", "sv", "zz"]),
        st.text("0123456789ABCDEFX", max_size=8)).map(lambda t: "".join(t).encode()),
    st.binary(max_size=6))


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(_packets, st.floats(0.0, 0.5)), max_size=25))
def test_any_byte_stream_gets_only_well_formed_replies(script):
    """Whatever arrives (packets with any data, line noise), the bus answers only
    well-formed replies from modules that exist, and never raises."""
    clock = ManualClock()
    bus = ElliptecEmulator("fuzz", addresses="02", clock=clock)
    for data, dt in script:
        for frame in bus.receive(data) + bus.poll():
            assert _REPLY.fullmatch(frame), frame
        clock.advance(dt)
