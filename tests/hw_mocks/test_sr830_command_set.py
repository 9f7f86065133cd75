"""The SR830 emulator's remote command set beyond the measurement core (manual ch. 5):
harmonics, the reference trigger and sine output, input configuration, displays and
ratios, offsets, aux I/O, setups, status registers and the clock-driven data buffer.

Raw bytes in and out, time held by a :class:`~hw_mocks.clock.ManualClock`.
"""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hw_mocks.clock import ManualClock
from hw_mocks.firmware.sr830 import AUX_IN_STEP_V, InputSignal, Sr830Emulator
from hw_mocks.firmware.sr830_storage import BUFFER_POINTS, SAMPLE_RATES_HZ
from tests.hw_mocks.test_sr830_emulator import ask, one


@pytest.fixture
def clock():
    return ManualClock()


@pytest.fixture
def emu(clock):
    emu = Sr830Emulator("t", clock=clock, output_interface=0, input_noise_v_per_rthz=0.0)
    emu.receive(b"*ESR?\n")  # clear PON
    return emu


def esr(emu) -> int:
    return int(one(emu, "*ESR?"))


#: (setting, a legal value, its read-back, the query) for the plain index settings.
ROUND_TRIPS = [
    ("HARM 7", "HARM?", "7"), ("RSLP 2", "RSLP?", "2"), ("ISRC 3", "ISRC?", "3"),
    ("IGND 1", "IGND?", "1"), ("ILIN 3", "ILIN?", "3"), ("RMOD 0", "RMOD?", "0"),
    ("SYNC 1", "SYNC?", "1"), ("SLVL 0.1234", "SLVL?", "0.124"),
    ("DDEF 1,1,2", "DDEF? 1", "1,2"), ("DDEF 2,1,0", "DDEF? 2", "1,0"),
    ("FPOP 2,1", "FPOP? 2", "1"), ("OEXP 3,-12.345,2", "OEXP? 3", "-12.35,2"),
    ("AUXV 4,-3.2104", "AUXV? 4", "-3.21"), ("OVRM 1", "OVRM?", "1"),
    ("LOCL 2", "LOCL?", "2"), ("KCLK 0", "KCLK?", "0"), ("ALRM 0", "ALRM?", "0"),
    ("SRAT 13", "SRAT?", "13"), ("SEND 0", "SEND?", "0"), ("TSTR 1", "TSTR?", "1"),
    ("FAST 2", "FAST?", "2"), ("*PSC 0", "*PSC?", "0"),
]


@pytest.mark.parametrize("setting, query, expected", ROUND_TRIPS)
def test_settings_round_trip(emu, setting, query, expected):
    assert ask(emu, setting) == []
    assert one(emu, query) == expected
    assert esr(emu) == 0


@pytest.mark.parametrize("request_, bit", [
    ("HARM 0", 16), ("HARM 20000", 16), ("HARM 103", 16),  # 103 kHz at 1 kHz
    ("RSLP 3", 16), ("ISRC 4", 16), ("ILIN -1", 16), ("SLVL 0.001", 16), ("SLVL 5.1", 16),
    ("DDEF 3,0,0", 16), ("DDEF 1,5,0", 16), ("DDEF 1,0", 32), ("OEXP 1,106,0", 16),
    ("AUXV 1,11", 16), ("AUXV 0,1", 16), ("OAUX? 5", 16), ("OUTR? 3", 16),
    ("RSET 4", 16), ("SSET 10", 16), ("SRAT 15", 16), ("TRCA? 1,0,1", 16),
    ("TRCB? 3,0,1", 16), ("SPTS", 32), ("STRT?", 32), ("WXYZ", 32), ("HARM? 1", 32),
])
def test_refused_commands_latch_exe_or_cmd(emu, request_, bit):
    assert ask(emu, request_) == []
    assert esr(emu) == bit


def test_unknown_command_sets_cmd_and_the_status_byte_summary(emu):
    ask(emu, "*ESE 32;*SRE 32")
    ask(emu, "BOGS 1")
    assert int(one(emu, "*STB?")) & 0x60 == 0x60  # ESB and SRQ (MSS)
    assert one(emu, "*ESR? 5") == "1" and one(emu, "*STB? 5") == "0"


def test_harmonic_limits_the_frequency_and_detects_the_nth_component(emu, clock):
    ask(emu, "HARM 100")  # 100 kHz: allowed
    assert ask(emu, "FREQ 1100") == [] and esr(emu) == 16  # 110 kHz refused
    ask(emu, "FREQ 500;HARM 2;OFLT 4")
    emu.set_input(2e-3, phase_deg=20.0)
    emu.input_signal = lambda: InputSignal(2e-3, 20.0, harmonics=((2, 5e-4, 45.0),))
    clock.advance(1.0)
    _, _, r, theta = (float(v) for v in one(emu, "SNAP? 1,2,3,4").split(","))
    assert r == pytest.approx(5e-4, rel=1e-9) and theta == pytest.approx(45.0, abs=1e-6)
    ask(emu, "PHAS 45")  # the phase shifts the harmonic's reference
    clock.advance(1.0)
    assert float(one(emu, "OUTP? 2")) == pytest.approx(0.0, abs=1e-12)


def test_range_and_time_constant_change_bits(emu):
    ask(emu, "FREQ 100;LIAS?")
    ask(emu, "OFLT 15")  # 300 s at 100 Hz: allowed
    one(emu, "LIAS?")
    ask(emu, "HARM 3")  # 300 Hz detection: crosses 200 Hz, τ cut to 30 s
    assert one(emu, "LIAS?") == str(0x10 | 0x20)
    assert one(emu, "OFLT?") == "13"


def test_displays_ratios_offsets_and_aux(emu, clock):
    emu.aux_inputs_v = [2.0, -0.5, 4.0, 0.0]
    emu.set_input(0.1, phase_deg=90.0)  # X = 0, Y = 0.1 V
    ask(emu, "OFLT 4")
    clock.advance(1.0)
    # the inputs read through the 16-bit A/D: each within half a step of its voltage
    assert float(one(emu, "OAUX? 3")) == pytest.approx(4.0, abs=AUX_IN_STEP_V / 2)
    assert [float(v) for v in one(emu, "SNAP? 5,6,7,8").split(",")] == pytest.approx(
        [2.0, -0.5, 4.0, 0.0], abs=AUX_IN_STEP_V / 2)
    ask(emu, "DDEF 1,1,1")  # CH1 = R / Aux In 1
    ask(emu, "DDEF 2,1,0")  # CH2 = θ
    ch1, ch2 = (float(v) for v in one(emu, "SNAP? 10,11").split(","))
    assert ch1 == pytest.approx(0.05, rel=1e-4) and ch2 == pytest.approx(90.0)
    assert float(one(emu, "OUTR? 1")) == pytest.approx(0.05, rel=1e-4)  # Aux In 1 as quantised
    ask(emu, "AOFF 2")  # Y offset to zero: 10 % of the 1 V full scale
    assert one(emu, "OEXP? 2") == "10.00,0"
    assert float(one(emu, "OUTP? 2")) == pytest.approx(0.0, abs=1e-9)
    assert float(one(emu, "OUTP? 4")) == pytest.approx(90.0)  # θ ignores offsets
    ask(emu, "APHS")
    assert float(one(emu, "PHAS?")) == pytest.approx(90.0)


def test_setups_save_and_recall_and_rst_restores_standard_settings(emu):
    ask(emu, "HARM 3;SENS 10;ISRC 1;SSET 4;*RST")
    assert (one(emu, "HARM?"), one(emu, "SENS?"), one(emu, "ISRC?")) == ("1", "26", "0")
    ask(emu, "RSET 4")
    assert (one(emu, "HARM?"), one(emu, "SENS?"), one(emu, "ISRC?")) == ("3", "10", "1")


def test_power_on_status_clear(emu):
    ask(emu, "*ESE 36;*PSC 0")
    emu.enter_error_state("power_cycle")
    assert one(emu, "*ESE?") == "36"  # kept with *PSC 0
    ask(emu, "*PSC 1")
    emu.enter_error_state("power_cycle")
    assert one(emu, "*ESE?") == "0"


def test_buffer_runs_on_the_emulated_clock(emu, clock):
    emu.set_input(0.25)
    ask(emu, "OFLT 0")  # 10 µs: settled at once
    clock.advance(0.01)
    ask(emu, "SRAT 8;SEND 0;STRT")  # 16 Hz, one shot
    assert int(one(emu, "*STB?")) & 0x01 == 0  # SCN clear: a scan is in progress
    clock.advance(1.0)
    assert one(emu, "SPTS?") == "17"
    ask(emu, "PAUS")
    clock.advance(10.0)
    assert one(emu, "SPTS?") == "17" and int(one(emu, "*STB?")) & 0x01 == 1
    ask(emu, "STRT")  # resumes: a point at once, then 16 Hz
    clock.advance(0.5)
    assert one(emu, "SPTS?") == "26"
    text = one(emu, "TRCA? 1,0,3")
    assert text == "0.25,0.25,0.25,"  # every point followed by a comma
    raw = emu.receive(b"TRCB? 2,24,2\n")
    assert raw == [struct.pack("<2f", 0.0, 0.0)]  # no terminator
    ask(emu, "REST")
    assert one(emu, "SPTS?") == "0"


def test_one_shot_stops_when_full_and_loop_keeps_the_newest(emu, clock):
    rate = SAMPLE_RATES_HZ[13]
    seconds = (BUFFER_POINTS + 10) / rate
    ask(emu, "SRAT 13;SEND 0;STRT")
    clock.advance(seconds)
    assert one(emu, "SPTS?") == str(BUFFER_POINTS)
    assert int(one(emu, "*STB?")) & 0x01 == 1  # stopped
    ask(emu, "SEND 1")  # a change of mode resets
    assert one(emu, "SPTS?") == "0"
    ask(emu, "STRT")
    clock.advance(3 * seconds)
    assert one(emu, "SPTS?") == str(BUFFER_POINTS)
    assert int(one(emu, "*STB?")) & 0x01 == 0  # still running


def test_trigger_start_and_trigger_rate(emu, clock):
    ask(emu, "SRAT 14;TSTR 1;LIAS?")
    ask(emu, "TRIG")  # starts the scan and stores a point
    ask(emu, "TRIG;TRIG")
    clock.advance(100.0)
    assert one(emu, "SPTS?") == "3"
    assert one(emu, "LIAS? 6") == "1"
    ask(emu, "STRD")  # restart 0.5 s later, at 1 Hz
    ask(emu, "SRAT 4;STRD")
    clock.advance(0.4)
    assert one(emu, "SPTS?") == "0"
    clock.advance(2.1)
    assert one(emu, "SPTS?") == "3"  # t = 0.5, 1.5, 2.5


def test_non_normalised_trace_format(emu):
    emu.storage.points.extend([(1.5, -0.003), (0.0, 2e-9)])
    raw = emu.receive(b"TRCL? 1,0,2\n")[0] + emu.receive(b"TRCL? 2,0,2\n")[0]
    values = [m * 2.0 ** (e - 124) for m, e in struct.iter_unpack("<hh", raw)]
    assert values[:2] == [1.5, 0.0]
    assert values[2] == pytest.approx(-0.003, rel=1e-4)
    assert values[3] == pytest.approx(2e-9, rel=1e-4)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from(
    ["HARM", "RSLP", "ISRC", "IGND", "ILIN", "SLVL", "DDEF", "OEXP", "AUXV", "OAUX", "SRAT",
     "SEND", "TRCA", "TRCB", "TRCL", "SPTS", "STRT", "PAUS", "REST", "TRIG", "SSET",
     "RSET", "OUTR", "FPOP", "AOFF", "APHS", "ARSV", "*PSC", "LOCL", "STRD"]),
    min_size=1, max_size=6),
    st.lists(st.one_of(st.integers(-3, 20000), st.floats(-200, 200), st.just("")),
             max_size=4), st.booleans())
def test_any_command_and_arguments_leave_the_emulator_consistent(names, raw_args, query):
    clock = ManualClock()
    emu = Sr830Emulator("h", clock=clock, output_interface=0, input_noise_v_per_rthz=0.0)
    args = ",".join(str(a) for a in raw_args)
    line = ";".join(f"{n}{'?' if query else ''} {args}" for n in names)
    for reply in emu.receive(line.encode("ascii") + b"\n"):
        assert isinstance(reply, bytes)
    clock.advance(3.0)
    # Still answering, with settings inside their tables.
    assert one(emu, "*IDN?").startswith("Stanford_Research_Systems")
    assert 1 <= int(one(emu, "HARM?")) <= 19999
    assert int(one(emu, "HARM?")) * float(one(emu, "FREQ?")) <= 102000.0
    assert 0 <= int(one(emu, "SPTS?")) <= BUFFER_POINTS
    assert math.isfinite(float(one(emu, "OUTP? 1")))


def test_aux_inputs_read_through_a_16_bit_converter(emu):
    """SR830 manual, specifications: Aux In ±10.5 V, 16 bits (21 V / 2¹⁶ ≈ 1/3 mV). A
    steady voltage between two codes reads the nearest code every time (a mean of
    readings keeps the rounding); beyond the range it reads the limit."""
    assert 3.1e-4 < AUX_IN_STEP_V < 3.4e-4  # the manual's "1/3 mV"
    volts = 1234.4 * AUX_IN_STEP_V  # 0.4 of a step above a code
    emu.aux_inputs_v = [volts, 11.0, -11.0, 0.0]
    first = {float(one(emu, "OAUX? 1")) for _ in range(5)}
    assert len(first) == 1
    code = first.pop()
    assert code == pytest.approx(1234 * AUX_IN_STEP_V, abs=2e-6)  # six digits
    assert volts - code == pytest.approx(0.4 * AUX_IN_STEP_V, abs=2e-6)
    assert float(one(emu, "OAUX? 2")) == pytest.approx(10.5, abs=AUX_IN_STEP_V)
    assert float(one(emu, "SNAP? 5,7").split(",")[1]) == pytest.approx(-10.5,
                                                                        abs=AUX_IN_STEP_V)
