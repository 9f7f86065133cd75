"""The SMC100 firmware emulator on its own: raw bytes in, raw bytes out, manual time.

These tests pin the emulator to the facts of the SMC100CC/PP user's manual without the driver, so
that the driver's tests really test the driver against an independent reading.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from hw_mocks import registry
from hw_mocks.clock import ManualClock
from hw_mocks.firmware.smc100 import STAGE_MODELS, Smc100Emulator
from hw_mocks.motion import TrapezoidalProfile
from tests.hw_mocks.purity import assert_imports_nothing_forbidden


@pytest.fixture
def clock():
    return ManualClock()


@pytest.fixture
def emu(clock):
    return Smc100Emulator("t", clock=clock)


def ask(emu: Smc100Emulator, request: str) -> str | None:
    """Send one request; return the reply line without CR LF, or None if unanswered."""
    replies = emu.receive(request.encode("ascii") + b"\r\n")
    assert len(replies) <= 1
    if not replies:
        return None
    assert replies[0].endswith(b"\r\n")
    return replies[0][:-2].decode("ascii")


def te(emu) -> str:
    return ask(emu, "1TE")[3:]


def state(emu) -> str:
    return ask(emu, "1TS")[-2:]


def home(emu, clock) -> None:
    assert ask(emu, "1OR") is None
    assert te(emu) == "@"
    clock.advance(60.0)
    assert state(emu) == "32"


# --------------------------------------------------------------------------- basics


def test_power_up_identity_and_queries(emu):
    assert ask(emu, "1TS") == "1TS00000A"
    assert ask(emu, "1TE") == "1TE@"
    assert ask(emu, "1TP") == "1TP0.000000"  # counter reads 0 wherever the stage is
    assert emu.stage.physical_position() == pytest.approx(37.0)
    assert ask(emu, "1ID?").startswith("1IDURS100BCC_")
    assert ask(emu, "1VE").startswith("1VE SMC_CC")
    assert ask(emu, "1VA?") == "1VA20.000000"
    assert ask(emu, "1SL?") == "1SL-170.000000"
    assert emu.baudrate == 57600 and emu.scheme == "simsmc"


def test_te_latch_keeps_last_error_until_read(emu):
    assert ask(emu, "1PA5") is None
    assert ask(emu, "1TS") == "1TS00000A"  # a successful query does not clear it
    assert ask(emu, "1XX") is None           # unknown command overwrites it
    assert te(emu) == "A"
    assert te(emu) == "@"                    # reading cleared it


@pytest.mark.parametrize("request_, letter", [
    ("1PA5", "H"), ("1PR1", "H"), ("1MM0", "H"), ("1XX", "A"), ("1TP5", "C"),
    ("1VA0", "C"), ("1VA-3", "C"), ("1VA", "C"), ("1VAabc", "C"), ("1VA999", "C"),
    ("1SL5", "C"), ("1PW7", "C"), ("1ID", "A"),
])
def test_refusals_in_not_referenced(emu, request_, letter):
    assert ask(emu, request_) is None
    assert te(emu) == letter


def test_addressing(emu):
    assert ask(emu, "2TS") is None   # another controller on the chain: silence
    assert te(emu) == "@"
    assert ask(emu, "40TS") is None  # not an address at all
    assert te(emu) == "B"
    assert emu.receive(b"TS\r\n") == [] and te(emu) == "A"
    assert emu.receive(b"\x13\x111TS\r\n") == [b"1TS00000A\r\n"]  # XON/XOFF ignored
    assert emu.receive(b"1T") == [] and emu.receive(b"S\r\n1TE\r\n") == [
        b"1TS00000A\r\n", b"1TE@\r\n"]  # split and joined requests
    two = Smc100Emulator("a12", address=12, clock=ManualClock())
    assert ask(two, "12TS") == "12TS00000A"
    with pytest.raises(ValueError):
        Smc100Emulator("bad", address=0)
    with pytest.raises(ValueError):
        Smc100Emulator("bad", kind="tilt")


# --------------------------------------------------------------------------- homing


def test_homing_runs_to_the_switch_and_zeroes_the_counter(emu, clock):
    assert ask(emu, "1OR") is None and te(emu) == "@"
    assert state(emu) == "1E"
    run = 37.0 / STAGE_MODELS["rotary"].home_velocity
    clock.advance(run / 2)
    assert state(emu) == "1E"
    assert emu.stage.physical_position() == pytest.approx(37.0 / 2)
    assert ask(emu, "1OR") is None and te(emu) == "E"  # already homing
    assert ask(emu, "1PA1") is None and te(emu) == "L"
    clock.advance(run / 2 + 1e-9)
    assert state(emu) == "32"
    assert ask(emu, "1TP") == "1TP0.000000"
    assert emu.stage.physical_position() == pytest.approx(0.0)
    assert ask(emu, "1OR") is None and te(emu) == "K"  # only in NOT REFERENCED


def test_stop_during_homing_leaves_not_referenced(emu, clock):
    ask(emu, "1OR")
    clock.advance(1.0)
    assert ask(emu, "1ST") is None and te(emu) == "@"
    assert state(emu) == "0B"
    position = emu.stage.physical_position()
    clock.advance(10.0)
    assert emu.stage.physical_position() == position


def test_homing_time_out(emu, clock):
    ask(emu, "1OT1")
    assert ask(emu, "1OT?") == "1OT1.000000"
    ask(emu, "1OR")  # 37 deg at 10 deg/s needs 3.7 s
    clock.advance(10.0)  # a late look must still see the time-out, not a finished run
    assert ask(emu, "1TS") == "1TS00400B"
    assert emu.stage.physical_position() == pytest.approx(27.0)
    assert not emu.stage.homed
    ask(emu, "1OT100")
    ask(emu, "1OR")  # clears the bit and starts again
    assert ask(emu, "1TS") == "1TS00001E"
    clock.advance(10.0)
    assert state(emu) == "32"


# --------------------------------------------------------------------------- motion


def test_absolute_move_follows_the_trapezoid(emu, clock):
    home(emu, clock)
    ask(emu, "1VA10")
    ask(emu, "1AC20")
    t0 = clock.now()
    assert ask(emu, "1PA30") is None and te(emu) == "@"
    profile = TrapezoidalProfile(0.0, 30.0, 10.0, 20.0, t0)
    assert profile.duration == pytest.approx(30 / 10 + 10 / 20)
    for t in (0.25, 1.0, 2.0, 3.2):
        clock.set(t0 + t)
        assert state(emu) == "28"
        tp = float(ask(emu, "1TP")[3:])
        assert tp == pytest.approx(profile.position(t0 + t), abs=1e-6)
        assert float(ask(emu, "1TH")[3:]) == 30.0
    clock.set(t0 + profile.duration + 1e-6)
    assert ask(emu, "1TP") == "1TP30.000000"
    assert ask(emu, "1TS") == "1TS000028"  # settling into the in-position window
    clock.set(t0 + profile.duration + emu.settle_s)
    assert ask(emu, "1TS") == "1TS000033"


def test_relative_move_counts_from_the_setpoint(emu, clock):
    home(emu, clock)
    ask(emu, "1PA10")
    clock.advance(30)
    ask(emu, "1PR-2.5")
    clock.advance(30)
    assert ask(emu, "1TP") == "1TP7.500000"
    assert ask(emu, "1PR1e1") is None and te(emu) == "@"
    clock.advance(30)
    assert ask(emu, "1TP") == "1TP17.500000"


def test_software_limits_and_moving_refusals(emu, clock):
    home(emu, clock)
    assert ask(emu, "1PA171") is None and te(emu) == "G"
    assert ask(emu, "1PR-171") is None and te(emu) == "G"
    assert state(emu) == "32"
    ask(emu, "1PA100")
    assert ask(emu, "1PA1") is None and te(emu) == "M"
    assert ask(emu, "1VA5") is None and te(emu) == "M"
    assert ask(emu, "1MM0") is None and te(emu) == "M"
    assert ask(emu, "1PA") is None  # no value
    assert te(emu) == "M"  # refused for the state before the argument is looked at


def test_stop_decelerates_at_the_configured_acceleration(emu, clock):
    home(emu, clock)
    ask(emu, "1PA150")
    clock.advance(3.0)  # cruising at 20 deg/s
    at_stop = float(ask(emu, "1TP")[3:])
    ask(emu, "1ST")
    assert te(emu) == "@"
    assert state(emu) == "28"  # still braking
    clock.advance(5.0)
    assert state(emu) == "33"
    braking = 20.0**2 / (2 * 80.0)
    assert float(ask(emu, "1TP")[3:]) == pytest.approx(at_stop + braking, abs=1e-6)
    assert float(ask(emu, "1TH")[3:]) == pytest.approx(at_stop + braking, abs=1e-6)
    assert ask(emu, "1ST") is None and te(emu) == "@"  # nothing to stop: accepted


def test_disable_enable_cycle(emu, clock):
    home(emu, clock)
    ask(emu, "1MM0")
    assert state(emu) == "3C"
    assert ask(emu, "1PA1") is None and te(emu) == "J"
    ask(emu, "1MM1")
    assert state(emu) == "34"
    ask(emu, "1PA1")
    clock.advance(5)
    assert ask(emu, "1TP") == "1TP1.000000"


def test_limit_switch_stops_and_disables(emu, clock):
    home(emu, clock)
    emu.stage.travel = (-5.0, 5.0)
    ask(emu, "1PA8")
    clock.advance(10)
    assert ask(emu, "1TS") == "1TS00023D"  # positive end of run, DISABLE from MOVING
    assert ask(emu, "1TP") == "1TP5.000000"
    ask(emu, "1MM1")
    ask(emu, "1PA0")
    clock.advance(10)
    assert ask(emu, "1TS") == "1TS000033"


def test_injected_error_state_disables_and_mm1_clears(emu, clock):
    home(emu, clock)
    ask(emu, "1PA100")
    clock.advance(1.0)
    emu.enter_error_state("0020")
    assert ask(emu, "1TS") == "1TS00203D"
    position = emu.stage.physical_position()
    clock.advance(5.0)
    assert emu.stage.physical_position() == position  # the motor is off
    ask(emu, "1MM1")
    assert ask(emu, "1TS") == "1TS000034"
    emu.enter_error_state(None)  # default: following error, from READY
    assert ask(emu, "1TS") == "1TS00203C"
    assert emu.unsolicited_frame() == b"2TS000033\r\n"


# --------------------------------------------------------------------------- busy windows


def test_reset_is_deaf_then_not_referenced_with_stored_parameters(emu, clock):
    home(emu, clock)
    ask(emu, "1VA5")
    ask(emu, "1PA10")
    clock.advance(10)
    assert ask(emu, "1RS") is None
    assert emu.is_busy()
    assert ask(emu, "1TS") is None and ask(emu, "1TE") is None
    assert emu.ignored == [b"1TS", b"1TE"]
    clock.advance(emu.reset_busy_s)
    assert ask(emu, "1TS") == "1TS00000A"
    assert ask(emu, "1TP") == "1TP0.000000"  # reference lost: counter restarts
    assert emu.stage.physical_position() == pytest.approx(10.0)
    assert ask(emu, "1VA?") == "1VA20.000000"  # the stored value, not the RAM one


def test_configuration_stores_parameters_through_a_flash_write(emu, clock):
    assert ask(emu, "1PW1") is None and te(emu) == "@"
    assert state(emu) == "14"
    ask(emu, "1VA7")
    assert ask(emu, "1PA1") is None and te(emu) == "I"
    ask(emu, "1PW0")
    assert ask(emu, "1TS") is None  # writing flash: deaf
    clock.advance(emu.pw0_busy_s)
    assert ask(emu, "1TS") == "1TS00000C"
    ask(emu, "1RS")
    clock.advance(emu.reset_busy_s)
    assert ask(emu, "1VA?") == "1VA7.000000"  # survived the reset
    assert ask(emu, "1PW0") is None and te(emu) == "D"


# --------------------------------------------------------------------------- URL and purity


def test_url_options_reach_the_emulator():
    port = serial.serial_for_url(
        "simsmc://lin?address=4&kind=linear&start=-3&seed=9&step=0.001&reset_busy=0.2"
        "&settle=0.05",
        baudrate=57600, timeout=0.2)
    emu = registry.get("simsmc", "lin")
    assert isinstance(emu, Smc100Emulator)
    assert (emu.address, emu.kind, emu.reset_busy_s, emu.settle_s) == (4, "linear", 0.2, 0.05)
    assert emu.stage.physical_position() == pytest.approx(-3.0)
    port.write(b"4SR?\r\n")
    assert port.read_until(b"\r\n") == b"4SR50.000000\r\n"
    port.close()


def test_software_limits_from_the_url_let_a_detector_arm_reach_the_beam():
    port = serial.serial_for_url("simsmc://straight?kind=rotary&sr=181&step=0.001",
                                 baudrate=57600, timeout=0.2)
    port.write(b"1SR?\r\n")
    assert port.read_until(b"\r\n") == b"1SR181.000000\r\n"
    port.write(b"1SL?\r\n")  # the other limit stays the stage model's
    assert port.read_until(b"\r\n") == b"1SL-170.000000\r\n"
    port.close()


def test_wrong_baud_rate_gets_no_answer():
    port = serial.serial_for_url("simsmc://baud", baudrate=921600, timeout=0.05)
    port.write(b"1TS\r\n")
    assert port.read(20) == b""


def test_linear_stage_defaults():
    model = STAGE_MODELS["linear"]
    assert model.units == "mm"
    low, high = model.software_limits
    assert model.travel[0] < low < 0 < high < model.travel[1]
    assert math.isinf(STAGE_MODELS["rotary"].travel[1])


def test_firmware_emulator_imports_nothing_from_drivers():
    root = Path(__file__).resolve().parents[2] / "hw_mocks"
    assert_imports_nothing_forbidden(root / "firmware" / "smc100.py",
                                     root / "urlhandler" / "protocol_simsmc.py")


# --------------------------------------------------------------------------- fuzzing

_COMMANDS = ["TS", "TE", "TP", "TH", "VE", "ID", "OR", "PA", "PR", "ST", "MM", "RS", "PW",
             "VA", "AC", "OH", "OT", "SL", "SR", "XX", "pa"]
_requests = st.one_of(
    # well-formed-looking requests with arbitrary arguments: they drive the state machine
    st.builds(lambda a, c, v: f"{a}{c}{v}".encode("ascii", "replace") + b"\r\n",
              st.sampled_from([1, 1, 1, 2, 0, 99]), st.sampled_from(_COMMANDS),
              st.one_of(st.just(""), st.just("?"), st.floats(-1e3, 1e3).map("{:g}".format),
                        st.text(max_size=6))),
    # and raw line noise, with or without a terminator
    st.binary(max_size=30),
)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(_requests, st.floats(0.0, 5.0)), max_size=25))
def test_arbitrary_requests_never_crash_and_replies_stay_well_formed(steps):
    clock = ManualClock()
    emu = Smc100Emulator("fuzz", clock=clock, kind="linear")
    for request, dt in steps:
        for reply in emu.receive(request):
            assert reply.endswith(b"\r\n") and reply.startswith(b"1")
            assert all(0x20 <= b < 0x7F for b in reply[:-2]), reply
        clock.advance(dt)
        emu.poll()
    # Whatever happened, TS still answers six hex digits of a documented state, the
    # stage stays inside its hardware travel, and a fresh line is understood.
    clock.advance(10.0)  # past any reboot or flash-write window (deaf while busy)
    emu.receive(b"\r\n")  # end any half-received request
    line = ask(emu, "1TS")
    assert line is not None and len(line) == 9
    assert int(line[-2:], 16) in {0x0A, 0x0B, 0x0C, 0x14, 0x1E, 0x28, 0x32, 0x33, 0x34,
                                  0x3C, 0x3D}
    low, high = emu.model.travel
    assert low - 1e-9 <= emu.stage.physical_position() <= high + 1e-9
