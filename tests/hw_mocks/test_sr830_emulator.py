"""The SR830 firmware emulator on its own: raw bytes in, raw bytes out, manual time.

These tests pin the emulator to the manual's facts and to the physics it claims (output
filter settling, noise bandwidth, DC rejection, overloads) without the driver, so that the
driver's tests really test the driver against an independent reading.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hw_mocks.clock import ManualClock
from hw_mocks.firmware.sr830 import (
    ENBW_TIMES_TAU,
    INPUT_LIMIT_V,
    SENSITIVITIES_V,
    TIME_CONSTANTS_S,
    Sr830Emulator,
)


@pytest.fixture
def clock():
    return ManualClock()


@pytest.fixture
def emu(clock):
    return Sr830Emulator("t", clock=clock, output_interface=0, input_noise_v_per_rthz=0.0)


def ask(emu: Sr830Emulator, request: str) -> list[str]:
    """Send one line; return the reply lines without CR."""
    replies = emu.receive(request.encode("ascii") + b"\n")
    assert all(r.endswith(b"\r") for r in replies)
    return [r[:-1].decode("ascii") for r in replies]


def one(emu: Sr830Emulator, request: str) -> str:
    replies = ask(emu, request)
    assert len(replies) == 1, replies
    return replies[0]


def snap(emu: Sr830Emulator) -> tuple[float, ...]:
    return tuple(float(v) for v in one(emu, "SNAP? 1,2,3,4").split(","))


def step_response(x: float, poles: int) -> float:
    """Fraction of a step reached after x = t/τ by ``poles`` cascaded single poles."""
    return 1.0 - math.exp(-x) * sum(x**k / math.factorial(k) for k in range(poles))


# --------------------------------------------------------------------------- the wire


def test_power_up_identity_and_tables(emu):
    assert one(emu, "*IDN?") == "Stanford_Research_Systems,SR830,s/n00111,ver1.07"
    assert (one(emu, "SENS?"), one(emu, "OFLT?"), one(emu, "OFSL?")) == ("26", "8", "1")
    assert (one(emu, "FMOD?"), one(emu, "FREQ?"), one(emu, "OUTX?")) == ("1", "1000", "0")
    assert one(emu, "*ESR?") == "128"  # PON latched at power-up, cleared by reading
    assert one(emu, "*ESR?") == "0"
    assert len(SENSITIVITIES_V) == 27 and SENSITIVITIES_V[0] == 2e-9
    assert len(TIME_CONSTANTS_S) == 20 and TIME_CONSTANTS_S[-1] == 30e3
    assert emu.baudrate == 9600 and emu.scheme == "simsr830"


def test_syntax_case_spaces_separators_and_terminators(emu):
    assert ask(emu, " sens 20 ; sens ? ; oflt?") == ["20", "8"]
    assert emu.receive(b"SENS 20;SENS?;OFLT?\r") == [b"20\r", b"8\r"]
    assert emu.receive(b"sEnS ? \n") == [b"20\r"]
    assert emu.receive(b"*ID") == [] and emu.receive(b"N?\r") == [
        b"Stanford_Research_Systems,SR830,s/n00111,ver1.07\r"]
    assert emu.receive(b"\r\n\r") == []  # empty lines are nothing


@pytest.mark.parametrize("request_, bit", [
    ("XXXX", 32), ("SENS 27", 16), ("SENS -1", 16), ("SENS 2.5", 16), ("SENS", 32),
    ("SENS abc", 32), ("SNAP? 1", 32), ("SNAP? 0,1", 16), ("OUTP? 5", 16), ("OFSL 4", 16),
    ("*IDN", 32), ("FREQ 200000", 16), ("PHAS 800", 16), ("SNAP 1,2", 32),
    ("SENS 1E999", 16), ("FREQ 9E999", 16),  # beyond a double: refused, not a crash
])
def test_errors_latch_cmd_or_exe_and_failed_queries_answer_nothing(emu, request_, bit):
    one(emu, "*ESR?")
    assert ask(emu, request_) == []
    assert one(emu, "*ESR?") == str(bit)
    assert one(emu, "*ESR?") == "0"


def test_frequency_and_long_time_constants_depend_on_the_reference(emu):
    one(emu, "*ESR?")  # clear PON
    ask(emu, "FREQ 137.5")
    assert one(emu, "FREQ?") == "137.5"
    ask(emu, "OFLT 14")  # 100 s allowed below 200 Hz
    assert one(emu, "OFLT?") == "14"
    ask(emu, "OFLT 8;FREQ 1000;OFLT 14")  # not above 200 Hz
    assert one(emu, "OFLT?") == "8" and one(emu, "*ESR?") == "16"
    ask(emu, "FMOD 0")
    ask(emu, "FREQ 500")  # FREQ sets only the internal oscillator
    assert one(emu, "*ESR?") == "16"
    assert one(emu, "FREQ?") == "0"  # nothing at REF IN
    emu.reference_input_hz = 137.0
    assert one(emu, "FREQ?") == "137"


def test_output_interface_gpib_sends_nothing_on_this_line(emu):
    ask(emu, "OUTX 1")
    assert ask(emu, "*IDN?") == [] and emu.replies_to_gpib == 1
    assert ask(emu, "OUTX 0;*IDN?")[0].startswith("Stanford")
    default = Sr830Emulator("g", clock=ManualClock())
    assert default.outx == 1 and default.receive(b"*IDN?\n") == []


def test_status_registers_read_clear_by_bit_and_enable(emu, clock):
    emu.enter_error_state("6")
    emu.enter_error_state("2")
    assert one(emu, "ERRS? 6") == "1"
    assert one(emu, "ERRS?") == "4"  # bit 6 cleared by its own read
    one(emu, "*ESR?")
    ask(emu, "XXXX")
    ask(emu, "*ESE 32")
    assert one(emu, "*ESE?") == "32" and one(emu, "*ESE? 5") == "1"
    assert int(one(emu, "*STB?")) & 0x22 == 0x22  # IFC and ESB
    ask(emu, "*CLS")
    assert one(emu, "*STB?") == "3" and one(emu, "*ESR?") == "0"
    ask(emu, "ERRE 0,1")
    assert one(emu, "ERRE?") == "1"
    with pytest.raises(ValueError):
        emu.enter_error_state("9")


def test_power_cycle_restores_standard_settings_and_latches_pon(emu):
    ask(emu, "SENS 3;OFLT 2;OFSL 3")
    one(emu, "*ESR?")
    emu.enter_error_state("power_cycle")
    assert (one(emu, "SENS?"), one(emu, "OFLT?"), one(emu, "OFSL?")) == ("26", "8", "1")
    assert one(emu, "*ESR?") == "128"
    assert one(emu, "OUTX?") == "0"  # the interface setting is retained


def test_auto_gain_keeps_the_interpreter_busy_and_queues_commands(emu, clock):
    ask(emu, "OFLT 4")  # 1 ms
    emu.set_input(3e-3)
    clock.advance(0.1)
    assert ask(emu, "AGAN") == []
    assert emu.is_busy()
    assert emu.receive(b"*STB? 1\n") == []  # queued until the auto gain is over
    assert emu.poll() == []
    clock.advance(0.05)
    assert emu.poll() == [b"1\r"]
    assert one(emu, "SENS?") == str(SENSITIVITIES_V.index(5e-3))  # R <= 0.8 FS
    ask(emu, "OFLT 11")  # 3 s: AGAN does nothing
    ask(emu, "AGAN")
    assert not emu.is_busy() and one(emu, "SENS?") == "19"


def test_rest_of_a_line_after_agan_waits(emu, clock):
    ask(emu, "OFLT 4")
    assert emu.receive(b"AGAN;SENS?\n") == []  # no signal: the smallest full scale
    clock.advance(1.0)
    assert emu.poll() == [b"0\r"]


# --------------------------------------------------------------------------- physics


@pytest.mark.parametrize("ofsl, poles", [(0, 1), (1, 2), (2, 3), (3, 4)])
def test_output_follows_the_cascaded_exponential(emu, clock, ofsl, poles):
    ask(emu, f"OFLT 6;OFSL {ofsl};SENS 26")  # 10 ms
    tau = 0.01
    emu.set_input(0.5)  # a step at t0 (the filter was at 0)
    for x in (0.5, 1.0, 2.0, 4.0, 8.0):
        clock.set(tau * x)
        assert snap(emu)[0] == pytest.approx(0.5 * step_response(x, poles), rel=1e-4,
                                             abs=2e-6)


@pytest.mark.parametrize("ofsl, slope, reached", [
    (0, 6, 0.9933), (1, 12, 0.9927), (2, 18, 0.9938), (3, 24, 0.9897)])
def test_the_manuals_wait_times_reach_99_percent(emu, clock, ofsl, slope, reached):
    """Manual p. 3-25: wait 5, 7, 9, 10 τ "to reach 99 %". The cascade reaches 99.3, 99.3,
    99.4 and 98.97 %: the 24 dB/oct entry is rounded (99 % needs 10.05 τ)."""
    waits = {6: 5.0, 12: 7.0, 18: 9.0, 24: 10.0}
    ask(emu, f"OFLT 6;OFSL {ofsl}")
    emu.set_input(0.5)
    clock.set(0.01 * waits[slope])
    assert snap(emu)[0] / 0.5 == pytest.approx(reached, abs=1e-4)
    assert step_response(waits[slope] - 1.0, ofsl + 1) < 0.99  # one τ less is too short


def test_settling_with_noise_stays_within_the_noise(clock):
    emu = Sr830Emulator("n", clock=clock, output_interface=0, seed=5,
                        input_noise_v_per_rthz=1e-6)
    ask(emu, "OFLT 6;OFSL 3;SENS 20")
    tau, density = 0.01, 1e-6
    sigma = density * math.sqrt(ENBW_TIMES_TAU[4] / tau)
    emu.set_input(5e-3)
    for x in (1.0, 3.0, 10.0):
        clock.set(tau * x)
        expected = 5e-3 * step_response(x, 4)
        assert abs(snap(emu)[0] - expected) < 5 * sigma


def _x_samples(emu: Sr830Emulator, clock: ManualClock, tau: float, n: int) -> np.ndarray:
    samples = []
    for _ in range(n):
        clock.advance(20 * tau)  # far apart: independent samples
        samples.append(emu.outputs()[0])
    return np.array(samples)


@pytest.mark.parametrize("ofsl", [0, 1, 3])
def test_noise_scales_with_the_equivalent_noise_bandwidth(clock, ofsl):
    """σ_X = density·√ENBW with ENBW = 1/(4τ), 1/(8τ), 5/(64τ) (manual p. 3-25).

    With N independent samples the sample standard deviation has a relative spread of
    about 1/√(2N); the tolerance is 4 of those.
    """
    n = 400
    tolerance = 4 / math.sqrt(2 * n)
    density = 1e-6
    for oflt, tau in ((4, 1e-3), (8, 0.1)):
        emu = Sr830Emulator("n", clock=clock, output_interface=0, seed=11 + oflt,
                            input_noise_v_per_rthz=density)
        ask(emu, f"OFLT {oflt};OFSL {ofsl}")
        samples = _x_samples(emu, clock, tau, n)
        expected = density * math.sqrt(ENBW_TIMES_TAU[ofsl + 1] / tau)
        assert samples.std(ddof=1) == pytest.approx(expected, rel=tolerance)
        assert abs(samples.mean()) < 4 * expected / math.sqrt(n)


def test_dc_is_rejected_and_only_the_locked_component_reads(emu, clock):
    ask(emu, "OFLT 6;SENS 17")  # 1 mV full scale
    emu.set_input(0.0, dc_v=0.5)  # a large DC part alone
    clock.advance(1.0)
    assert snap(emu)[2] == pytest.approx(0.0, abs=1e-12)
    assert one(emu, "LIAS?") == "0"  # AC coupling: DC does not overload the input
    emu.set_input(0.4e-3, dc_v=0.5, phase_deg=30.0)
    clock.advance(1.0)
    x, _y, r, theta = snap(emu)
    assert r == pytest.approx(0.4e-3, rel=1e-5) and theta == pytest.approx(30.0, abs=1e-3)
    assert x == pytest.approx(0.4e-3 * math.cos(math.radians(30)), rel=1e-5)
    ask(emu, "PHAS 30")
    clock.advance(1.0)
    assert snap(emu)[3] == pytest.approx(0.0, abs=1e-3)
    emu.set_input(0.4e-3, frequency_hz=1234.0)  # modulated at another frequency
    clock.advance(1.0)
    assert snap(emu)[2] == pytest.approx(0.0, abs=1e-12)
    ask(emu, "ICPL 1")  # DC coupling: now the DC counts for the input's range
    emu.set_input(0.0, dc_v=2.0)
    clock.advance(0.1)
    assert int(one(emu, "LIAS?")) & 1


def test_output_overload_latches_and_clips(emu, clock):
    ask(emu, "OFLT 6;SENS 17")
    emu.set_input(5e-3)
    clock.advance(1.0)
    x, _y, r, _theta = snap(emu)
    assert x == pytest.approx(1.09e-3) and r == pytest.approx(1.09e-3)
    assert one(emu, "LIAS? 2") == "1"
    assert one(emu, "LIAS? 2") == "1"  # read and cleared, latched again: still overloaded
    ask(emu, "SENS 22")
    clock.advance(0.01)
    assert snap(emu)[2] == pytest.approx(5e-3, rel=1e-5)
    assert one(emu, "LIAS?") == "4"  # latched before the range change, read once
    assert one(emu, "LIAS?") == "0"
    emu.set_input(2.0)  # above the input range
    clock.advance(0.01)
    assert int(one(emu, "LIAS?")) & 1 and 2.0 * math.sqrt(2) > INPUT_LIMIT_V


def test_external_reference_unlock(emu, clock):
    ask(emu, "FMOD 0")
    emu.set_input(1e-3)
    clock.advance(1.0)
    assert snap(emu)[2] == 0.0 and int(one(emu, "LIAS?")) & 8
    emu.reference_input_hz = 137.0
    clock.advance(5.0)
    assert snap(emu)[2] == pytest.approx(1e-3) and one(emu, "LIAS?") == "0"


def test_more_poles_start_from_the_last_stage(emu, clock):
    ask(emu, "OFLT 6;OFSL 0")
    emu.set_input(0.1)
    clock.advance(1.0)
    ask(emu, "OFSL 3")
    assert snap(emu)[0] == pytest.approx(0.1, rel=1e-6)  # no jump when poles are added


# --------------------------------------------------------------------------- fuzzing

_WORDS = ["*IDN?", "*ESR?", "*STB?", "*CLS", "*RST", "ERRS?", "LIAS?", "SENS", "SENS?",
          "OFLT", "OFLT?", "OFSL", "FMOD", "FREQ", "FREQ?", "PHAS", "SNAP?", "OUTP?", "AGAN",
          "OUTX", "ICPL", "XXXX", "*ESE", "ERRE", "LIAE"]
_lines = st.one_of(
    st.builds(lambda w, a: (w + " " + a).encode("ascii") + b"\n", st.sampled_from(_WORDS),
              st.text(alphabet="0123456789.,-eE ", max_size=12)),
    st.binary(max_size=40),
)


@settings(max_examples=200)
@given(st.lists(_lines, max_size=8))
def test_arbitrary_bytes_never_break_the_emulator(chunks):
    clock = ManualClock()
    emu = Sr830Emulator("f", clock=clock, output_interface=0)
    for chunk in chunks:
        for reply in emu.receive(chunk):
            assert reply.endswith(b"\r") and b"\r" not in reply[:-1]
        clock.advance(0.2)
        emu.poll()
    assert 0 <= emu.sens < 27 and 0 <= emu.oflt < 20 and 0 <= emu.ofsl < 4
    # Queued lines may hold further AGANs, each busy in turn: let them all run first.
    for _ in range(sum(len(c) for c in chunks) // 4 + 2):  # at most one AGAN per 4 bytes
        clock.advance(100.0)
        emu.poll()
        if not emu.is_busy():
            break
    assert not emu.is_busy()
    assert emu.receive(b"\nOUTX 0;*IDN?\n")[-1].startswith(b"Stanford")
