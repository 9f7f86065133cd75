"""AptMotor: byte-exact transcripts, the motion contract on both transports, field quirks
and every injected fault.

Transcript bytes are written out by hand from the *APT Host-Controller Communications
Protocol* (header layouts, ids, the K10CR1 and KDC101 scaling), independently of the
driver's packers.
"""

from __future__ import annotations

import itertools
import struct
import time
from dataclasses import replace

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.apt_protocol import MessageId
from drivers.base import AxisKind
from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceTimeout,
    LimitError,
    MotionError,
    ProtocolError,
    StateError,
    UnsupportedFeature,
)
from drivers.thorlabs_apt import STAGES, AptMotor
from hw_mocks import registry
from hw_mocks.clock import ScaledClock
from hw_mocks.faults import FaultKind
from hw_mocks.firmware.apt import DEFAULTS, AptEmulator
from hw_mocks.pty_server import PtyServer
from hw_mocks.transcript import TranscriptSerial
from tests.drivers.motion_contract import MotionAxisContract

H = bytes.fromhex
SPEED = 200  # emulated seconds per real second
FAST = {"rts_settle_s": 0.0, "flush_s": 0.0}
REQ_POS = H("11 04 01 00 50 01")  # MOT_REQ_POSCOUNTER, channel 1
REQ_VEL = H("14 04 01 00 50 01")  # MOT_REQ_VELPARAMS, channel 1


# --------------------------------------------------------------------------- transcripts


def info_reply(serial_no: int, model: bytes, stage_id: int = 0) -> bytes:
    space = bytes(10) + struct.pack("<H", stage_id)
    payload = struct.pack("<l8sH4s48s12sHHH", serial_no, model, 16, bytes([3, 0, 1, 0]),
                          b"test", space, 1, 0, 1)
    return H("06 00 54 00 81 50") + payload


# K10CR1 parameters written on open: home reverse (2), reverse switch (1), 10 deg/s
# (10 * 7329109 = 73291090 = 0x045E5552), offset 0; velocity 10 deg/s, 10 deg/s^2 (15020).
K10_HOME = "01 00 02 00 01 00 52 55 5E 04 00 00 00 00"
K10_VEL = "01 00 00 00 00 00 AC 3A 00 00 52 55 5E 04"
# PRM1-Z8 on a KDC101: 10 deg/s = 19196.4 counts/s * 2048/6e6 * 65536 = 429417 (0x068D69);
# 10 deg/s^2 = 19196.4 * (2048/6e6)^2 * 65536 = 147.
PRM_HOME = "01 00 02 00 01 00 69 8D 06 00 00 00 00 00"
PRM_VEL = "01 00 00 00 00 00 93 00 00 00 69 8D 06 00"


def open_steps(info: bytes, home: str, vel: str, stale: bytes = b"") -> list[tuple[bytes, bytes]]:
    head = [(b"", stale)] if stale else []
    return [
        *head,
        (H("12 00 00 00 50 01"), b""),                        # HW_STOP_UPDATEMSGS
        (H("05 00 00 00 50 01"), info),                       # HW_REQ_INFO
        (H("10 02 01 01 50 01"), b""),                        # enable ch1: no reply
        (H("11 02 01 00 50 01"), H("12 02 01 01 01 50")),     # REQ -> GET enabled
        (H("40 04 0E 00 D0 01") + H(home), b""),              # MOT_SET_HOMEPARAMS
        (H("41 04 01 00 50 01"), H("42 04 0E 00 81 50") + H(home)),
        (H("13 04 0E 00 D0 01") + H(vel), b""),               # MOT_SET_VELPARAMS
        (H("14 04 01 00 50 01"), H("15 04 0E 00 81 50") + H(vel)),
    ]


def k10_status(status: str, counts: str) -> list[tuple[bytes, bytes]]:
    return [
        (H("29 04 01 00 50 01"), H("2A 04 06 00 81 50 01 00") + H(status)),
        (H("11 04 01 00 50 01"), H("12 04 06 00 81 50 01 00") + H(counts)),
    ]


def dc(status: str, counts: str) -> tuple[bytes, bytes]:
    """MOT_REQ_DCSTATUSUPDATE and its 14-byte reply (chan, position, velocity 0,
    reserved 0, status)."""
    return (H("90 04 01 00 50 01"),
            H("91 04 0E 00 81 50 01 00") + H(counts) + bytes(4) + H(status))


def transcript_motor(steps, stage="K10CR1", **kw) -> tuple[AptMotor, TranscriptSerial]:
    port = TranscriptSerial(steps, baudrate=115200)
    motor = AptMotor(port, name="rot", stage=stage, timeout=0.2, **FAST, **kw)
    return motor, port


def test_k10cr1_open_identify_home_move_stop_transcript():
    homed_idle = "00 25 00 80"  # enabled | settled | homed | connected
    steps = open_steps(info_reply(55000123, b"K10CR1"), K10_HOME, K10_VEL,
                       stale=H("91 04 0E 00 81 50") + bytes(14))
    steps += [
        # home: the base class's enabled check, parameters again, then MOT_MOVE_HOME;
        # MOVE_HOMED arrives unsolicited
        *k10_status("00 01 00 80", "00 00 00 00"),  # enabled | connected, not homed
        (H("40 04 0E 00 D0 01") + H(K10_HOME), b""),
        (H("41 04 01 00 50 01"), H("42 04 0E 00 81 50") + H(K10_HOME)),
        (H("43 04 01 00 50 01"), b""),
        (H("29 04 01 00 50 01"), H("44 04 01 00 01 50") + H("2A 04 06 00 81 50 01 00")
         + H(homed_idle)),
        (H("11 04 01 00 50 01"), H("12 04 06 00 81 50 01 00 00 00 00 00")),
        # move_to(45): status check, MOT_MOVE_ABSOLUTE 6144000 counts, poll until settled
        *k10_status(homed_idle, "00 00 00 00"),
        (H("53 04 06 00 D0 01 01 00 00 C0 5D 00"), b""),
        *k10_status("10 24 00 A0", "00 A0 5D 00"),  # moving CW | active
        # MOVE_COMPLETED (14-byte status form) interleaved before the status reply;
        # the stage stopped 3 counts short of 6144000
        (H("29 04 01 00 50 01"), H("64 04 0E 00 81 50 01 00 FD BF 5D 00 00 00 00 00")
         + H(homed_idle) + H("2A 04 06 00 81 50 01 00") + H(homed_idle)),
        (H("11 04 01 00 50 01"), H("12 04 06 00 81 50 01 00 FD BF 5D 00")),
        # position, then a profiled stop
        (H("11 04 01 00 50 01"), H("12 04 06 00 81 50 01 00 FD BF 5D 00")),
        (H("65 04 01 02 50 01"), b""),
    ]
    motor, port = transcript_motor(steps, poll_interval=0.0)
    ident = motor.identity
    assert (ident.vendor, ident.model, ident.serial, ident.firmware) == (
        "Thorlabs", "K10CR1", "55000123", "1.0.3")
    assert motor.kind is AxisKind.ROTARY
    motor.home(timeout=1.0)
    motor.move_to(45.0)
    final = motor.wait(timeout=60)
    assert final == pytest.approx(45.0 - 3 / (409600 / 3))
    assert motor.position == pytest.approx(45.0, abs=1e-4)
    motor.stop()
    port.assert_complete()
    assert motor.unsolicited_count == 2  # MOVE_HOMED, MOVE_COMPLETED
    motor.close()
    motor.close()


def test_kdc101_prm1_transcript_uses_dc_status_and_relative_moves():
    homed_idle = "00 25 00 80"
    steps = open_steps(info_reply(27000456, b"KDC101", stage_id=6), PRM_HOME, PRM_VEL)
    steps += [
        dc(homed_idle, "00 00 00 00"),                       # move_to(45): ready check
        (H("53 04 06 00 D0 01 01 00 70 51 01 00"), b""),    # 45 deg = 86384 counts
        dc(homed_idle, "70 51 01 00"),                       # wait: settled at target
        # move_by(-1): ready check, position counter, MOT_MOVE_RELATIVE by -1919 counts
        # (round(44 * 1919.64) - 86384 = 84464 - 86384)
        dc(homed_idle, "70 51 01 00"),
        (H("11 04 01 00 50 01"), H("12 04 06 00 81 50 01 00 70 51 01 00")),
        (H("48 04 06 00 D0 01 01 00") + struct.pack("<i", 84464 - 86384), b""),
        # velocity query and change keep the acceleration
        (H("14 04 01 00 50 01"), H("15 04 0E 00 81 50") + H(PRM_VEL)),
        (H("14 04 01 00 50 01"), H("15 04 0E 00 81 50") + H(PRM_VEL)),
        (H("13 04 0E 00 D0 01 01 00 00 00 00 00 93 00 00 00")
         + struct.pack("<i", 214708), b""),               # 5 deg/s
        (H("14 04 01 00 50 01"), H("15 04 0E 00 81 50 01 00 00 00 00 00 93 00 00 00")
         + struct.pack("<i", 214708)),
    ]
    motor, port = transcript_motor(steps, stage="PRM1-Z8")
    assert motor.identity.extra["stage"] == "PRM1-Z8"
    motor.move_to(45.0, wait=True, timeout=1.0)
    motor.move_by(-1.0)
    assert motor.velocity == pytest.approx(10.0, rel=1e-5)
    motor.velocity = 5.0
    port.assert_complete()


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=120))
def test_driver_arbitrary_reply_is_a_value_or_a_typed_error(reply):
    """Whatever bytes answer a query, the driver returns a number or raises a typed error
    naming itself and the command (parser-level fuzzing is in test_apt_protocol.py)."""
    steps = open_steps(info_reply(55000123, b"K10CR1"), K10_HOME, K10_VEL)
    steps += [(REQ_POS, reply), (REQ_POS, b"")]  # one retry, answered by silence
    motor, _port = transcript_motor(steps, retries=1)
    motor.timeout = 0.005
    try:
        value = motor.position
    except (ProtocolError, DeviceTimeout, ControllerError) as err:
        assert err.device == "rot" and err.command
    else:
        assert isinstance(value, float)


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=80).map(lambda b: b.replace(b"\x50", b"\x51")),
       st.integers(-2**31, 2**31 - 1))
def test_driver_decodes_the_reply_after_arbitrary_garbage(garbage, counts):
    # Garbage without the device address 0x50 cannot pass for a header (see the parser's
    # resynchronisation property), so the reply behind it must be found and decoded.
    steps = open_steps(info_reply(55000123, b"K10CR1"), K10_HOME, K10_VEL)
    steps += [(REQ_POS, garbage + H("12 04 06 00 81 50 01 00") + struct.pack("<i", counts))]
    motor, port = transcript_motor(steps, retries=0)
    assert motor.position == counts / (409600 / 3)
    port.assert_complete()


def test_kdc101_mts25_transcript_scales_millimetres_and_writes_the_home_offset():
    # MTS25-Z8: 34304 counts/mm; KDC101 velocity 1 mm/s = 34304 * 2048/6e6 * 65536
    # = 767367 (0x0BB587), 2 mm/s = 1534735 (0x176B0F); 1.5 mm/s^2 = 34304 * (2048/6e6)^2
    # * 65536 = 393 (0x0189). Home offset 12.5 mm = 428800 counts (0x068B00).
    home = "01 00 02 00 01 00 87 B5 0B 00 00 8B 06 00"
    vel = "01 00 00 00 00 00 89 01 00 00 0F 6B 17 00"

    homed_idle = "00 25 00 80"
    steps = open_steps(info_reply(27000789, b"KDC101", stage_id=7), home, vel)
    steps += [
        dc(homed_idle, "00 00 00 00"),                       # move_to(10 mm): ready check
        (H("53 04 06 00 D0 01 01 00 00 3C 05 00"), b""),    # 10 mm = 343040 counts
        dc(homed_idle, "FE 3B 05 00"),                       # settled 2 counts short
        (H("11 04 01 00 50 01"), H("12 04 06 00 81 50 01 00 FE 3B 05 00")),  # position
    ]
    motor, port = transcript_motor(steps, stage="MTS25-Z8", home_offset=12.5,
                                   home_velocity=1.0, velocity=2.0, acceleration=1.5)
    assert motor.kind is AxisKind.LINEAR and motor.units == "mm"
    # The travel (0..25 mm from the switch) seen from the zero 12.5 mm off the switch.
    assert motor.soft_limits == (-12.5, 12.5)
    with pytest.raises(LimitError):
        motor.move_to(12.6)  # refused before a byte is written
    motor.move_to(10.0, wait=True, timeout=1.0)
    assert motor.position == pytest.approx(10.0 - 2 / 34304)
    port.assert_complete()


def test_status_decoding_of_limits_homing_and_errors():
    steps = open_steps(info_reply(55000123, b"K10CR1"), K10_HOME, K10_VEL)
    steps += k10_status("01 02 00 80", "00 00 00 00")        # CW limit, homing
    steps += k10_status("02 04 00 C0", "00 00 00 00")        # CCW limit, homed, error
    motor, port = transcript_motor(steps)
    s = motor.status()
    assert s.at_forward_limit and not s.at_reverse_limit
    assert s.is_homing and s.is_moving and not s.is_homed and s.is_enabled
    s = motor.status()
    assert s.at_reverse_limit and s.is_homed and s.error and "ERROR" in s.error
    port.assert_complete()


def test_wrong_model_fails_open_and_leaves_the_callers_port_to_the_caller():
    steps = open_steps(info_reply(27000456, b"KDC101", stage_id=6), K10_HOME, K10_VEL)[:2]
    port = TranscriptSerial(steps, baudrate=115200)
    with pytest.raises(ConnectionFailed) as info:
        AptMotor(port, name="rot", stage="K10CR1", timeout=0.2, **FAST)
    assert info.value.device == "rot" and info.value.command == "HW_REQ_INFO"
    assert "KDC101" in str(info.value)
    assert port.is_open  # handed in by the caller: still the caller's (ADR 0002)


def test_rich_response_error_is_a_controller_error_with_code():
    steps = open_steps(info_reply(55000123, b"K10CR1"), K10_HOME, K10_VEL)
    rich = struct.pack("<HH64s", 0x0453, 0x21, b"refused")
    steps += [(H("29 04 01 00 50 01"), H("81 00 44 00 81 50") + rich)]
    motor, port = transcript_motor(steps)
    with pytest.raises(ControllerError) as info:
        motor.status()
    err = info.value
    assert err.code == 0x21 and err.device == "rot" and err.command == "MOT_REQ_STATUSBITS"
    assert "MOT_MOVE_ABSOLUTE" in str(err) and "refused" in str(err)
    port.assert_complete()


def test_constructor_validates_arguments():
    with pytest.raises(ValueError, match="unknown APT stage"):
        AptMotor("simapt://x", name="a", stage="Z825")
    with pytest.raises(ValueError, match="velocity"):
        AptMotor("simapt://x", name="a", stage="K10CR1", velocity=50.0)
    with pytest.raises(ValueError, match="counter range"):
        AptMotor("simapt://x", name="a", stage="K10CR1", soft_limits=(-1e6, 1e6))


def test_stage_scaling_table():
    k10 = STAGES["K10CR1"]
    assert k10.counts_per_unit == pytest.approx(136533.33, abs=0.01)
    assert (k10.velocity_scale, k10.acceleration_scale) == (7329109.0, 1502.0)
    prm = STAGES["PRM1-Z8"]
    assert prm.counts_per_unit == 1919.6418578623391
    # KDC101: velocity = counts/s * 2048/6e6 * 65536 -> 42941.66 per deg/s for a PRM1-Z8
    assert prm.velocity_scale == pytest.approx(42941.66, abs=0.01)
    assert prm.acceleration_scale == pytest.approx(14.66, abs=0.01)
    mts = STAGES["MTS25-Z8"]
    assert mts.counts_per_unit == 34304.0 and mts.kind is AxisKind.LINEAR
    assert mts.velocity_scale == pytest.approx(767367.49, abs=0.01)
    assert mts.acceleration_scale == pytest.approx(261.93, abs=0.01)


# --------------------------------------------------------------------------- contract

QUERIES = {
    "K10CR1": "model=K10CR1",
    "PRM1-Z8": "model=KDC101&stage=PRM1-Z8",
    "MTS25-Z8": "model=KDC101&stage=MTS25-Z8",
}
_names = itertools.count()


def driver_options(stage: str) -> dict:
    # The linear stage's zero is put mid-travel by the home offset, so that the
    # contract's targets in [-10, 10] mm lie inside its 25 mm travel.
    return {"home_offset": 12.5} if stage == "MTS25-Z8" else {}


@pytest.fixture
def served() -> dict[str, AptEmulator]:
    """Emulators behind pseudo-terminals, by axis name (those of URLs are in the registry)."""
    return {}


@pytest.fixture
def clock_of(served):
    """The contract's handle on emulated time."""
    return lambda axis: (served.get(axis.name) or registry.get("simapt", axis.name)).clock


@pytest.fixture(params=[(s, t) for s in QUERIES for t in ("url", "pty")],
                ids=lambda p: f"{p[0]}-{p[1]}")
def axis_factory(request, served):
    stage, transport = request.param
    servers: list[PtyServer] = []

    def make() -> AptMotor:
        name = f"ax{next(_names)}"
        options = {**FAST, **driver_options(stage)}
        if transport == "url":
            return AptMotor(f"simapt://{name}?{QUERIES[stage]}&speed={SPEED}", name=name,
                            stage=stage, **options)
        model = "K10CR1" if stage == "K10CR1" else "KDC101"
        served[name] = AptEmulator(name, model=model, stage=stage, clock=ScaledClock(SPEED))
        server = PtyServer(served[name])
        servers.append(server)
        return AptMotor(server.path, name=name, stage=stage, **options)

    yield make
    for server in servers:
        server.close()


class TestAptMotorContract(MotionAxisContract):
    pass


# --------------------------------------------------------------------------- behaviour


def open_url(name="ax", stage="K10CR1", extra="", **kw) -> AptMotor:
    url = f"simapt://{name}?{QUERIES[stage]}&speed={SPEED}{extra}"
    return AptMotor(url, name=name, stage=stage, **{**FAST, **driver_options(stage), **kw})


def test_pty_open_tolerates_rts_ioctl_failure():
    server = PtyServer(AptEmulator("p", clock=ScaledClock(SPEED)))
    with server, AptMotor(server.path, name="p", **FAST) as motor:
        assert motor.rts_cycled is False
        assert motor.identity.model == "K10CR1"
    with open_url("u") as motor:
        assert motor.rts_cycled is True


def test_homing_completes_although_power_up_home_velocity_is_zero():
    motor = open_url()
    emu = registry.get("simapt", "ax")
    assert emu.defaults.power_up_home_velocity == 0.0
    assert emu.stage.home_velocity == pytest.approx(10.0)  # the driver wrote it
    motor.home(timeout=5.0)
    assert motor.is_homed
    assert emu.stage.physical_position() == pytest.approx(0.0, abs=1e-9)


def test_stale_messages_after_reconnect_are_discarded():
    motor = open_url()
    motor.home(timeout=5.0)
    motor.move_to(12.0, wait=True, timeout=5.0)
    emu = registry.get("simapt", "ax")
    emu.updates_on = True  # a previous session left the status stream running
    motor.close()
    again = open_url()  # on_connect puts a partial frame and stale frames in the pipe
    assert emu.connections == 2 and not emu.updates_on
    assert again.position == pytest.approx(12.0, abs=again.position_tolerance)
    assert again.is_homed


def test_stale_bytes_arriving_after_the_flush_are_resynchronised():
    motor = open_url()
    emu = registry.get("simapt", "ax")
    frame = emu.status_update_frame()
    emu.send_unsolicited([frame[3:], frame])  # a partial frame, then a whole one
    assert motor.position == pytest.approx(0.0)
    assert motor._unpacker.discarded >= 1 and motor.unsolicited_count >= 1


def test_stop_short_is_within_default_tolerance_but_not_a_tiny_one():
    motor = open_url(extra="&stop_short=100&seed=3")
    motor.home(timeout=5.0)
    motor.move_to(20.0, wait=True, timeout=5.0)
    counts = registry.get("simapt", "ax").position_counts()
    short = round(20.0 * 409600 / 3) - counts
    assert 0 < short <= 100
    motor.position_tolerance = 1e-6
    with pytest.raises(MotionError) as info:
        motor.move_to(30.0, wait=True, timeout=5.0)
    assert info.value.device == "ax" and info.value.command == "wait"


def test_status_stream_does_not_disturb_queries():
    motor = open_url(stage="PRM1-Z8")
    emu = registry.get("simapt", "ax")
    emu.updates_on = True  # as after HW_START_UPDATEMSGS
    motor.home(timeout=5.0)
    motor.move_to(-30.0, wait=True, timeout=5.0)
    assert motor.position == pytest.approx(-30.0, abs=motor.position_tolerance)
    assert motor.unsolicited_count > 2


def test_controller_that_answers_set_enable_is_tolerated():
    emu = registry.get_or_create(
        "simapt", "ax",
        lambda n, o: AptEmulator(n, model="KDC101", clock=ScaledClock(SPEED),
                                 defaults=replace(DEFAULTS, replies_to_set_enable=True)))
    motor = open_url(stage="PRM1-Z8")
    assert emu.enabled
    motor.disable()
    motor.enable()
    motor.home(timeout=5.0)
    motor.move_to(5.0, wait=True, timeout=5.0)
    assert motor.position == pytest.approx(5.0, abs=motor.position_tolerance)


def test_limit_switch_stops_linear_stage():
    motor = open_url(stage="MTS25-Z8", soft_limits=(-13.0, 20.0))
    motor.home(timeout=5.0)
    with pytest.raises(LimitError) as info:
        motor.move_to(14.0, wait=True, timeout=10.0)  # travel ends 12.5 mm past zero
    assert info.value.device == "ax"
    status = motor.status()
    assert status.at_forward_limit
    assert status.position == pytest.approx(12.5, abs=1e-3)
    motor.move_to(0.0, wait=True, timeout=10.0)
    assert not motor.status().at_forward_limit


def test_stepping_clock_makes_motion_deterministic():
    # step=: every clock reading advances emulated time, so polling drives the motion.
    motor = AptMotor("simapt://ax?model=K10CR1&step=0.05", name="ax", **FAST)
    motor.home(timeout=5.0)
    motor.move_to(-60.0, wait=True, timeout=5.0)
    assert motor.position == pytest.approx(-60.0, abs=motor.position_tolerance)


def test_stage_mismatch_on_kdc101_is_refused():
    with pytest.raises(ConnectionFailed, match="MTS25-Z8"):
        AptMotor(f"simapt://ax?{QUERIES['PRM1-Z8']}", name="ax", stage="MTS25-Z8", **FAST)


def test_identify_blinks():
    motor = open_url()
    motor.identify()
    assert motor.position == 0.0  # a query after it, so the emulator has seen it
    assert registry.get("simapt", "ax").identify_count == 1


# --------------------------------------------------------------------------- faults

def test_fault_drop_is_recovered_by_retrying_the_query():
    motor = open_url(timeout=0.1)
    emu = registry.get("simapt", "ax")
    emu.faults.schedule(FaultKind.DROP, nth=1)
    before = emu.received_log.count(REQ_POS)
    assert motor.position == 0.0
    assert emu.received_log.count(REQ_POS) - before == 2


def test_fault_drop_every_reply_ends_in_a_typed_timeout():
    motor = open_url(timeout=0.1, retries=1)
    emu = registry.get("simapt", "ax")
    emu.faults.randomly(FaultKind.DROP, 1.0)
    before = emu.received_log.count(REQ_POS)
    with pytest.raises(DeviceTimeout) as info:
        motor.position  # noqa: B018
    assert emu.received_log.count(REQ_POS) - before == 2  # bounded: one retry, then typed
    err = info.value
    assert err.device == "ax" and err.command == "MOT_REQ_POSCOUNTER"
    assert "GET_POSCOUNTER" in str(err)


def test_fault_delay_past_timeout_retries_and_discards_the_late_reply():
    motor = open_url(timeout=0.1, stage="PRM1-Z8")
    motor.home(timeout=5.0)
    emu = registry.get("simapt", "ax")
    # late past any timeout: it arrives when the host retries, just ahead of the retry's
    # reply, however loaded the host
    emu.faults.schedule(FaultKind.DELAY, nth=1, until_host_writes=True)
    assert motor.position == pytest.approx(0.0, abs=1e-3)
    count = motor.unsolicited_count
    motor.move_to(3.0, wait=True, timeout=5.0)
    assert motor.position == pytest.approx(3.0, abs=motor.position_tolerance)
    assert motor.unsolicited_count > count  # the late reply was consumed, not used


def test_a_late_settled_status_from_before_the_move_never_ends_the_wait():
    """The readiness status (settled at 0) arrives after the timeout while the move it
    preceded runs: it is consumed as stale, never read as a later poll's answer.

    In-process link: a late frame is never part of a read whose deadline passed, however
    loaded the host; emulated time stands while the move must be seen in progress."""
    motor = open_url(timeout=0.1, stage="PRM1-Z8")
    motor.home(timeout=60)
    emu = registry.get("simapt", "ax")
    with emu.clock.held():
        emu.faults.schedule(FaultKind.DELAY, nth=1, delay_s=0.15)
        motor.move_to(3.0)
        for _ in range(3):
            status = motor.status()
            assert status.is_moving and status.position == pytest.approx(0.0, abs=1e-3)
    assert motor.wait(60) == pytest.approx(3.0, abs=motor.position_tolerance)
    assert [k for _, k in emu.faults.log] == [FaultKind.DELAY]
    motor.close()


def test_motion_commands_are_sent_once_although_the_queries_around_them_are_retried():
    motor = open_url(timeout=0.1)
    motor.home(timeout=5.0)
    emu = registry.get("simapt", "ax")
    # Lose the first reply of the ready check (MOT_GET_STATUSBITS) and, for the relative
    # move, also the position read it starts from: both queries are retried, the moves not.
    emu.faults.schedule(FaultKind.DROP, nth=1)
    motor.move_to(4.0, wait=True, timeout=5.0)
    emu.faults.schedule(FaultKind.DROP, nth=1)  # STATUSBITS (ready check); 2: its retry
    emu.faults.schedule(FaultKind.DROP, nth=4)  # 3: POSCOUNTER (ready check), 4: the move's
    motor.move_by(-1.0, wait=True, timeout=5.0)
    log = bytes(emu.received_log)
    # the position the relative step is computed from was asked twice, the step sent once
    before_step = log.split(H("48 04 06 00 D0 01"))[0]
    assert before_step.endswith(REQ_POS * 2)
    assert log.count(H("53 04 06 00 D0 01 01 00")) == 1  # MOT_MOVE_ABSOLUTE, ch1
    assert log.count(H("48 04 06 00 D0 01 01 00")) == 1  # MOT_MOVE_RELATIVE, ch1
    assert [k for _, k in emu.faults.log] == [FaultKind.DROP] * 3
    assert motor.position == pytest.approx(3.0, abs=motor.position_tolerance)


def test_fault_split_reply_is_reassembled():
    motor = open_url()
    registry.get("simapt", "ax").faults.schedule(FaultKind.SPLIT, nth=1, chunks=4,
                                                 gap_s=0.01)
    assert motor.velocity == pytest.approx(10.0)


def test_fault_garbage_before_a_reply_is_skipped():
    motor = open_url(stage="PRM1-Z8")
    registry.get("simapt", "ax").faults.schedule(FaultKind.GARBAGE, nth=1, nbytes=23)
    assert motor.velocity == pytest.approx(10.0, rel=1e-5)
    assert motor._unpacker.discarded >= 1


@pytest.mark.parametrize("seed", range(12))
def test_fault_corrupt_ends_in_recovery_or_a_typed_error(seed):
    motor = open_url(extra=f"&seed={seed}", timeout=0.1)
    emu = registry.get("simapt", "ax")
    emu.faults.schedule(FaultKind.CORRUPT, nth=1, nbytes=1)
    try:
        value = motor.position
    except (ProtocolError, DeviceTimeout) as err:
        assert err.device == "ax" and err.command == "MOT_REQ_POSCOUNTER"
    else:
        # A flipped header bit is caught and the query retried; a flipped data bit is
        # undetectable (APT has no checksum) and can only be corrected by the next read.
        assert isinstance(value, float)
    assert motor.position == 0.0


def test_fault_corrupt_header_is_retried():
    recovered = 0
    for seed in range(12):
        registry.reset()
        motor = open_url(extra=f"&seed={seed}", timeout=0.05)
        emu = registry.get("simapt", "ax")
        emu.faults.schedule(FaultKind.CORRUPT, nth=1, nbytes=1)
        before = emu.received_log.count(REQ_POS)
        value = motor.position
        if emu.received_log.count(REQ_POS) - before == 2:
            recovered += 1
            assert value == 0.0
        motor.close()
    assert recovered >= 2  # the 12 seeds hit the header (6 of 12 bytes) several times


def test_fault_unsolicited_message_is_consumed():
    motor = open_url(stage="PRM1-Z8")
    emu = registry.get("simapt", "ax")
    emu.faults.schedule(FaultKind.UNSOLICITED, nth=1)
    emu.faults.schedule(FaultKind.UNSOLICITED, nth=2)
    assert motor.velocity == pytest.approx(10.0, rel=1e-5)
    assert motor.position == 0.0
    assert motor.unsolicited_count == 2


def test_fault_disconnect_is_connection_failed_and_reconnect_recovers():
    motor = open_url()
    motor.home(timeout=5.0)
    registry.get("simapt", "ax").faults.schedule(FaultKind.DISCONNECT, nth=1)
    with pytest.raises(ConnectionFailed) as info:
        motor.move_to(5.0)  # the ready check's reply is lost with the link
    assert info.value.device == "ax" and info.value.command == "MOT_REQ_STATUSBITS"
    motor.close()
    again = open_url()  # reopening the port reconnects the emulated cable
    assert again.is_homed
    again.move_to(5.0, wait=True, timeout=5.0)
    assert again.position == pytest.approx(5.0, abs=again.position_tolerance)


@pytest.fixture(params=["url", "pty"])
def apt_on(request):
    """Open a PRM1-Z8 axis on either transport: ``(motor, emulator)``."""
    servers: list[PtyServer] = []

    def make(name: str, **kw) -> tuple[AptMotor, AptEmulator]:
        if request.param == "url":
            return open_url(name, stage="PRM1-Z8", **kw), registry.get("simapt", name)
        emu = AptEmulator(name, model="KDC101", stage="PRM1-Z8", clock=ScaledClock(SPEED))
        servers.append(PtyServer(emu))
        return AptMotor(servers[-1].path, name=name, stage="PRM1-Z8", **FAST, **kw), emu

    make.transport = request.param
    yield make
    for server in servers:
        server.close()


def test_unplugged_mid_move_is_typed_and_bounded_then_the_move_is_found_finished(apt_on):
    """In-process the link raises (ConnectionFailed); on a pty the dead device answers
    nothing (DeviceTimeout after the retries). The controller keeps running the move on
    its own, as a real one whose USB cable is pulled does; after reconnecting, the
    driver sees where it ended."""
    motor, emu = apt_on("mid", timeout=0.1)
    motor.home(timeout=5.0)
    motor.velocity = 2.0
    motor.move_to(6.0)  # 3 s of emulated time: 15 ms at SPEED
    emu.faults.schedule(FaultKind.DISCONNECT, nth=1)
    expected = ConnectionFailed if apt_on.transport == "url" else DeviceTimeout
    with pytest.raises(expected) as info:
        motor.wait(timeout=60)
    assert info.value.device == "mid" and info.value.command == "MOT_REQ_DCSTATUSUPDATE"
    assert info.value.__cause__ is not None
    if apt_on.transport == "url":
        motor.close()
        motor = open_url("mid", stage="PRM1-Z8", timeout=0.1)  # reopen: stale frames wait
    else:
        emu.faults.reconnect()  # the cable is back; the same port works again
    deadline = time.monotonic() + 60.0
    while motor.is_moving and time.monotonic() < deadline:
        time.sleep(0.005)
    assert motor.is_homed
    assert motor.position == pytest.approx(6.0, abs=motor.position_tolerance)
    motor.close()


def test_lost_replies_on_both_transports_are_retried(apt_on):
    motor, emu = apt_on("lost", timeout=0.1)
    count = motor.unsolicited_count
    # the late reply arrives when the host retries (ahead of the retry's reply), so the
    # first attempt has timed out whatever the load
    for kind, params in [(FaultKind.DROP, {}), (FaultKind.DELAY, {"until_host_writes": True})]:
        emu.faults.schedule(kind, nth=1, **params)
        before = emu.received_log.count(REQ_VEL)
        assert motor.velocity == pytest.approx(10.0, rel=1e-5)
        assert emu.received_log.count(REQ_VEL) - before == 2  # one lost attempt, one retry
    # The late reply is consumed as stale exactly once: before the retry is sent (a host
    # that reaches the retry after the reply arrived), or before or while the next query
    # waits (the wire keeps order, so it comes ahead of that query's reply).
    assert motor.acceleration == pytest.approx(10.0, rel=0.01)
    assert motor.unsolicited_count == count + 1
    assert [k for _, k in emu.faults.log] == [FaultKind.DROP, FaultKind.DELAY]


def test_fault_error_state_is_a_controller_error_and_reenable_recovers():
    motor = open_url(stage="PRM1-Z8")
    motor.home(timeout=5.0)
    emu = registry.get("simapt", "ax")
    emu.stage.velocity = 0.5  # a slow move, so the fault lands mid-way
    # Emulated time stands while the fault is injected: the move is still on when the wait
    # meets it, however long a loaded host takes to get from the move to the first poll.
    with emu.clock.held():
        motor.move_to(10.0)
        emu.faults.schedule(FaultKind.ERROR_STATE, nth=1, code="0x21")
        with pytest.raises(ControllerError) as info:
            motor.wait(timeout=60)
    err = info.value
    # The HW_RICHRESPONSE arrives during the status poll of the wait.
    assert err.device == "ax" and err.command == "MOT_REQ_DCSTATUSUPDATE"
    assert err.code == 0x21 and "0x0021" in str(err)
    assert motor.status().error  # latched in the status bits
    with pytest.raises(ControllerError):
        motor.wait(timeout=60)
    motor.enable()  # the documented recovery: re-enable the channel
    assert motor.status().error is None
    motor.move_to(10.0, wait=True, timeout=10.0)
    assert motor.position == pytest.approx(10.0, abs=motor.position_tolerance)


def test_home_on_a_disabled_channel_is_refused_not_silently_skipped():
    motor = open_url()
    motor.home(timeout=5.0)
    motor.move_to(5.0, wait=True, timeout=5.0)
    motor.disable()
    with pytest.raises(StateError) as info:
        motor.home(timeout=5.0)  # the controller would ignore MOT_MOVE_HOME
    assert info.value.device == "ax" and info.value.command == "home"
    assert motor.position == pytest.approx(5.0, abs=motor.position_tolerance)
    motor.enable()
    motor.home(timeout=5.0)
    assert motor.is_homed and motor.position == pytest.approx(0.0, abs=1e-9)


def test_motion_refused_in_error_state_names_the_command():
    motor = open_url(stage="PRM1-Z8")
    motor.home(timeout=5.0)
    emu = registry.get("simapt", "ax")
    emu.enter_error_state("7")
    with pytest.raises(ControllerError) as info:
        motor.move_to(1.0)
    assert info.value.code == 7


def test_move_on_an_axis_in_error_state_is_refused_before_anything_is_sent():
    motor = open_url(stage="PRM1-Z8")
    motor.home(timeout=5.0)
    emu = registry.get("simapt", "ax")
    emu.enter_error_state("7")
    with pytest.raises(ControllerError):
        motor.status()  # the error event is read (and reported) here
    assert motor.status().error  # the status bits keep it
    sent = len(emu.received_log)
    with pytest.raises(ControllerError) as info:
        motor.move_to(1.0)
    err = info.value
    assert err.device == "ax" and err.command == "move_to"
    assert "enable" in (err.hint or "")
    move_header = struct.pack("<H", MessageId.MOT_MOVE_ABSOLUTE)
    assert move_header not in emu.received_log[sent:]  # no move reached the controller
    motor.enable()  # the recovery the error names
    motor.move_to(1.0, wait=True, timeout=10.0)
    assert motor.position == pytest.approx(1.0, abs=motor.position_tolerance)


def test_failed_open_is_connection_failed_and_the_handed_in_port_stays_open():
    port = serial.serial_for_url("simapt://dead?speed=200", baudrate=115200)
    registry.get("simapt", "dead").faults.randomly(FaultKind.DROP, 1.0)
    with pytest.raises(ConnectionFailed) as info:
        AptMotor(port, name="dead", timeout=0.05, retries=0, **FAST)
    assert info.value.command == "HW_REQ_INFO" and info.value.device == "dead"
    assert isinstance(info.value.__cause__, DeviceTimeout)
    assert port.is_open  # the caller's port (ADR 0002)
    port.close()


def test_wrong_baud_rate_is_connection_failed_naming_the_baud_rate():
    port = serial.serial_for_url("simapt://baud?speed=200", baudrate=57600)
    with pytest.raises(ConnectionFailed) as info:  # after 3 attempts of 0.05 s, no hang
        AptMotor(port, name="baud", timeout=0.05, **FAST)
    err = info.value
    assert err.device == "baud" and err.command == "HW_REQ_INFO"
    assert "115200" in str(err) and isinstance(err.__cause__, DeviceTimeout)
    assert port.is_open  # the caller's port (ADR 0002)
    assert registry.get("simapt", "baud").received_log == b""  # nothing got through


def test_stop_is_sent_although_an_error_event_is_waiting():
    """Safety: a pending HW_RICHRESPONSE (raised when the input is drained) must not keep
    stop() from reaching a moving stage; the error is reported by the next exchange."""
    motor = open_url(stage="PRM1-Z8")
    motor.home(timeout=5.0)
    emu = registry.get("simapt", "ax")
    motor.velocity = 0.5
    with emu.clock.held():  # the stage is surely still moving when stop() is sent
        motor.move_to(10.0)
        # An error event the controller sent without stopping (the emulator's own error
        # state would stop the stage, which would hide the bug).
        emu.send_unsolicited([struct.pack("<HHBB", 0x0081, 68, 0x81, 0x50)
                              + struct.pack("<HH64s", 0, 0x33, b"event")])
        emu.clock.advance(1.0)  # under way at 0.5 mm/s
        assert emu.stage.is_moving()
        motor.stop()
    assert emu.received_log.count(H("65 04 01 02 50 01")) == 1  # MOT_MOVE_STOP, profiled
    deadline = time.monotonic() + 60.0
    while emu.stage.is_moving() and time.monotonic() < deadline:
        time.sleep(0.005)
    assert not emu.stage.is_moving()
    with pytest.raises(ControllerError) as info:
        motor.status()
    assert info.value.code == 0x33


@pytest.mark.parametrize("stage", ["K10CR1", "MTS25-Z8"])
def test_after_a_stop_wait_reports_the_rest_position_and_move_by_counts_from_it(stage):
    motor = open_url(stage=stage)
    motor.home(timeout=5.0)
    motor.velocity = motor.velocity / 100.0  # 80 s of emulated time for 8 deg on a K10CR1
    clock = registry.get("simapt", "ax").clock
    with clock.held():  # stopped 4 emulated seconds into the move, however slow the machine
        motor.move_to(8.0)
        clock.advance(4.0)
        motor.stop()
    rest = motor.wait(timeout=60)  # no MotionError: the stop voided the target
    assert 0.0 < rest < 8.0 - motor.position_tolerance
    assert motor.target is None
    # Read back in quantised device units and scaled up again, the K10CR1's 10 deg/s
    # comes out as 10.0000014: still the maximum, not a ValueError.
    motor.velocity = motor.velocity * 100.0
    # a device unit of 1/100 of it is 7e-5 relative on an MTS25-Z8
    assert motor.velocity == pytest.approx(STAGES[stage].velocity, rel=1e-4)
    motor.move_by(1.0, wait=True, timeout=5.0)
    assert motor.position == pytest.approx(rest + 1.0, abs=motor.position_tolerance)


# --------------------------------------------------------------------------- continuous


def test_continuous_move_turns_at_the_set_velocity_until_stopped():
    motor = open_url(extra="&stop_short=0")
    emu = registry.get("simapt", "ax")
    motor.home(timeout=5.0)
    motor.velocity = 6.0
    with emu.clock.held() as clock:
        start = emu.stage.physical_position()
        motor.move_continuous(forward=False)
        clock.advance(10.0)  # 0.6 s of ramp at 10 °/s², then 6 °/s
        assert emu.stage.velocity_now() == pytest.approx(-6.0, rel=1e-12)
        assert emu.stage.physical_position() == pytest.approx(start - (60.0 - 1.8), abs=1e-6)
        bits = emu.status_bits()
        assert bits & 0x20000000 and bits & 0x20  # active, moving reverse
        motor.stop()
        clock.advance(1.0)  # braking takes 0.6 s
        assert not emu.stage.is_moving()
    assert not motor.is_moving


def test_continuous_move_wraps_the_32_bit_counter():
    motor = open_url()
    emu = registry.get("simapt", "ax")
    motor.home(timeout=5.0)
    with emu.clock.held() as clock:
        motor.move_continuous()
        clock.advance(2000.0)  # ≈ 20 000°: past the counter's 15 729°
        counts = emu.position_counts()
        assert -2**31 <= counts < 2**31
        true = round(emu.stage.position() * 409600 / 3)
        assert (true - counts) % 2**32 == 0 and true != counts
        motor.stop()
        clock.advance(2.0)


def test_continuous_move_refused_on_a_linear_stage_or_a_disabled_channel():
    with open_url(stage="MTS25-Z8") as linear, pytest.raises(UnsupportedFeature) as info:
        linear.move_continuous()
    assert info.value.device == "ax" and "continuous-rotation" in str(info.value)
    motor = open_url(name="rot")
    motor.disable()
    with pytest.raises(StateError, match="enable"):
        motor.move_continuous()
