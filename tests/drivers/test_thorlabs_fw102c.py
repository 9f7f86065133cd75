"""Fw102cWheel: byte-exact transcripts, the filter-wheel contract on both transports, jams.

Transcripts pin the exact bytes (``pos=n`` is one exchange whose prompt comes on arrival;
it is never repeated). The contract suite runs the driver against the independent FW102C
emulator in-process (``simfw102c://``) and through a real pseudo-terminal, with the
emulated wheel turning ``SPEED`` times faster than a real one. A jammed wheel must end in
a typed error that names the wheel and says what to do, within the move timeout.
"""

from __future__ import annotations

import time

import pytest

from drivers.base import FilterSpec, WheelSpeed
from drivers.errors import (
    ConnectionFailed,
    DeviceTimeout,
    LimitError,
    MotionError,
)
from drivers.thorlabs_fw102c import (
    CommandRejected,
    Fw102cWheel,
    WheelJammed,
    WheelMoveTimeout,
)
from hw_mocks import registry
from hw_mocks.clock import ScaledClock
from hw_mocks.faults import FaultKind
from hw_mocks.firmware.fw102c import Fw102cEmulator
from hw_mocks.pty_server import PtyServer
from hw_mocks.transcript import TranscriptSerial
from tests.drivers.fault_checks import corrupted_reads, random_fault_session
from tests.drivers.filter_wheel_contract import FilterWheelContract
from tests.drivers.serial_faults import QUERY_FAULTS, QUERY_RETRIES, query_survives
from tests.waiting import wait_for

SPEED = 50.0
IDN = b"THORLABS FW102C/FW212C Filter Wheel version 1.07"
RESYNC = (b"\r", b"\rCommand error CMD_NOT_DEFINED\n\r> ")


def q(keyword: str, value: str) -> tuple[bytes, bytes]:
    request = f"{keyword}?\r".encode()
    return request, request + value.encode() + b"\r> "


CONNECT = [RESYNC, (b"*idn?\r", b"*idn?\r" + IDN + b"\r> "), q("pcount", "6")]


def transcript_wheel(steps, **kw) -> tuple[Fw102cWheel, TranscriptSerial]:
    port = TranscriptSerial(steps, baudrate=115200)
    kw.setdefault("reply_timeout", 0.05)
    return Fw102cWheel(port, name="wheel", **kw), port


# --------------------------------------------------------------------------- transcripts


def test_connect_identity_and_filters():
    wheel, port = transcript_wheel(
        CONNECT, filters={"3": {"center_nm": 532, "bandwidth_nm": 10, "label": "green"}})
    ident = wheel.identity
    assert (ident.vendor, ident.model, ident.firmware) == ("Thorlabs", "FW102C", "1.07")
    assert wheel.position_count == 6
    assert wheel.filters == {3: FilterSpec(532, 10, "green")}
    port.assert_complete()


def test_move_is_one_exchange_then_a_position_check():
    steps = [*CONNECT,
             q("pos", "1"), q("speed", "1"),  # the default timeout's estimate
             (b"pos=4\r", b"pos=4\r> "), q("pos", "4"),
             (b"pos=4\r", b"pos=4\r> "), q("pos", "4")]
    wheel, port = transcript_wheel(steps)
    assert wheel.move_to(4) == 4
    assert wheel.move_to(4, timeout=1.0) == 4  # explicit timeout: no estimate needed
    port.assert_complete()


def test_speed_set_reads_back_and_estimates_use_it():
    steps = [*CONNECT, (b"speed=0\r", b"speed=0\r> "), q("speed", "0"),
             q("pos", "1"), (b"speed=1\r", b"speed=1\r> "), q("speed", "1"), q("pos", "1")]
    wheel, port = transcript_wheel(steps)
    wheel.speed = "normal"
    slow = wheel.estimated_move_s(4)
    wheel.speed = WheelSpeed.HIGH
    fast = wheel.estimated_move_s(4)
    # half a turn: 3 s at high speed (hispec's observation), twice that at normal speed
    assert fast == pytest.approx(3.0 + 0.3) and slow == pytest.approx(6.0 + 0.3)
    port.assert_complete()


def test_speed_given_at_connect_is_set():
    steps = [*CONNECT, (b"speed=1\r", b"speed=1\r> "), q("speed", "1")]
    _, port = transcript_wheel(steps, speed="high")
    port.assert_complete()


def test_silent_jam_is_a_typed_timeout_naming_the_wheel():
    steps = [*CONNECT, (b"pos=2\r", b"pos=2\r"), (b"pos?\r", b"")]
    wheel, port = transcript_wheel(steps)
    with pytest.raises(WheelMoveTimeout) as info:
        wheel.move_to(2, timeout=0.1)
    err = info.value
    assert isinstance(err, DeviceTimeout) and isinstance(err, WheelJammed)
    assert isinstance(err, MotionError)
    assert err.device == "wheel" and err.command == "pos=2"
    assert "jammed" in str(err) and "power-cycle" in err.hint
    port.assert_complete()


def test_lost_prompt_is_recovered_by_asking_where_the_wheel_is():
    steps = [*CONNECT, (b"pos=2\r", b"pos=2\r"), q("pos", "2"), q("pos", "2")]
    wheel, port = transcript_wheel(steps)
    assert wheel.move_to(2, timeout=0.1) == 2
    port.assert_complete()


def test_wheel_that_stops_at_another_slot_is_jammed():
    steps = [*CONNECT, (b"pos=3\r", b"pos=3\r> "), q("pos", "2")]
    wheel, port = transcript_wheel(steps)
    with pytest.raises(WheelJammed) as info:
        wheel.move_to(3, timeout=1.0)
    assert "slot 2" in str(info.value) and info.value.device == "wheel"
    assert "obstruction" in info.value.hint
    port.assert_complete()


def test_slot_outside_the_wheel_sends_nothing():
    wheel, port = transcript_wheel(CONNECT)
    with pytest.raises(LimitError):
        wheel.move_to(7)
    with pytest.raises(LimitError):
        wheel.filter_at(0)
    port.assert_complete()


def test_rejected_move_is_a_typed_error():
    steps = [*CONNECT, (b"pos=5\r", b"pos=5\rCommand error CMD_ARG_INVALID\n\r> ")]
    wheel, port = transcript_wheel(steps)
    with pytest.raises(CommandRejected) as info:
        wheel.move_to(5, timeout=1.0)
    assert info.value.code == "CMD_ARG_INVALID" and info.value.command == "pos=5"
    port.assert_complete()


def test_garbled_position_is_retried():
    steps = [*CONNECT, (b"pos?\r", b"pos?\r9\r> "), (b"pos?\r", b"pos?\r\x02\r> "),
             q("pos", "5")]
    wheel, port = transcript_wheel(steps)
    assert wheel.position == 5
    port.assert_complete()


@pytest.mark.parametrize("steps, message", [
    ([(b"\r", b""), *[(b"*idn?\r", b"")] * 3], "no FW102C/FW212C answers"),
    ([RESYNC, (b"*idn?\r", b"*idn?\rTHORLABS SC10 VERSION 1.07\r> ")], "not an FW102C"),
    ([*CONNECT[:2], q("pcount", "8")], "8 slots"),
])
def test_connect_failures_are_connection_failed(steps, message):
    port = TranscriptSerial(steps, baudrate=115200)
    with pytest.raises(ConnectionFailed) as info:
        Fw102cWheel(port, name="wheel", reply_timeout=0.5)
    assert message in str(info.value)


def test_jam_errors_pickle_with_their_types():
    import pickle

    err = WheelMoveTimeout("stuck", device="wheel", command="pos=2", hint="power-cycle")
    back = pickle.loads(pickle.dumps(err))
    assert isinstance(back, WheelMoveTimeout) and isinstance(back, DeviceTimeout)
    assert (back.device, back.command, back.hint) == ("wheel", "pos=2", "power-cycle")


def test_arguments_are_validated_before_opening():
    with pytest.raises(ValueError):
        Fw102cWheel("simfw102c://x", name="w", baudrate=57600)
    with pytest.raises(ValueError):
        Fw102cWheel("simfw102c://x", name="w", move_timeout_factor=0)
    with pytest.raises(ValueError):
        Fw102cWheel("simfw102c://x", name="w", filters={"first": {}})
    with pytest.raises(ConnectionFailed):
        Fw102cWheel("simnothing://x", name="w")


# --------------------------------------------------------------------------- contract


def open_wheel(transport: str, name: str, *, cleanup: list, slots: int = 6,
               **kw) -> Fw102cWheel:
    if transport == "url":
        return Fw102cWheel(f"simfw102c://{name}?slots={slots}&speed={SPEED:g}", name=name,
                           **kw)
    emulator = Fw102cEmulator(name, slots=slots, clock=ScaledClock(SPEED))
    server = PtyServer(emulator)
    cleanup.append(server)
    wheel = Fw102cWheel(server.path, name=name, **kw)
    wheel.emulator = emulator
    return wheel


def emulator_of(wheel: Fw102cWheel) -> Fw102cEmulator:
    return getattr(wheel, "emulator", None) or registry.get("simfw102c", wheel.name)


class TestContractSixSlots(FilterWheelContract):
    @pytest.fixture
    def wheel_factory(self, transport, servers):
        count = iter(range(100))
        return lambda **kw: open_wheel(transport, f"fw{next(count)}", cleanup=servers, **kw)


class TestContractTwelveSlots(FilterWheelContract):
    @pytest.fixture
    def wheel_factory(self, transport, servers):
        count = iter(range(100))
        return lambda **kw: open_wheel(transport, f"fw12_{next(count)}", cleanup=servers,
                                       slots=12, **kw)


# --------------------------------------------------------------------------- behaviour


@pytest.fixture
def wheel(transport, servers):
    device = open_wheel(transport, "beh", cleanup=servers)
    device.move_timeout_margin_s = 0.5
    yield device
    device.close()


def test_the_physical_wheel_follows_and_takes_the_short_way(wheel):
    emulator = emulator_of(wheel)
    wheel.move_to(6)  # 1 -> 6 is one slot backwards
    assert emulator.slot_at_beam() == 6 and emulator.moves == 1
    assert emulator.move_duration_s(6, 1) == pytest.approx(emulator.move_duration_s(1, 2))


def test_silent_jam_raises_within_the_timeout_and_a_power_cycle_recovers(wheel):
    emulator = emulator_of(wheel)
    wheel._link.reply_timeout = 0.1
    emulator.jam("silent")
    timeout = 0.5
    with pytest.raises(WheelMoveTimeout) as info:
        wheel.move_to(4, timeout=timeout)
    assert info.value.device == "beh" and "power-cycle" in info.value.hint
    assert emulator.slot_at_beam() is None  # stuck between slots: the beam is blocked
    with pytest.raises(DeviceTimeout):  # still inside pos=: deaf
        wheel.position  # noqa: B018
    emulator.power_off()
    emulator.power_on()  # the wheel settles on the nearest slot
    assert wheel.position == emulator.slot_at_beam()
    assert wheel.move_to(2) == 2


def test_cleared_jam_completes_late_and_the_late_prompt_is_skipped(wheel):
    emulator = emulator_of(wheel)
    wheel._link.reply_timeout = 0.1
    emulator.jam("silent")
    with pytest.raises(WheelMoveTimeout):
        wheel.move_to(3, timeout=0.3)
    emulator.clear_jam()  # the obstruction is gone: the move completes, its prompt comes late
    # Waited for on the emulator, not slept: a loaded host may take any time to get there.
    wait_for(lambda: emulator.slot_at_beam() == 3, what="the freed wheel to reach slot 3")
    assert wheel.position == 3
    assert wheel.move_to(5) == 5


def test_stalled_wheel_is_jammed_at_the_slot_it_reached(wheel):
    emulator = emulator_of(wheel)
    emulator.jam("stall", fraction=0.6)
    with pytest.raises(WheelJammed) as info:
        wheel.move_to(4)  # three slots forward; it gives up after passing slot 2
    assert not isinstance(info.value, DeviceTimeout)
    assert "slot 2" in str(info.value)
    assert wheel.position == 2 and emulator.slot_at_beam() == 2
    assert wheel.move_to(4) == 4  # the jam is gone


def test_error_state_fault_jams_the_next_move(wheel):
    emulator = emulator_of(wheel)
    emulator.faults.schedule(FaultKind.ERROR_STATE, nth=1, code="stall")
    wheel.position  # noqa: B018 - this answer carries the fault
    with pytest.raises(WheelJammed):
        wheel.move_to(3)


@pytest.mark.parametrize("kind, params", QUERY_FAULTS)
def test_query_faults_recover_by_retry(wheel, kind, params):
    wheel._link.reply_timeout = 0.1
    wheel._link.retries = QUERY_RETRIES
    query_survives(emulator_of(wheel).faults, kind, params, lambda: wheel.position, 1)


def test_lost_prompt_after_a_real_move_is_recovered(wheel):
    emulator = emulator_of(wheel)
    wheel._link.reply_timeout = 0.1
    wheel._link.retries = QUERY_RETRIES  # the position query that recovers, on a loaded pty
    emulator.faults.schedule(FaultKind.DROP, nth=2)  # frames: echo, then the prompt
    assert wheel.move_to(2, timeout=0.5) == 2


def test_random_faults_never_hang(wheel):
    wheel._link.reply_timeout = 0.1
    got = random_fault_session(lambda i: wheel.move_to(i % 6 + 1, timeout=1.0),
                               emulator_of(wheel).faults, n=20, device="beh",
                               after_failure=lambda: time.sleep(0.2))  # late prompts arrive
    assert got.right + got.failed == 20 and got.right >= 12


def test_wheel_that_does_not_answer_is_typed_and_bounded(wheel):
    wheel._link.reply_timeout = 0.1
    emulator_of(wheel).power_off()
    with pytest.raises(WheelMoveTimeout):
        wheel.move_to(3, timeout=0.3)
    with pytest.raises(DeviceTimeout):
        wheel.position  # noqa: B018


def test_corrupted_answers_are_retried_or_typed(wheel):
    wheel._link.reply_timeout = 0.1
    got = corrupted_reads(lambda: wheel.position, lambda slot: slot == 1,
                          emulator_of(wheel).faults, n=20, device="beh", command="pos?")
    # No checksum: a flip of "1" into another digit 1..6 would read as that slot; count it.
    assert got.failed == 0 and got.right >= 15


# --------------------------------------------------------------------------- real hardware


@pytest.mark.hardware
def test_real_fw102c_identity_and_position():
    """Opt-in: ``SCATTERLAB_HW_FW102C=/dev/ttyUSB0``. Reads only; the wheel is not moved."""
    import os

    port = os.environ.get("SCATTERLAB_HW_FW102C")
    if not port:
        pytest.skip("set SCATTERLAB_HW_FW102C to the wheel's port to run")
    with Fw102cWheel(port, name="hw_fw102c", reply_timeout=1.0) as wheel:
        assert wheel.identity.vendor == "Thorlabs"
        assert wheel.position_count in (6, 12)
        assert 1 <= wheel.position <= wheel.position_count
