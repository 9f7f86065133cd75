"""The APT firmware emulator on its own: wire replies, motion profiles and field quirks.

Requests are packed by hand here (``<HBBBB`` short / ``<HHBB`` long headers, host 0x01,
device 0x50), so these tests do not lean on the driver's codec.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from hw_mocks import registry
from hw_mocks.clock import ManualClock
from hw_mocks.firmware import apt as firmware
from hw_mocks.firmware.apt import PROFILES, AptEmulator
from hw_mocks.motion import TrapezoidalProfile
from tests.hw_mocks.purity import assert_imports_nothing_forbidden

K10_CPU = 409600 / 3


def short(msg_id, p1=1, p2=0):
    return struct.pack("<HBBBB", msg_id, p1, p2, 0x50, 0x01)


def long(msg_id, data):
    return struct.pack("<HHBB", msg_id, len(data), 0xD0, 0x01) + data


def frames(raw_frames):
    """(id, payload-or-params) for each reply frame."""
    out = []
    for f in raw_frames:
        msg_id, p1, p2, dest, source = struct.unpack_from("<HBBBB", f)
        assert source == 0x50 and dest & 0x7F == 0x01
        if dest & 0x80:
            assert len(f) == 6 + (p1 | p2 << 8)
            out.append((msg_id, f[6:]))
        else:
            assert len(f) == 6
            out.append((msg_id, (p1, p2)))
    return out


def query(emu, request, reply_id):
    replies = [r for r in frames(emu.receive(request)) if r[0] == reply_id]
    assert len(replies) == 1, replies
    return replies[0][1]


def status(emu):
    if emu.profile.stepper:
        return struct.unpack("<HL", query(emu, short(0x0429), 0x042A))[1]
    return struct.unpack("<HlhHL", query(emu, short(0x0490), 0x0491))[4]


def position(emu):
    return struct.unpack("<Hi", query(emu, short(0x0411), 0x0412))[1]


def make(model="K10CR1", stage=None, **kw):
    clock = ManualClock()
    return AptEmulator("e", model=model, stage=stage, clock=clock, **kw), clock


def write_home_params(emu, velocity_units, offset=0):
    emu.receive(long(0x0440, struct.pack("<HHHii", 1, 2, 1, velocity_units, offset)))


def test_identity_reply_layout():
    emu, _ = make("KDC101", "MTS25-Z8")
    info = query(emu, short(0x0005, 0, 0), 0x0006)
    assert len(info) == 84
    serial_no, model, _type, fw = struct.unpack_from("<l8sH4s", info)
    assert serial_no // 1_000_000 == 27 and model.rstrip(b"\0") == b"KDC101"
    assert fw == bytes([4, 0, 2, 0])  # minor, interim, major, unused
    assert struct.unpack_from("<H", info, 76)[0] == 7  # MTS25-Z8 stage id
    k10, _ = make()
    assert struct.unpack_from("<l", query(k10, short(0x0005, 0, 0), 0x0006))[0] // 1_000_000 == 55


def test_power_up_homing_never_completes_until_home_params_are_set():
    emu, clock = make()
    emu.receive(short(0x0210, 1, 1))
    assert emu.home_velocity_du == 0
    emu.receive(short(0x0443))
    clock.advance(1000.0)
    assert emu.poll() == []
    assert status(emu) & 0x200 and not status(emu) & 0x400  # homing, never homed
    assert emu.stage.physical_position() == pytest.approx(37.0)
    write_home_params(emu, 7329109 * 10)  # 10 deg/s
    assert emu.stage.home_velocity == pytest.approx(10.0)
    emu.receive(short(0x0443))
    clock.advance(3.6)
    assert emu.poll() == []
    clock.advance(0.2)  # 37 deg at 10 deg/s = 3.7 s
    assert frames(emu.poll()) == [(0x0444, (1, 0))]  # MOVE_HOMED, short form
    bits = status(emu)
    assert bits & 0x400 and not bits & 0x200 and bits & 0x2000
    assert position(emu) == 0 and emu.stage.physical_position() == 0.0


def test_home_offset_moves_off_the_switch_and_zeroes_there():
    emu, clock = make("KDC101", "MTS25-Z8")
    emu.receive(short(0x0210, 1, 1))
    vel = round(1.0 * PROFILES[("KDC101", "MTS25-Z8")].velocity_scale)
    write_home_params(emu, vel, offset=round(12.5 * 34304))
    emu.receive(short(0x0443))
    clock.advance(7.9)  # 8 mm to the switch at 1 mm/s
    assert emu.poll() == [] and status(emu) & 0x200
    clock.advance(0.2)
    assert emu.poll() == []  # switch found: now the offset move, still "homing"
    assert status(emu) & 0x200 and not status(emu) & 0x400
    clock.advance(20.0)
    assert [f[0] for f in frames(emu.poll())] == [0x0444]
    assert position(emu) == 0
    assert emu.stage.physical_position() == pytest.approx(12.5)


def test_move_absolute_follows_a_trapezoid_and_stops_short():
    emu, clock = make(seed=5)
    emu.receive(short(0x0210, 1, 1))
    emu.stage.teleport(0.0)
    target = round(45 * K10_CPU)
    emu.receive(long(0x0453, struct.pack("<Hi", 1, target)))
    duration = TrapezoidalProfile.duration_for(45.0, 10.0, 10.0)  # power-up 10 deg/s, 10/s²
    clock.advance(duration / 2)
    bits = status(emu)
    assert bits & 0x10 and bits & 0x20000000 and not bits & 0x2000  # moving CW, active
    assert position(emu) == pytest.approx(target / 2, rel=0.01)
    clock.advance(duration / 2 + 1e-6)
    (done,) = frames(emu.poll())
    assert done[0] == 0x0464 and len(done[1]) == 14  # 14-byte status form
    chan, pos, _vel, _res, final_bits = struct.unpack("<HlhHL", done[1])
    short_by = target - pos
    assert chan == 1 and 0 <= short_by <= PROFILES[("K10CR1", "K10CR1")].stop_short_counts
    assert final_bits & 0x2000 and not final_bits & 0x30
    assert emu.stage.physical_position() == pytest.approx(pos / K10_CPU)


def test_servo_settles_after_the_profile_before_move_completed():
    emu, clock = make("KDC101", stop_short_counts=0)
    settle = PROFILES[("KDC101", "PRM1-Z8")].settle_s
    assert settle > 0 and PROFILES[("K10CR1", "K10CR1")].settle_s == 0
    emu.receive(short(0x0210, 1, 1))
    emu.stage.teleport(0.0)
    emu.receive(long(0x0453, struct.pack("<Hi", 1, 10000)))
    duration = TrapezoidalProfile.duration_for(10000 / emu.profile.counts_per_unit,
                                               10.0, 10.0)
    clock.advance(duration + settle / 2)
    bits = status(emu)
    # profile over, at the target, but not yet settled: still active, no direction bits
    assert bits & 0x20000000 and not bits & 0x2000 and not bits & 0x30
    assert position(emu) == 10000
    assert [f[0] for f in frames(emu.poll())] == []
    clock.advance(settle)
    assert [f[0] for f in frames(emu.poll())] == [0x0464]
    bits = status(emu)
    assert bits & 0x2000 and not bits & 0x20000000


def test_stop_short_can_be_switched_off_and_relative_moves_add():
    emu, clock = make("KDC101", stop_short_counts=0)
    emu.receive(short(0x0210, 1, 1))
    emu.receive(long(0x0453, struct.pack("<Hi", 1, 10000)))
    clock.advance(100.0)
    # the first MOVE_COMPLETED went out when the move ended, before the next request
    sent = emu.receive(long(0x0448, struct.pack("<Hi", 1, -2500)))
    clock.advance(100.0)
    assert [f[0] for f in frames(sent + emu.poll())] == [0x0464, 0x0464]
    assert position(emu) == 7500


def test_velocity_parameters_are_scaled_to_physical_units():
    emu, _ = make()
    emu.receive(long(0x0413, struct.pack("<Hiii", 1, 0, 1502 * 4, 7329109 * 5)))
    assert emu.stage.velocity == pytest.approx(5.0)
    assert emu.stage.acceleration == pytest.approx(4.0)
    assert struct.unpack("<Hiii", query(emu, short(0x0414), 0x0415)) == (
        1, 0, 1502 * 4, 7329109 * 5)
    kdc, _ = make("KDC101", "PRM1-Z8")
    # 2048/6e6 s servo period, x65536: 42941.66 units per deg/s on a PRM1-Z8
    kdc.receive(long(0x0413, struct.pack("<Hiii", 1, 0, 147, 429417)))
    assert kdc.stage.velocity == pytest.approx(10.0, rel=1e-5)
    assert kdc.stage.acceleration == pytest.approx(10.0, rel=0.01)


def test_k10cr1_does_not_answer_set_enable_and_disabled_channel_ignores_moves():
    emu, clock = make()
    assert emu.receive(short(0x0210, 1, 1)) == []
    assert query(emu, short(0x0211), 0x0212) == (1, 1)
    assert status(emu) & 0x80000000
    emu.receive(short(0x0210, 1, 2))
    assert query(emu, short(0x0211), 0x0212) == (1, 2)
    assert emu.receive(long(0x0453, struct.pack("<Hi", 1, 100000))) == []
    clock.advance(10.0)
    assert position(emu) == 0 and emu.poll() == []


def test_status_stream_at_10_hz_of_emulator_time():
    emu, clock = make("KDC101")
    emu.receive(short(0x0011, 0, 0))
    got = []
    for _ in range(10):
        got += frames(emu.poll())
        clock.advance(0.05)
    assert [f[0] for f in got] == [0x0491] * 5  # 0.5 s: five frames at 0.1 s
    emu.receive(short(0x0012, 0, 0))
    clock.advance(1.0)
    assert emu.poll() == []
    k10, _ = make()
    k10.receive(short(0x0011, 0, 0))
    assert [f[0] for f in frames(k10.poll())] == [0x0481]  # the stepper's status update


def test_stale_frames_only_after_a_reconnect():
    port = serial.serial_for_url("simapt://r?speed=100", baudrate=115200, timeout=0.05)
    assert port.read(100) == b""
    port.close()
    port = serial.serial_for_url("simapt://r", baudrate=115200, timeout=0.05)
    stale = port.read(200)
    frame_len = 20
    assert len(stale) == 5 + 2 * frame_len + frame_len  # partial + 2 status + completed
    assert stale[5:7] == b"\x81\x04" and stale[-20:-18] == b"\x64\x04"
    assert registry.get("simapt", "r").connections == 2


def test_limit_switch_latches_at_the_end_of_travel():
    emu, clock = make("KDC101", "MTS25-Z8", stop_short_counts=0)
    emu.receive(short(0x0210, 1, 1))
    emu.receive(long(0x0453, struct.pack("<Hi", 1, 30 * 34304)))  # counter 0 at 8 mm
    clock.advance(100.0)
    bits = status(emu)
    assert bits & 0x1 and not bits & 0x2
    assert emu.stage.physical_position() == 25.0
    emu.receive(long(0x0453, struct.pack("<Hi", 1, -20 * 34304)))
    clock.advance(100.0)
    assert status(emu) & 0x2 and emu.stage.physical_position() == 0.0


def test_error_state_refuses_motion_until_reenabled():
    emu, clock = make("KDC101")
    emu.receive(short(0x0210, 1, 1))
    emu.receive(long(0x0453, struct.pack("<Hi", 1, 50000)))
    clock.advance(0.5)
    emu.enter_error_state("0x33")
    (event,) = frames(emu.poll())
    assert event[0] == 0x0081 and struct.unpack_from("<HH", event[1]) == (0, 0x33)
    assert status(emu) & 0x40000000 and status(emu) & 0x4000
    assert not emu.stage.is_moving()
    (refusal,) = frames(emu.receive(long(0x0453, struct.pack("<Hi", 1, 0))))
    assert refusal[0] == 0x0081 and struct.unpack_from("<HH", refusal[1]) == (0x0453, 0x33)
    emu.receive(short(0x0210, 1, 1))
    assert not status(emu) & 0x40000000


def test_garbage_on_the_input_is_skipped():
    emu, _ = make()
    replies = frames(emu.receive(b"\x00\xff\x05" + short(0x0005, 0, 0)))
    assert [r[0] for r in replies] == [0x0006]
    # a request split across writes is answered once complete
    req = short(0x0411)
    assert emu.receive(req[:4]) == []
    assert frames(emu.receive(req[4:]))[0][0] == 0x0412


def test_stop_sends_move_stopped():
    emu, clock = make()
    emu.receive(short(0x0210, 1, 1))
    emu.receive(long(0x0453, struct.pack("<Hi", 1, round(90 * K10_CPU))))
    clock.advance(2.0)
    emu.receive(short(0x0465, 1, 2))  # profiled stop
    clock.advance(2.0)
    (stopped,) = frames(emu.poll())
    assert stopped[0] == 0x0466 and len(stopped[1]) == 14
    assert 0 < emu.stage.physical_position() - 37.0 < 90


def test_unsolicited_frames_alternate_between_status_and_move_completed():
    emu, _ = make("KDC101")
    ids = [frames([emu.unsolicited_frame()])[0][0] for _ in range(4)]
    assert ids == [0x0491, 0x0464, 0x0491, 0x0464]


def test_unknown_model_is_refused():
    with pytest.raises(ValueError, match="unknown APT"):
        AptEmulator("x", model="TDC001")


def test_emulator_imports_nothing_from_drivers():
    assert_imports_nothing_forbidden(Path(firmware.__file__))
    assert math.isfinite(PROFILES[("K10CR1", "K10CR1")].counts_per_unit)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=40), max_size=10))
def test_arbitrary_host_bytes_never_crash_the_emulator(chunks):
    emu, clock = make("KDC101")
    for chunk in chunks:
        for frame in emu.receive(chunk):
            assert frame[5] == 0x50  # everything it sends is a well-formed device frame
        clock.advance(0.1)
        emu.poll()
    # and it still answers a proper request afterwards
    emu.on_connect()  # a reconnect drops any half-received request
    assert query(emu, short(0x0005, 0, 0), 0x0006)


@pytest.mark.parametrize("step", [0.01, 0.03, 0.05])
@pytest.mark.parametrize("target", [10000, 40000, 150000])
def test_a_status_frame_belongs_to_one_moment(step, target):
    """Position and status bits of one DC status frame come from one clock reading.

    A stepping clock moves on every reading, as a running clock does while the emulator's
    thread is descheduled on a loaded machine; read twice, a move could end between the
    position and the bits, and the frame would say "settled" short of the target.
    """
    from hw_mocks.clock import SteppingClock

    emu = AptEmulator("e", model="KDC101", clock=SteppingClock(step), stop_short_counts=0)
    emu.receive(short(0x0210, 1, 1))
    emu.stage.teleport(0.0)
    emu.receive(long(0x0453, struct.pack("<Hi", 1, target)))
    polls = 0
    while True:
        _chan, pos, _vel, _res, bits = struct.unpack(
            "<HlhHL", query(emu, short(0x0490), 0x0491))
        if bits & 0x2000:  # settled
            break
        polls += 1
    assert pos == target and polls >= 1
