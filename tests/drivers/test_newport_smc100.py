"""Smc100Axis: byte-exact transcripts, the motion contract on both transports, faults.

Transcripts pin the exact bytes of each operation. The contract suite runs the driver
against the independent firmware emulator in-process (``simsmc://``) and through a real
pseudo-terminal. Fault tests check that every injected fault ends in the documented
recovery (retries for idempotent queries only) or in a typed error naming the device,
the command and the cause, always within a bounded time.
"""

from __future__ import annotations

import pickle

import pytest

from drivers.base import AxisKind
from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceTimeout,
    LimitError,
    NotHomedError,
    ProtocolError,
    StateError,
)
from drivers.newport_smc100 import (
    CommandRefused,
    NotReferencedError,
    Smc100Axis,
    TargetOutOfLimits,
)
from hw_mocks import registry
from hw_mocks.clock import ScaledClock
from hw_mocks.faults import FaultKind
from hw_mocks.firmware.smc100 import Smc100Emulator
from hw_mocks.pty_server import PtyServer
from hw_mocks.transcript import TranscriptSerial
from tests.drivers.fault_checks import corrupted_reads, let_held_reply_arrive, lose_or_hold_reply
from tests.drivers.motion_contract import MotionAxisContract
from tests.drivers.serial_faults import (
    QUERY_FAULTS,
    QUERY_RETRIES,
    motion_fault_session,
    open_patiently,
    query_survives,
    unplug_during_move,
    unplug_during_query,
)

SPEED = 200.0

# Connect sequence with soft limits read from the controller (powered up, not referenced).
CONNECT = [
    (b"1TS\r\n", b"1TS00000A\r\n"),
    (b"1TE\r\n", b"1TE@\r\n"),
    (b"1SL?\r\n", b"1SL-170.000000\r\n"),
    (b"1SR?\r\n", b"1SR170.000000\r\n"),
]
READY_TS = (b"1TS\r\n", b"1TS000033\r\n")


def transcript_axis(steps, **kw) -> tuple[Smc100Axis, TranscriptSerial]:
    port = TranscriptSerial(steps, baudrate=57600)
    kw.setdefault("reply_timeout", 0.05)
    return Smc100Axis(port, name="theta", **kw), port


# --------------------------------------------------------------------------- transcripts


def test_connect_reads_state_clears_latch_and_reads_limits():
    axis, port = transcript_axis(CONNECT)
    assert axis.soft_limits == (-170.0, 170.0)
    assert axis.error_at_connect is None
    port.assert_complete()


def test_connect_with_given_limits_and_two_digit_address():
    steps = [(b"12TS\r\n", b"12TS00000A\r\n"), (b"12TE\r\n", b"12TEA\r\n")]
    axis, port = transcript_axis(steps, address=12, soft_limits=(-5.0, 5.0))
    assert axis.soft_limits == (-5.0, 5.0)
    assert axis.error_at_connect is not None and axis.error_at_connect.letter == "A"
    port.assert_complete()


def test_identity_transcript():
    steps = [*CONNECT,
             (b"1ID?\r\n", b"1IDURS100BCC_B12345\r\n"),
             (b"1VE\r\n", b"1VE SMC_CC - Controller-driver version 3.0.1\r\n")]
    axis, port = transcript_axis(steps)
    ident = axis.identity
    assert (ident.vendor, ident.serial) == ("Newport", "B12345")
    assert "URS100BCC" in ident.model
    assert ident.firmware == "SMC_CC - Controller-driver version 3.0.1"
    assert axis.identity is ident  # cached: no second exchange
    port.assert_complete()


def test_home_from_not_referenced_transcript():
    steps = [*CONNECT,
             # home(): the base class checks the axis is enabled (TS + TP) ...
             (b"1TS\r\n", b"1TS00000A\r\n"), (b"1TP\r\n", b"1TP3.000000\r\n"),
             # ... then the driver reads the state to choose OR or RS+OR
             (b"1TS\r\n", b"1TS00000A\r\n"),
             (b"1OR\r\n", b""),
             (b"1TE\r\n", b"1TE@\r\n"),
             (b"1TS\r\n", b"1TS00001E\r\n"), (b"1TP\r\n", b"1TP3.000000\r\n"),
             (b"1TS\r\n", b"1TS000032\r\n"), (b"1TP\r\n", b"1TP0.000000\r\n")]
    axis, port = transcript_axis(steps, poll_interval=0.0)
    axis.home()
    port.assert_complete()


def test_move_absolute_relative_and_wait_transcript():
    steps = [*CONNECT,
             # move_to(45.5): readiness check, PA, TE
             READY_TS, (b"1TP\r\n", b"1TP0.000000\r\n"),
             (b"1PA45.5\r\n", b""), (b"1TE\r\n", b"1TE@\r\n"),
             # wait(): MOVING, then READY from MOVING at the target
             (b"1TS\r\n", b"1TS000028\r\n"), (b"1TP\r\n", b"1TP20.100000\r\n"),
             READY_TS, (b"1TP\r\n", b"1TP45.500000\r\n"),
             # move_by(-1.25): readiness check, PR, TE
             READY_TS, (b"1TP\r\n", b"1TP45.500000\r\n"),
             (b"1PR-1.25\r\n", b""), (b"1TE\r\n", b"1TE@\r\n")]
    axis, port = transcript_axis(steps, poll_interval=0.0)
    axis.move_to(45.5)
    assert axis.wait(60) == pytest.approx(45.5)
    axis.move_by(-1.25)
    assert axis.target == pytest.approx(44.25)
    port.assert_complete()


def test_refused_move_maps_te_letter_to_typed_error():
    steps = [*CONNECT,
             READY_TS, (b"1TP\r\n", b"1TP0.000000\r\n"),
             (b"1PA10\r\n", b""), (b"1TE\r\n", b"1TEM\r\n"),
             READY_TS, (b"1TP\r\n", b"1TP0.000000\r\n"),
             (b"1PA11\r\n", b""), (b"1TE\r\n", b"1TEG\r\n"),
             READY_TS, (b"1TP\r\n", b"1TP0.000000\r\n"),
             (b"1PA12\r\n", b""), (b"1TE\r\n", b"1TEV\r\n")]
    axis, port = transcript_axis(steps)
    with pytest.raises(CommandRefused) as info:
        axis.move_to(10)
    assert isinstance(info.value, StateError) and info.value.code == "M"
    assert info.value.device == "theta" and info.value.command == "1PA10"
    assert "MOVING" in str(info.value)
    with pytest.raises(TargetOutOfLimits) as info:
        axis.move_to(11)
    assert isinstance(info.value, LimitError) and info.value.code == "G"
    with pytest.raises(ControllerError) as info:
        axis.move_to(12)
    assert info.value.code == "V" and "execution" in info.value.message
    port.assert_complete()


def test_status_decodes_limits_and_faults():
    steps = [*CONNECT,
             (b"1TS\r\n", b"1TS02023D\r\n"), (b"1TP\r\n", b"1TP50.000000\r\n"),
             (b"1TS\r\n", b"1TS00003C\r\n"), (b"1TP\r\n", b"1TP1.000000\r\n")]
    axis, port = transcript_axis(steps)
    status = axis.status()
    assert status.at_forward_limit and not status.at_reverse_limit
    assert not status.is_enabled and status.is_homed and not status.is_moving
    assert "80 W" in status.error and "positive end of run" not in status.error
    status = axis.status()
    assert status.error is None and not status.is_enabled
    port.assert_complete()


def test_velocity_acceleration_and_stop_transcript():
    steps = [*CONNECT,
             (b"1VA?\r\n", b"1VA20.000000\r\n"),
             (b"1VA7.5\r\n", b""), (b"1TE\r\n", b"1TE@\r\n"),
             (b"1AC?\r\n", b"1AC80.000000\r\n"),
             (b"1AC40\r\n", b""), (b"1TE\r\n", b"1TEC\r\n"),
             (b"1ST\r\n", b""), (b"1TE\r\n", b"1TE@\r\n")]
    axis, port = transcript_axis(steps)
    assert axis.velocity == 20.0
    axis.velocity = 7.5
    assert axis.acceleration == 80.0
    with pytest.raises(ControllerError) as info:
        axis.acceleration = 40
    assert info.value.code == "C" and info.value.command == "1AC40"
    axis.stop()
    port.assert_complete()


def test_home_when_referenced_resets_first_and_reapplies_velocity():
    steps = [*CONNECT,
             (b"1VA5\r\n", b""), (b"1TE\r\n", b"1TE@\r\n"),
             # the base class's enabled check (TS + TP), then the driver's state check
             READY_TS, (b"1TP\r\n", b"1TP0.000000\r\n"),
             READY_TS,
             (b"1RS\r\n", b""),
             (b"1TS\r\n", b""),  # rebooting: deaf
             (b"1TS\r\n", b"1TS00000A\r\n"), (b"1TE\r\n", b"1TE@\r\n"),
             (b"1VA5\r\n", b""), (b"1TE\r\n", b"1TE@\r\n"),
             (b"1OR\r\n", b""), (b"1TE\r\n", b"1TE@\r\n")]
    axis, port = transcript_axis(steps)
    axis.velocity = 5
    axis.home(wait=False)
    port.assert_complete()


def test_stale_and_foreign_lines_are_skipped_and_garbage_prefix_dropped():
    steps = [*CONNECT,
             # a late TP reply, a neighbour's TS and line noise before ours
             (b"1TS\r\n", b"1TP1.000000\r\n2TS000033\r\n\x07#\r\n\xfe1TS000033\r\n"),
             (b"1TP\r\n", b"1TP2.000000\r\n")]
    axis, port = transcript_axis(steps)
    status = axis.status()
    assert status.position == 2.0 and status.is_homed
    assert axis.skipped_lines == 3
    port.assert_complete()


def test_garbled_query_is_retried_but_te_is_not():
    steps = [*CONNECT,
             (b"1TP\r\n", b"1TPabc\r\n"), (b"1TP\r\n", b"1TP3.500000\r\n"),
             (b"1ST\r\n", b""), (b"1TE\r\n", b"1TE?\r\n")]
    axis, port = transcript_axis(steps)
    assert axis.position == 3.5
    with pytest.raises(ProtocolError) as info:
        axis.stop()
    assert info.value.command == "1ST" and info.value.device == "theta"
    port.assert_complete()


def test_silence_after_stale_reply_is_timeout_after_noise_is_protocol_error():
    steps = [*CONNECT,
             (b"1ST\r\n", b""), (b"1TE\r\n", b"1TP1.000000\r\n"),   # stale, then silence
             (b"1ST\r\n", b""), (b"1TE\r\n", b"\x15\x80~\r\n")]     # noise, then silence
    axis, port = transcript_axis(steps)
    with pytest.raises(DeviceTimeout) as timeout_info:
        axis.stop()
    assert timeout_info.value.command == "1ST"
    with pytest.raises(ProtocolError) as noise_info:
        axis.stop()
    assert "noise" in str(noise_info.value) and noise_info.value.command == "1ST"
    port.assert_complete()


def test_query_gives_up_after_retries_with_typed_error():
    steps = [*CONNECT, *[(b"1TP\r\n", b"")] * 3]
    axis, port = transcript_axis(steps, retries=2)
    with pytest.raises(DeviceTimeout) as info:
        axis.position  # noqa: B018
    assert "3 attempts" in str(info.value) and info.value.command == "1TP"
    port.assert_complete()


def test_constructor_without_answer_is_connection_failed():
    port = TranscriptSerial([(b"1TS\r\n", b"")] * 3, baudrate=57600)
    with pytest.raises(ConnectionFailed) as info:
        Smc100Axis(port, name="theta", reply_timeout=0.5)
    assert isinstance(info.value.__cause__, DeviceTimeout)
    assert "address 1" in str(info.value)


def test_arguments_are_validated_before_opening():
    with pytest.raises(ValueError):
        Smc100Axis("simsmc://x", name="t", address=0)
    with pytest.raises(ValueError):
        Smc100Axis("simsmc://x", name="t", retries=-1)
    with pytest.raises(ConnectionFailed):
        Smc100Axis("simnothing://x", name="t")


def test_errors_pickle_with_code():
    err = CommandRefused("refused", code="M", device="theta", command="1PA1")
    back = pickle.loads(pickle.dumps(err))
    assert isinstance(back, CommandRefused) and back.code == "M" and back.device == "theta"
    assert issubclass(NotReferencedError, NotHomedError)


# --------------------------------------------------------------------------- contract


def open_axis(transport: str, name: str, *, kind: str = "rotary", cleanup: list,
              **kw) -> Smc100Axis:
    if transport == "url":
        return open_patiently(Smc100Axis, f"simsmc://{name}?kind={kind}&speed={SPEED:g}",
                              name=name, kind=kind, **kw)
    emulator = Smc100Emulator(name, kind=kind, clock=ScaledClock(SPEED))
    server = PtyServer(emulator)
    cleanup.append(server)
    axis = open_patiently(Smc100Axis, server.path, name=name, kind=kind, **kw)
    axis.emulator = emulator  # test-side handle on the far end
    return axis


def emulator_of(axis: Smc100Axis) -> Smc100Emulator:
    return getattr(axis, "emulator", None) or registry.get("simsmc", axis.name)


@pytest.fixture
def clock_of():
    """The contract's handle on emulated time."""
    return lambda axis: emulator_of(axis).clock


class TestContractRotary(MotionAxisContract):
    @pytest.fixture
    def axis_factory(self, transport, servers):
        count = iter(range(100))
        return lambda: open_axis(transport, f"rot{next(count)}", cleanup=servers)


class TestContractLinear(MotionAxisContract):
    @pytest.fixture
    def axis_factory(self, transport, servers):
        count = iter(range(100))
        return lambda: open_axis(transport, f"lin{next(count)}", kind="linear",
                                 cleanup=servers)


class TestContractSteppingClock(MotionAxisContract):
    """In-process with a stepping clock: simulated time passes only as the driver polls."""

    @pytest.fixture
    def axis_factory(self):
        names = (f"step{n}" for n in range(100))  # the axis is named as its emulator
        return lambda: Smc100Axis(f"simsmc://{(name := next(names))}?step=0.005", name=name)


# --------------------------------------------------------------------------- behaviour


@pytest.fixture
def homed(transport, servers):
    axis = open_axis(transport, "beh", cleanup=servers)
    axis.home(timeout=10)
    yield axis
    axis.close()


def test_units_follow_kind_and_physical_stage_follows(homed):
    assert homed.kind is AxisKind.ROTARY and homed.units == "deg"
    homed.move_to(12.5, wait=True, timeout=10)
    assert emulator_of(homed).stage.physical_position() == pytest.approx(12.5, abs=1e-6)


def test_homing_reaches_physical_zero_from_power_up_offset(transport, servers):
    axis = open_axis(transport, "off", kind="linear", cleanup=servers)
    emulator = emulator_of(axis)
    assert emulator.stage.physical_position() == pytest.approx(12.0)
    assert axis.position == pytest.approx(0.0)  # the counter reads 0 at power-up
    axis.home(timeout=10)
    assert emulator.stage.physical_position() == pytest.approx(0.0, abs=1e-9)
    axis.close()


def test_rehome_after_moves_resets_and_keeps_velocity(homed):
    homed.velocity = 5.0
    homed.move_to(3.0, wait=True, timeout=10)
    homed.home(timeout=10)
    assert homed.position == pytest.approx(0.0, abs=homed.position_tolerance)
    assert homed.velocity == pytest.approx(5.0)


def test_limit_switch_stop_raises_limit_error_and_recovers(homed):
    emulator = emulator_of(homed)
    emulator.stage.travel = (-5.0, 5.0)  # switches inside the software limits
    homed.move_to(8.0)
    with pytest.raises(LimitError) as info:
        homed.wait(60)
    assert info.value.device == "beh" and info.value.command == "wait"
    status = homed.status()
    assert status.at_forward_limit and not status.is_enabled
    assert status.position == pytest.approx(5.0, abs=1e-6)
    homed.enable()
    homed.move_to(0.0, wait=True, timeout=10)
    assert not homed.status().at_forward_limit


def test_move_while_moving_is_refused_with_state_error(homed):
    # 3000 s of emulated motion (15 s at SPEED): still moving when the second command
    # arrives however late a loaded machine schedules it (10 mm at 0.5 was over in 0.1 s)
    homed.velocity = 0.05
    homed.move_to(150.0)
    with pytest.raises(CommandRefused) as info:
        homed.move_to(2.0)
    assert info.value.code == "M"
    homed.stop()


def test_controller_limit_refusal_when_driver_limits_are_wider(transport, servers):
    axis = open_axis(transport, "wide", cleanup=servers, soft_limits=(-500.0, 500.0))
    axis.home(timeout=10)
    with pytest.raises(TargetOutOfLimits) as info:
        axis.move_to(200.0)
    assert info.value.code == "G"
    assert not axis.is_moving
    axis.close()


def test_disable_in_not_referenced_is_refused(transport, servers):
    axis = open_axis(transport, "nr", cleanup=servers)
    with pytest.raises(StateError):
        axis.disable()
    axis.close()


def test_homing_timeout_is_a_controller_error_then_rehome_works(homed):
    emulator = emulator_of(homed)
    homed.move_to(20.0, wait=True, timeout=10)
    with emulator.lock:  # 20 deg at OH = 10 deg/s cannot finish within OT = 0.5 s
        emulator.stored["OT"] = emulator.params["OT"] = 0.5
    with pytest.raises(ControllerError) as info:
        homed.home(timeout=10)
    assert "homing time-out" in str(info.value) and info.value.code == 0x0040
    assert info.value.device == "beh" and info.value.command == "home"
    assert not homed.is_homed
    with emulator.lock:
        emulator.stored["OT"] = emulator.params["OT"] = 120.0
    homed.home(timeout=10)
    assert homed.is_homed and homed.status().error is None


# --------------------------------------------------------------------------- faults


@pytest.fixture
def faulty(homed):
    """A homed axis with a short reply timeout and the emulator's fault injector."""
    homed.reply_timeout = 0.1
    return homed, emulator_of(homed).faults


@pytest.mark.parametrize("kind, params", QUERY_FAULTS)
def test_query_faults_recover_by_retry(faulty, kind, params):
    axis, faults = faulty
    axis.move_to(4.0, wait=True, timeout=10)
    axis.retries = QUERY_RETRIES
    query_survives(faults, kind, params, lambda: round(axis.position, 6), 4.0)


def test_corrupted_replies_are_retried_or_decoded_never_hang(faulty):
    """Bit flips: most break the echo, the terminator or the number and are retried.

    The SMC100 protocol has no checksum, so a flip that turns one digit into another
    is decoded as a (wrong) number: the test counts those instead of hiding them.
    """
    axis, faults = faulty
    axis.move_to(4.0, wait=True, timeout=10)
    got = corrupted_reads(lambda: axis.position, lambda v: v == pytest.approx(4.0, abs=1e-6),
                          faults, n=30, device="beh", command="1TP")
    assert got.failed == 0  # one corrupted reply never exhausts the retries
    assert got.right >= 15 and got.right + got.wrong == 30


@pytest.mark.parametrize("late", [False, True], ids=["lost", "late"])
def test_lost_te_reply_is_a_typed_error_never_retried(faulty, late):
    """PA's check ``TE`` is lost, or late (held on the wire until the driver has given
    up, then let in ahead of the next command)."""
    axis, faults = faulty
    axis.reply_timeout = 0.1
    # the readiness queries before PA (TS, TP) may time out on a loaded host's pty and be
    # retried: retries enough for that, and the fault aimed at the first TE reply rather
    # than at the third reply, which a retry would move onto TP
    axis.retries = QUERY_RETRIES
    before = len(emulator_of(axis).received_log)
    release = lose_or_hold_reply(faults, late=late, on=b"TE")
    with pytest.raises(DeviceTimeout) as info:
        axis.move_to(3.0)
    assert info.value.command == "1PA3" and info.value.device == "beh"
    assert "TE" in str(info.value)
    if release is not None:
        let_held_reply_arrive(release, axis._channel.port)  # the host's end of the link
    sent = bytes(emulator_of(axis).received_log[before:])
    assert sent.count(b"1TE\r\n") == 1  # reading TE clears it: never asked twice
    # The documented recovery: the outcome is learnt from status; the move did start.
    axis.wait(60)
    assert axis.position == pytest.approx(3.0, abs=1e-6)


def test_a_late_ready_reply_from_before_the_move_never_ends_the_wait(servers):
    """The readiness poll's TS (READY) arrives after the timeout while the move it preceded
    runs: the retry takes it (same query, same answer), the retry's own reply is dropped
    as stale input before the next request, and no later poll reads READY mid-move.

    In-process link: a late frame is never part of a read whose deadline passed, however
    loaded the host; emulated time stands while the move must be seen in progress."""
    axis = open_axis("url", "late", cleanup=servers, reply_timeout=0.1)
    servers.append(axis)
    axis.home(timeout=60)
    emulator = emulator_of(axis)
    with emulator.clock.held():
        emulator.faults.schedule(FaultKind.DELAY, nth=1, delay_s=0.15)  # TS: READY
        axis.move_to(4.0)
        for _ in range(3):
            status = axis.status()
            assert status.is_moving and status.position == pytest.approx(0.0, abs=1e-6)
    assert axis.wait(60) == pytest.approx(4.0, abs=1e-6)
    assert [k for _, k in emulator.faults.log] == [FaultKind.DELAY]


def test_random_faults_on_a_long_session_never_hang(faulty):
    """Random faults: each operation succeeds or raises a typed error naming its command."""
    motion_fault_session(*faulty)


def test_disconnect_is_typed_and_reconnect_finds_same_state(transport, servers):
    """In-process the link raises (ConnectionFailed); a pty stays open but the dead
    device answers nothing (DeviceTimeout after the retries). Either way, within bounds."""
    axis = open_axis(transport, "dc", cleanup=servers)
    axis.home(timeout=10)
    axis.move_to(2.0, wait=True, timeout=10)
    axis.reply_timeout = 0.1
    axis = unplug_during_query(axis, emulator_of(axis), transport,
                               lambda: open_axis(transport, "dc", cleanup=servers),
                               command="1TP")
    assert axis.is_homed and axis.position == pytest.approx(2.0, abs=1e-6)
    axis.close()


def test_unplugged_mid_move_is_typed_and_the_move_is_found_finished(transport, servers):
    """The controller finishes a move on its own while the cable is out; after the
    reconnect the driver reads where it ended. Bounded either way."""
    axis = open_axis(transport, "mid", cleanup=servers)
    axis.home(timeout=10)
    axis.velocity = 2.0
    axis.move_to(6.0)  # 3 s of emulated time: 15 ms at SPEED
    axis.reply_timeout = 0.1
    axis = unplug_during_move(axis, emulator_of(axis), transport,
                              lambda: open_axis(transport, "mid", cleanup=servers),
                              command="1TS")
    assert axis.is_homed
    assert axis.position == pytest.approx(6.0, abs=1e-6)
    axis.close()


def test_error_state_during_move_raises_controller_error_and_enable_recovers(faulty):
    axis, faults = faulty
    # no lost or late reply is injected here: a generous deadline, so that a loaded host's
    # emulator thread on a pty (not the fault under test) cannot time a reply out
    axis.reply_timeout = 5.0
    axis.velocity = 1.0
    # Emulated time stands while the fault is injected, so the move is still on when the
    # first poll of the wait meets it, whatever the host's load (on the running clock a
    # loaded host could reach that poll after the 25 ms the move takes at SPEED: READY).
    with emulator_of(axis).clock.held():
        axis.move_to(5.0)
        faults.schedule(FaultKind.ERROR_STATE, nth=1, code="0020")
        with pytest.raises(ControllerError) as info:
            axis.wait(60)
        assert "following error" in str(info.value) and info.value.code == 0x0020
        assert info.value.device == "beh"
        assert not axis.is_enabled
    axis.enable()
    axis.velocity = 20.0
    axis.move_to(1.0, wait=True, timeout=10)
    assert axis.status().error is None


def test_wrong_baud_rate_fails_to_connect_quickly():
    import serial

    port = serial.serial_for_url("simsmc://baud?speed=200", baudrate=9600, timeout=0.01)
    with pytest.raises(ConnectionFailed):
        Smc100Axis(port, name="baud", reply_timeout=0.05)


# --------------------------------------------------------------------------- real hardware


@pytest.mark.hardware
def test_real_controller_identity_and_status():
    """Opt-in: ``SCATTERLAB_HW_SMC100=/dev/ttyUSB0`` (and ``..._ADDRESS``). Moves nothing."""
    import os

    port = os.environ.get("SCATTERLAB_HW_SMC100")
    if not port:
        pytest.skip("set SCATTERLAB_HW_SMC100 to the controller's port to run")
    address = int(os.environ.get("SCATTERLAB_HW_SMC100_ADDRESS", "1"))
    with Smc100Axis(port, name="hw_smc100", address=address, reply_timeout=1.0) as axis:
        ident = axis.identity
        assert ident.vendor == "Newport" and ident.firmware
        status = axis.status()
        assert status.error is None, status.error
        low, high = axis.soft_limits
        assert low <= 0.0 <= high
        assert axis.velocity > 0 and axis.acceleration > 0
