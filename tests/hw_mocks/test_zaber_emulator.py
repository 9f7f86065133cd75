"""The Zaber firmware emulator on its own: raw bytes in, raw bytes out, manual time.

These tests pin the emulator to the protocol facts (Zaber's *ASCII Protocol Manual* and the
sources in its docstring) without the driver, so the driver's tests test the driver against an
independent reading.
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
from hw_mocks.firmware.zaber import STAGE_MODELS, ZaberEmulator
from hw_mocks.motion import TrapezoidalProfile
from tests.hw_mocks.purity import assert_imports_nothing_forbidden

MS = STAGE_MODELS["rotary"].microstep_size


@pytest.fixture
def clock():
    return ManualClock()


@pytest.fixture
def emu(clock):
    return ZaberEmulator("t", clock=clock)


def ask(emu: ZaberEmulator, command: str, end: bytes = b"\n") -> str | None:
    """Send one command; return the reply without CR LF (None if unanswered)."""
    frames = emu.receive(command.encode("ascii") + end)
    assert len(frames) <= 1, frames
    if not frames:
        return None
    assert frames[0].endswith(b"\r\n")
    return frames[0][:-2].decode("ascii")


def data(emu, command: str) -> str:
    return ask(emu, command).split(" ", 5)[5]


def home(emu, clock) -> None:
    assert ask(emu, "/1 1 home") == "@01 1 OK BUSY WR 0"
    clock.advance(60.0)
    assert ask(emu, "/1 1") == "@01 1 OK IDLE -- 0"


def checksum(body: str) -> str:
    return f"{(-sum(body.encode())) & 0xFF:02X}"


# --------------------------------------------------------------------------- basics


def test_power_up_state_and_identity(emu):
    assert ask(emu, "/1 1") == "@01 1 OK IDLE WR 0"          # no reference position yet
    assert ask(emu, "/1 1 get pos") == "@01 1 OK IDLE WR 0"  # counter reads 0 at power-up
    assert emu.stage.physical_position() == pytest.approx(37.0)
    assert ask(emu, "/1 1 warnings") == "@01 1 OK IDLE WR 01 WR"
    assert data(emu, "/1 0 get system.axiscount") == "1"
    assert data(emu, "/1 0 get version") == "7.38"
    assert data(emu, "/1 0 get deviceid").isdigit()
    assert data(emu, "/1 0 get system.serial").isdigit()
    assert data(emu, "/1 1 get resolution") == "64"
    assert data(emu, "/1 1 get limit.max") == str(round(180.0 / MS))
    assert data(emu, "/1 1 get maxspeed") == str(round(20.0 / MS * 1.6384))
    assert emu.baudrate == 115200 and emu.scheme == "simzaber"


def test_framing_line_ends_noise_backspace_and_delete(emu):
    assert ask(emu, "/1 1 get pos", b"\r") == "@01 1 OK IDLE WR 0"
    assert ask(emu, "/1 1 get pos", b"\r\n") == "@01 1 OK IDLE WR 0"
    assert emu.receive(b"\r\n") == []                       # the LF after a CR: nothing
    assert emu.receive(b"\x00\xffjunk/1 1 get pos\n") == [b"@01 1 OK IDLE WR 0\r\n"]
    assert emu.receive(b"/1 1 get posX\x08\n") == [b"@01 1 OK IDLE WR 0\r\n"]
    assert emu.receive(b"/1 1 home\x7f\n") == []             # DEL discards the command
    assert emu.receive(b"/1 1 ho\x80me\n") == []             # so does a non-printable byte
    assert emu.receive(b"/1 1 get") == [] and emu.receive(b" pos\n/1 1\n") == [
        b"@01 1 OK IDLE WR 0\r\n", b"@01 1 OK IDLE WR 0\r\n"]  # split and joined commands
    assert ask(emu, "/") == "@01 0 OK IDLE WR 0"             # every device, whole device
    assert ask(emu, "/1") == "@01 0 OK IDLE WR 0"


def test_addressing_and_message_ids(emu):
    assert ask(emu, "/2 1 get pos") is None                  # another device on the chain
    assert ask(emu, "/0 1 get pos") == "@01 1 OK IDLE WR 0"  # device 0 reaches everyone
    assert ask(emu, "/1 1 7 get pos") == "@01 1 07 OK IDLE WR 0"
    assert ask(emu, "/1 1 42") == "@01 1 42 OK IDLE WR 0"
    assert ask(emu, "/1 1 100 get pos") == "@01 1 RJ IDLE WR BADMESSAGEID"
    two = ZaberEmulator("a12", device=12, clock=ManualClock())
    assert ask(two, "/12 1 get pos") == "@12 1 OK IDLE WR 0"
    with pytest.raises(ValueError):
        ZaberEmulator("bad", device=0)
    with pytest.raises(ValueError):
        ZaberEmulator("bad", kinds=("tilt",))
    with pytest.raises(ValueError):
        ZaberEmulator("bad", kinds=("rotary",) * 10)


@pytest.mark.parametrize("command, reason", [
    ("/1 1 fly", "BADCOMMAND"),
    ("/1 1 get nothing", "BADCOMMAND"),
    ("/1 1 set resolution 32", "BADCOMMAND"),   # read-only in the emulator
    ("/1 1 set pos 5", "BADCOMMAND"),
    ("/1 2 get pos", "BADAXIS"),
    ("/1 1 get deviceid", "DEVICEONLY"),
    ("/1 1 set comm.alert 1", "DEVICEONLY"),
    ("/1 1 move abs 1.5", "BADDATA"),
    ("/1 1 move abs x", "BADDATA"),
    ("/1 1 move abs 999999999", "BADDATA"),     # beyond limit.max
    ("/1 1 set maxspeed 0", "BADDATA"),
    ("/1 1 set accel -1", "BADDATA"),
    ("/1 0 set comm.alert 2", "BADDATA"),
    ("/1 1 move sideways 5", "BADCOMMAND"),
])
def test_rejections_carry_their_reason(emu, command, reason):
    assert ask(emu, command) == f"@01 {command.split()[1]} RJ IDLE WR {reason}"


def test_checksummed_commands_and_replies(emu):
    body = "1 1 get pos"
    assert ask(emu, f"/{body}:{checksum(body)}") == "@01 1 OK IDLE WR 0"
    wrong = f"{(int(checksum(body), 16) + 1) % 256:02X}"
    assert ask(emu, f"/{body}:{wrong}") is None              # dropped, not answered
    assert emu.dropped == [f"{body}:{wrong}".encode()]
    assert ask(emu, "/1 0 set comm.checksum 1").endswith(":" + checksum("01 0 OK IDLE WR 0"))
    reply = ask(emu, "/1 1 get pos")
    assert reply == "@01 1 OK IDLE WR 0:" + checksum("01 1 OK IDLE WR 0")
    assert data(emu, "/1 0 get comm.checksum").startswith("1:")


# --------------------------------------------------------------------------- motion


def test_homing_runs_to_the_sensor_and_clears_wr(emu, clock):
    assert ask(emu, "/1 1 home") == "@01 1 OK BUSY WR 0"
    run = 37.0 / emu.stage.home_velocity  # maxspeed: 20 deg/s to a data unit
    clock.advance(run / 2)
    assert ask(emu, "/1 1") == "@01 1 OK BUSY WR 0"
    assert emu.stage.physical_position() == pytest.approx(37.0 / 2)
    clock.advance(run / 2 + 1e-9)
    assert ask(emu, "/1 1 warnings") == "@01 1 OK IDLE -- 00"
    assert ask(emu, "/1 1 get pos") == "@01 1 OK IDLE -- 0"
    assert emu.stage.physical_position() == pytest.approx(0.0)


def test_absolute_move_follows_the_trapezoid_in_microsteps(emu, clock):
    home(emu, clock)
    speed, accel = round(10.0 / MS * 1.6384), round(20.0 / MS * 1.6384 / 10000)
    ask(emu, f"/1 1 set maxspeed {speed}")
    ask(emu, f"/1 1 set accel {accel}")
    v, a = speed / 1.6384 * MS, accel * 10000 / 1.6384 * MS
    target = round(30.0 / MS)
    t0 = clock.now()
    assert ask(emu, f"/1 1 move abs {target}") == "@01 1 OK BUSY -- 0"
    profile = TrapezoidalProfile(0.0, target * MS, v, a, t0)
    for t in (0.25, 1.0, 2.0, profile.duration - 0.1):
        clock.set(t0 + t)
        pos = int(data(emu, "/1 1 get pos"))
        assert pos == pytest.approx(profile.position(t0 + t) / MS, abs=1.0)
        assert ask(emu, "/1 1").split()[3] == "BUSY"
    clock.set(t0 + profile.duration + 1e-6)
    assert ask(emu, "/1 1 get pos") == f"@01 1 OK IDLE -- {target}"


def test_relative_moves_count_from_the_target_and_limits_refuse(emu, clock):
    home(emu, clock)
    ask(emu, "/1 1 move abs 1000")
    assert ask(emu, "/1 1 move rel 500") == "@01 1 OK BUSY -- 0"   # from the target 1000
    clock.advance(30)
    assert data(emu, "/1 1 get pos") == "1500"
    ask(emu, "/1 1 move rel -2000")
    clock.advance(30)
    assert data(emu, "/1 1 get pos") == "-500"
    low = int(data(emu, "/1 1 get limit.min"))
    assert ask(emu, f"/1 1 move rel {low}") == "@01 1 RJ IDLE -- BADDATA"
    assert data(emu, "/1 1 get pos") == "-500"


def test_stop_decelerates_and_sets_ni(emu, clock):
    home(emu, clock)
    ask(emu, f"/1 1 move abs {round(150 / MS)}")
    clock.advance(3.0)  # cruising at 20 deg/s
    at_stop = int(data(emu, "/1 1 get pos")) * MS
    assert ask(emu, "/1 1 stop") == "@01 1 OK BUSY NI 0"   # still braking
    clock.advance(5.0)
    stage = emu.stage  # maxspeed and accel as quantised into data units
    braking = stage.velocity**2 / (2 * stage.acceleration)
    assert int(data(emu, "/1 1 get pos")) * MS == pytest.approx(at_stop + braking, abs=3 * MS)
    assert ask(emu, "/1 1 warnings") == "@01 1 OK IDLE NI 01 NI"
    ask(emu, "/1 1 move rel 10")
    assert "NI" not in ask(emu, "/1 1 warnings")           # the next motion clears it
    assert ask(emu, "/1 1 stop").startswith("@01 1 OK")    # nothing much to stop


def test_stop_during_homing_leaves_no_reference(emu, clock):
    ask(emu, "/1 1 home")
    clock.advance(0.5)
    ask(emu, "/1 1 stop")
    position = emu.stage.physical_position()
    clock.advance(10.0)
    assert emu.stage.physical_position() == position
    assert ask(emu, "/1 1") == "@01 1 OK IDLE WR 0"


def test_driver_disable_enable(emu, clock):
    home(emu, clock)
    assert ask(emu, "/1 1 driver disable") == "@01 1 OK IDLE FO 0"
    assert ask(emu, "/1 1 move abs 10") == "@01 1 RJ IDLE FO DRIVERDISABLED"
    assert ask(emu, "/1 1 home") == "@01 1 RJ IDLE FO DRIVERDISABLED"
    assert ask(emu, "/1 1 warnings clear") == "@01 1 OK IDLE FO 01 FO"
    assert ask(emu, "/1 1 warnings") == "@01 1 OK IDLE FO 01 FO"  # only enabling clears it
    assert ask(emu, "/1 1 driver enable") == "@01 1 OK IDLE -- 0"
    ask(emu, "/1 1 move abs 100000")
    assert ask(emu, "/1 1 driver disable") == "@01 1 RJ BUSY -- STATUSBUSY"


def test_limit_sensor_stop_raises_wl_until_cleared(emu, clock):
    home(emu, clock)
    emu.axes[1].stage.travel = (-5.0, 5.0)
    ask(emu, f"/1 1 move abs {round(8.0 / MS)}")
    clock.advance(10)
    assert ask(emu, "/1 1 get pos") == f"@01 1 OK IDLE WL {round(5.0 / MS)}"
    # The reply lists what was cleared; its warning field shows the state after.
    assert ask(emu, "/1 1 warnings clear") == "@01 1 OK IDLE -- 01 WL"
    assert ask(emu, "/1 1") == "@01 1 OK IDLE -- 0"


def test_injected_stall_stops_the_axis_and_persists_until_cleared(emu, clock):
    home(emu, clock)
    ask(emu, f"/1 1 move abs {round(100 / MS)}")
    clock.advance(1.0)
    emu.enter_error_state(None)
    position = emu.stage.physical_position()
    clock.advance(5.0)
    assert emu.stage.physical_position() == position
    assert ask(emu, "/1 1 warnings") == "@01 1 OK IDLE FS 01 FS"
    assert ask(emu, "/1 1 warnings clear") == "@01 1 OK IDLE -- 01 FS"
    assert ask(emu, "/1 1 warnings") == "@01 1 OK IDLE -- 00"
    emu.enter_error_state("1:FQ")
    assert emu.flags() == ["FQ"]
    with pytest.raises(ValueError):
        emu.enter_error_state("WR")
    with pytest.raises(ValueError):
        emu.enter_error_state("7:FS")


def test_alerts_when_enabled(emu, clock):
    home(emu, clock)
    ask(emu, "/1 0 set comm.alert 1")
    ask(emu, "/1 1 move abs 1000")
    assert emu.poll() == []
    clock.advance(10)
    assert emu.poll() == [b"!01 1 IDLE --\r\n"]
    assert emu.poll() == []
    ask(emu, "/1 1 move abs 0")
    clock.advance(10)
    # An alert raised while a command is handled goes out before its reply.
    assert emu.receive(b"/1 1\n") == [b"!01 1 IDLE --\r\n", b"@01 1 OK IDLE -- 0\r\n"]
    assert emu.unsolicited_frame() == b"!01 1 IDLE --\r\n"


def test_two_axes_device_scope(clock):
    emu = ZaberEmulator("two", kinds=("rotary", "linear"), clock=clock,
                        start_positions=(1.0, 2.0))
    assert data(emu, "/1 0 get system.axiscount") == "2"
    assert ask(emu, "/1 0 home") == "@01 0 OK BUSY WR 0"
    clock.advance(60)
    ms2 = STAGE_MODELS["linear"].microstep_size
    ask(emu, "/1 2 move abs 1000")
    assert ask(emu, "/1 0") == "@01 0 OK BUSY -- 0"       # BUSY while any axis moves
    clock.advance(60)
    assert data(emu, "/1 0 get pos") == "0 1000"
    assert emu.axes[2].stage.physical_position() == pytest.approx(1000 * ms2)
    assert ask(emu, "/1 0 set maxspeed 1000") == "@01 0 OK IDLE -- 0"
    assert data(emu, "/1 0 get maxspeed") == "1000 1000"


def test_reconnect_finds_stale_bytes():
    port = serial.serial_for_url("simzaber://stale?step=0.001", baudrate=115200, timeout=0.1)
    assert port.in_waiting == 0
    port.close()
    port = serial.serial_for_url("simzaber://stale", baudrate=115200, timeout=0.1)
    stale = port.read(200)
    assert stale.endswith(b"@01 1 OK IDLE -- 0\r\n!01 1 IDLE WR\r\n")
    assert not stale.startswith(b"@")  # the first piece is the tail of a reply
    port.close()


# --------------------------------------------------------------------------- URL and purity


def test_url_options_reach_the_emulator():
    port = serial.serial_for_url(
        "simzaber://multi?device=4&kind=rotary,linear&start=1,-3&seed=9&step=0.001"
        "&checksum=1&alerts=1", baudrate=115200, timeout=0.2)
    emu = registry.get("simzaber", "multi")
    assert isinstance(emu, ZaberEmulator)
    assert (emu.device, emu.kinds, emu.comm_checksum, emu.comm_alert) == (
        4, ("rotary", "linear"), True, True)
    assert emu.axes[2].stage.physical_position() == pytest.approx(-3.0)
    port.write(b"/4 0 get system.axiscount\n")
    assert port.read_until(b"\r\n") == b"@04 0 OK IDLE WR 2:" + checksum(
        "04 0 OK IDLE WR 2").encode() + b"\r\n"
    port.close()
    with pytest.raises(ValueError):
        serial.serial_for_url("simzaber://bad?axes=3&kind=rotary,linear", baudrate=115200)


def test_wrong_baud_rate_gets_no_answer():
    port = serial.serial_for_url("simzaber://baud", baudrate=9600, timeout=0.05)
    port.write(b"/1 1\n")
    assert port.read(20) == b""


def test_models_are_consistent():
    for model in STAGE_MODELS.values():
        low, high = model.limits
        assert model.travel[0] <= low < 0 < high <= model.travel[1]
        assert model.maxspeed <= model.maxspeed_max and model.accel <= model.accel_max
    assert math.isinf(STAGE_MODELS["rotary"].travel[1])


def test_firmware_emulator_imports_nothing_from_drivers():
    root = Path(__file__).resolve().parents[2] / "hw_mocks"
    assert_imports_nothing_forbidden(root / "firmware" / "zaber.py",
                                     root / "urlhandler" / "protocol_simzaber.py")


# --------------------------------------------------------------------------- fuzzing

_WORDS = ["", "get pos", "get maxspeed", "get limit.min", "warnings", "warnings clear",
          "home", "stop", "driver enable", "driver disable", "set maxspeed", "set accel",
          "move abs", "move rel", "get deviceid", "set comm.checksum", "fly"]
_commands = st.one_of(
    # well-formed-looking commands with arbitrary arguments: they drive the state machine
    st.builds(lambda d, a, i, w, v: (f"/{d} {a} " + (f"{i} " if i is not None else "") +
                                     f"{w} {v}").encode("ascii", "replace") + b"\n",
              st.sampled_from([1, 1, 1, 0, 2]), st.sampled_from([1, 1, 0, 2]),
              st.one_of(st.none(), st.integers(0, 120)), st.sampled_from(_WORDS),
              st.one_of(st.just(""), st.integers(-10**6, 10**6).map(str), st.text(max_size=5))),
    # and raw line noise, with or without a line end
    st.binary(max_size=30),
)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(_commands, st.floats(0.0, 5.0)), max_size=25))
def test_arbitrary_commands_never_crash_and_replies_stay_well_formed(steps):
    clock = ManualClock()
    emu = ZaberEmulator("fuzz", clock=clock, kinds=("linear",))
    for request, dt in steps:
        for frame in emu.receive(request):
            assert frame.endswith(b"\r\n") and frame[:3] in (b"@01", b"!01"), frame
            assert all(0x20 <= b < 0x7F for b in frame[:-2]), frame
        clock.advance(dt)
        emu.poll()
    # Whatever happened, a fresh command is understood, the reply is well formed, and the
    # stage stays inside its travel and the counter inside the limits.
    emu.receive(b"\n")  # end any half-received command
    emu.receive(b"/1 0 set comm.checksum 0\n")
    line = ask(emu, "/1 1 warnings")
    assert line is not None and line.startswith("@01 1 OK ")
    low, high = emu.axes[1].model.travel
    assert low - 1e-9 <= emu.stage.physical_position() <= high + 1e-9


@pytest.mark.parametrize("step", [0.01, 0.03, 0.05])
@pytest.mark.parametrize("target", [4000, 17067, 30000])
def test_a_reply_belongs_to_one_moment(step, target):
    """Position and BUSY/IDLE of one reply come from one reading of the clock.

    A stepping clock moves on every reading, as a running clock does while the emulator's
    thread is descheduled on a loaded machine. Read twice (the position, then the state), a
    move could end between them: IDLE with the position of mid-move, which a driver takes
    as a stop short of the target.
    """
    from hw_mocks.clock import SteppingClock

    emu = ZaberEmulator("t", clock=SteppingClock(step))
    ask(emu, "/1 1 home")
    while "BUSY" in ask(emu, "/1 1 get pos"):
        pass
    assert ask(emu, f"/1 1 move abs {target}") == "@01 1 OK BUSY -- 0"
    polls = 0
    while (reply := ask(emu, "/1 1 get pos")).startswith("@01 1 OK BUSY"):
        polls += 1
    assert reply == f"@01 1 OK IDLE -- {target}" and polls >= 1
