"""The SC10 and FW102C firmware emulators on their own: raw bytes in, raw bytes out.

These tests pin the emulators to the manuals' keyword tables and to the terminal
behaviour open-source drivers record (echo, ``"> "`` prompt, ``Command error`` lines),
without the drivers, so that the driver tests test against an independent reading.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from hw_mocks import registry
from hw_mocks.clock import ManualClock
from hw_mocks.firmware.fw102c import SETTLE_S, Fw102cEmulator
from hw_mocks.firmware.sc10 import Sc10Emulator
from tests.hw_mocks.purity import assert_imports_nothing_forbidden

NOT_DEFINED = b"Command error CMD_NOT_DEFINED\n\r> "
ARG_INVALID = b"Command error CMD_ARG_INVALID\n\r> "


def talk(emu, line: str) -> bytes:
    """Send one line; return everything the unit sends back at once."""
    return b"".join(emu.receive(line.encode("ascii") + b"\r"))


def value(emu, query: str) -> str:
    out = talk(emu, query)
    echo = query.encode() + b"\r"
    assert out.startswith(echo) and out.endswith(b"\r> "), out
    return out[len(echo):-3].decode()


@pytest.fixture
def clock():
    return ManualClock()


@pytest.fixture
def sc10(clock):
    return Sc10Emulator("s", clock=clock)


@pytest.fixture
def fw(clock):
    return Fw102cEmulator("w", clock=clock)


# --------------------------------------------------------------------------- terminal


@pytest.mark.parametrize("emu_fixture", ["sc10", "fw"])
def test_echo_prompt_and_error_answers(emu_fixture, request):
    emu = request.getfixturevalue(emu_fixture)
    assert talk(emu, "") == b"\r" + NOT_DEFINED            # a bare CR
    assert talk(emu, "nonsense?") == b"nonsense?\r" + NOT_DEFINED
    assert talk(emu, "POS?") == b"POS?\r" + NOT_DEFINED     # keywords are lower case
    assert talk(emu, "x" * 80) == b"x" * 80 + b"\r" + NOT_DEFINED  # buffer overflow
    assert talk(emu, "speed=") == b"speed=\r" + NOT_DEFINED
    assert b"".join(emu.receive(b"\xff\xfe\r")) == b"\xff\xfe\r" + NOT_DEFINED


def test_split_lines_and_lf_are_handled(sc10):
    assert sc10.receive(b"ens") == []
    assert b"".join(sc10.receive(b"?\r\n")) == b"ens?\r0\r> "
    assert b"".join(sc10.receive(b"\nens?\r")) == b"ens?\r0\r> "  # the stray LF is dropped


# --------------------------------------------------------------------------- SC10


def test_sc10_power_up_and_identity(sc10):
    assert value(sc10, "id?") == "THORLABS SC10 VERSION 1.07"
    assert value(sc10, "*idn?") == "THORLABS SC10 VERSION 1.07"
    assert [value(sc10, k) for k in ("mode?", "trig?", "ens?", "closed?", "interlock?",
                                     "baud?", "rep?", "open?", "shut?", "xto?")] == \
        ["1", "0", "0", "1", "0", "0", "1", "10", "10", "0"]


def test_sc10_ens_toggles_and_takes_no_argument(sc10):
    assert talk(sc10, "ens") == b"ens\r> "
    assert value(sc10, "ens?") == "1" and value(sc10, "closed?") == "0"
    assert talk(sc10, "ens") == b"ens\r> "
    assert value(sc10, "ens?") == "0" and value(sc10, "closed?") == "1"
    assert talk(sc10, "ens=1") == b"ens=1\r" + NOT_DEFINED
    assert value(sc10, "ens?") == "0"


@pytest.mark.parametrize("line", ["mode=0", "mode=6", "rep=0", "rep=100", "open=1234567",
                                  "trig=2", "xto=-1", "baud=2", "mode=x"])
def test_sc10_out_of_range_arguments_are_invalid(sc10, line):
    assert talk(sc10, line) == line.encode() + b"\r" + ARG_INVALID


def test_sc10_settings_round_trip_and_savp_resp(sc10):
    for line in ("open=250", "shut=750", "rep=3", "trig=1", "mode=4"):
        assert talk(sc10, line) == line.encode() + b"\r> "
    assert [value(sc10, k) for k in ("open?", "shut?", "rep?", "trig?", "mode?")] == \
        ["250", "750", "3", "1", "4"]
    talk(sc10, "savp")
    talk(sc10, "mode=1")
    talk(sc10, "resp")
    assert value(sc10, "mode?") == "4"
    sc10.power_off()
    sc10.power_on()
    assert value(sc10, "mode?") == "4" and value(sc10, "open?") == "250"


def test_sc10_timed_modes_follow_the_clock(sc10, clock):
    talk(sc10, "open=100")
    talk(sc10, "shut=300")
    talk(sc10, "mode=2")  # auto: 100 ms open, 300 ms shut, repeatedly
    talk(sc10, "ens")  # at t = 0
    states = []
    for k in range(10):  # mid-points of 50 ms steps: 0.025 ... 0.475 s
        clock.set(0.025 + 0.05 * k)
        states.append(value(sc10, "closed?"))
    assert states == ["0", "0"] + ["1"] * 6 + ["0", "0"]  # the second cycle opens at 0.4 s
    talk(sc10, "ens")
    talk(sc10, "rep=2")
    talk(sc10, "mode=4")  # repeat: two cycles, then closed
    talk(sc10, "ens")
    t0 = clock.now()
    opened = 0
    for k in range(40):  # 2 s at mid-points of 50 ms steps
        clock.set(t0 + 0.025 + 0.05 * k)
        opened += sc10.light_passes()
    assert opened == 4 and value(sc10, "closed?") == "1"  # 2 cycles x 100 ms
    talk(sc10, "mode=3")  # single: open once for 100 ms
    talk(sc10, "ens")
    assert sc10.light_passes()
    clock.advance(0.15)
    assert not sc10.light_passes() and value(sc10, "ens?") == "1"


def test_sc10_external_trigger_and_gate(sc10, clock):
    talk(sc10, "trig=1")
    talk(sc10, "mode=3")
    talk(sc10, "ens")
    assert not sc10.light_passes()  # waiting for a trigger
    sc10.external_trigger()
    assert sc10.light_passes()
    talk(sc10, "mode=5")  # gate: a mode change stops the sequence (and the enable)
    talk(sc10, "ens")
    assert not sc10.light_passes()
    sc10.gate_input = True
    assert sc10.light_passes()


def test_sc10_interlock(sc10):
    talk(sc10, "ens")
    sc10.trip_interlock()
    assert value(sc10, "interlock?") == "1" and value(sc10, "ens?") == "0"
    assert value(sc10, "closed?") == "1"
    talk(sc10, "ens")  # ignored while tripped
    assert value(sc10, "ens?") == "0"
    sc10.restore_interlock()
    assert value(sc10, "interlock?") == "0" and value(sc10, "ens?") == "0"
    talk(sc10, "ens")
    assert sc10.light_passes()
    sc10.enter_error_state()
    assert not sc10.light_passes()


def test_sc10_without_power_answers_nothing(sc10):
    sc10.power_off()
    assert sc10.receive(b"id?\r") == [] and sc10.poll() == []
    sc10.power_on()
    assert value(sc10, "id?").startswith("THORLABS")


def test_sc10_stored_baud_rate_applies_at_the_next_power_up(sc10):
    talk(sc10, "baud=1")
    assert sc10.baudrate == 9600
    talk(sc10, "save")
    sc10.power_off()
    sc10.power_on()
    assert sc10.baudrate == 115200 and value(sc10, "baud?") == "1"


# --------------------------------------------------------------------------- FW102C


def test_fw102c_power_up_and_identity(fw):
    assert value(fw, "*idn?") == "THORLABS FW102C/FW212C Filter Wheel version 1.07"
    assert [value(fw, k) for k in ("pos?", "pcount?", "speed?", "trig?", "sensors?",
                                   "baud?")] == ["1", "6", "1", "0", "0", "1"]
    assert talk(fw, "id?") == b"id?\r" + NOT_DEFINED  # the SC10's keyword is not the wheel's


def test_fw102c_move_echoes_at_once_and_prompts_on_arrival(fw, clock):
    duration = fw.move_duration_s(1, 4)
    assert duration == pytest.approx(180.0 * 3.0 / 180.0 + SETTLE_S)  # half a turn, high
    assert talk(fw, "pos=4") == b"pos=4\r"
    assert fw.slot_at_beam() is None
    assert talk(fw, "pos?") == b""  # inside pos=: input waits unread
    clock.advance(duration - 0.01)
    assert fw.poll() == []
    clock.advance(0.02)
    assert fw.poll() == [b"> ", b"pos?\r", b"4\r> "]
    assert fw.slot_at_beam() == 4 and fw.moves == 1


def test_fw102c_short_way_round_and_slow_profile(fw, clock):
    assert fw.move_duration_s(1, 6) == fw.move_duration_s(1, 2)
    talk(fw, "speed=0")
    assert fw.move_duration_s(1, 2) == pytest.approx(2 * 60.0 * 3.0 / 180.0 + SETTLE_S)
    assert talk(fw, "pos=1") == b"pos=1\r> "  # already there: at once


@pytest.mark.parametrize("line", ["pos=0", "pos=7", "pos=-1", "pcount=8", "speed=2",
                                  "sensors=3", "pos=1.5"])
def test_fw102c_invalid_arguments(fw, line):
    assert talk(fw, line) == line.encode() + b"\r" + ARG_INVALID


def test_fw102c_twelve_slots(clock):
    fw = Fw102cEmulator("w12", slots=12, start=11, clock=clock)
    assert value(fw, "pcount?") == "12" and value(fw, "pos?") == "11"
    assert fw.move_duration_s(11, 1) == fw.move_duration_s(1, 3)  # 30 degrees a slot
    talk(fw, "pcount=6")
    assert value(fw, "pos?") == "6"


def test_fw102c_silent_jam_and_its_clearing(fw, clock):
    fw.jam("silent", fraction=0.5)
    assert talk(fw, "pos=3") == b"pos=3\r"
    clock.advance(10.0)
    assert fw.poll() == [] and fw.jammed == "silent" and fw.slot_at_beam() is None
    assert talk(fw, "pos?") == b""
    fw.clear_jam()
    clock.advance(fw.move_duration_s(1, 3))
    assert fw.poll() == [b"> ", b"pos?\r", b"3\r> "]


def test_fw102c_power_cycle_ends_a_jam_on_the_nearest_slot(fw, clock):
    fw.jam("silent", fraction=0.6)
    talk(fw, "pos=4")  # three slots forward
    clock.advance(10.0)
    fw.power_off()
    fw.power_on()
    assert value(fw, "pos?") == "3" and fw.slot_at_beam() == 3


def test_fw102c_stall_prompts_but_stands_at_the_slot_it_reached(fw, clock):
    fw.enter_error_state("stall")
    talk(fw, "pos=5")  # 1 -> 5 is two slots backwards: 1, 6, 5
    clock.advance(10.0)
    assert fw.poll() == [b"> "]
    assert value(fw, "pos?") == "6"


def test_fw102c_save_and_power_cycle(fw):
    talk(fw, "speed=0")
    talk(fw, "save")
    talk(fw, "speed=1")
    fw.power_off()
    fw.power_on()
    assert value(fw, "speed?") == "0"


# --------------------------------------------------------------------------- URL and purity


def test_url_options_reach_the_emulators():
    port = serial.serial_for_url("simsc10://opt?mode=3&interlock=1&seed=4", baudrate=9600,
                                 timeout=0.2)
    emu = registry.get("simsc10", "opt")
    assert isinstance(emu, Sc10Emulator) and emu.settings["mode"] == 3 and emu.interlock
    port.write(b"interlock?\r")
    assert port.read_until(b"> ") == b"interlock?\r1\r> "
    port.close()
    port = serial.serial_for_url("simfw102c://opt?slots=12&start=7&wheel_speed=0",
                                 baudrate=115200, timeout=0.2)
    emu = registry.get("simfw102c", "opt")
    assert emu.settings == {**emu.settings, "pcount": 12, "speed": 0} and emu.position == 7
    port.close()
    with pytest.raises(ValueError):
        serial.serial_for_url("simfw102c://bad?colour=red", baudrate=115200)


@pytest.mark.parametrize("url, baud", [("simsc10://b", 115200), ("simfw102c://b", 9600)])
def test_wrong_baud_rate_gets_no_answer(url, baud):
    port = serial.serial_for_url(url, baudrate=baud, timeout=0.05)
    port.write(b"pos?\r")
    assert port.read(20) == b""


def test_emulators_import_nothing_from_drivers():
    root = Path(__file__).resolve().parents[2] / "hw_mocks"
    assert_imports_nothing_forbidden(
        *(root / "firmware" / name for name in ("sc10.py", "fw102c.py", "thorlabs_prompt.py")),
        *(root / "urlhandler" / name for name in
          ("protocol_simsc10.py", "protocol_simfw102c.py", "world_binding.py")))


# --------------------------------------------------------------------------- fuzzing

_SC10_WORDS = ["id?", "ens", "ens?", "closed?", "interlock?", "mode=", "mode?", "rep=",
               "open=", "shut=", "trig=", "savp", "resp", "x"]
_FW_WORDS = ["*idn?", "pos=", "pos?", "pcount=", "pcount?", "speed=", "speed?", "save", "x"]


def _lines(words):
    return st.one_of(
        st.builds(lambda w, v: (w + v).encode("ascii", "replace") + b"\r",
                  st.sampled_from(words),
                  st.one_of(st.just(""), st.integers(-2, 20).map(str), st.text(max_size=4))),
        st.binary(max_size=20),
    )


def _check_frames(frames):
    out = b"".join(frames)
    # every prompt-closed answer is printable apart from CR/LF, whatever came in
    for answer in out.split(b"> ")[:-1]:
        lines = answer.split(b"\r")
        assert all(0x20 <= b < 0x7F or b == 0x0A for line in lines[1:] for b in line), out


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(_lines(_SC10_WORDS), st.floats(0.0, 2.0)), max_size=20))
def test_sc10_arbitrary_input_never_crashes(steps):
    clock = ManualClock()
    emu = Sc10Emulator("fuzz", clock=clock)
    for line, dt in steps:
        _check_frames(emu.receive(line))
        clock.advance(dt)
        _check_frames(emu.poll())
    emu.receive(b"\r")
    assert value(emu, "interlock?") == "0"
    assert value(emu, "ens?") in ("0", "1")


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(_lines(_FW_WORDS), st.floats(0.0, 5.0)), max_size=20))
def test_fw102c_arbitrary_input_never_crashes(steps):
    clock = ManualClock()
    emu = Fw102cEmulator("fuzz", clock=clock)
    for line, dt in steps:
        _check_frames(emu.receive(line))
        clock.advance(dt)
        _check_frames(emu.poll())
    clock.advance(60.0)  # past any move
    emu.poll()
    emu.receive(b"\r")
    count = int(value(emu, "pcount?"))
    assert count in (6, 12) and 1 <= int(value(emu, "pos?")) <= count


# The manuals' keyword tables (SC10 8654-D02 §5; FW102C rev H §5.2.3), "?" included: every
# keyword is implemented and anything else is answered as an undefined command.
SC10_KEYWORDS = ["id?", "ens", "ens?", "rep=n", "rep?", "mode=n", "mode?", "trig=n", "trig?",
                 "xto=n", "xto?", "open=n", "open?", "shut=n", "shut?", "closed?",
                 "interlock?", "baud=n", "baud?", "save", "savp", "resp"]
FW102C_KEYWORDS = ["*idn?", "pos=n", "pos?", "pcount=n", "pcount?", "trig=n", "trig?",
                   "speed=n", "speed?", "sensors=n", "sensors?", "baud=n", "baud?", "save"]


@pytest.mark.parametrize("make, keywords", [
    (lambda clock: Sc10Emulator("kw", clock=clock), SC10_KEYWORDS),
    (lambda clock: Fw102cEmulator("kw", clock=clock), FW102C_KEYWORDS),
])
def test_question_mark_lists_every_keyword_of_the_manual(clock, make, keywords):
    emu = make(clock)
    listed = value(emu, "?").split()
    assert set(keywords) <= set(listed)
    assert talk(emu, "help") == b"help\rCommand error CMD_NOT_DEFINED\n\r> "
