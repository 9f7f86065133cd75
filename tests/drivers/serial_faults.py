"""Fault scenarios shared by the tests of the serial motion drivers (SMC100, Zaber).

Each helper drives one scenario through a driver on an emulator with a seeded fault
injector and asserts what every serial motion driver owes its user: recovery or a typed
error naming the device and the command, within a bounded time, and the same device state
found again after a replug. The driver's test module supplies the axis, the emulator and
how to reopen it.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from drivers.base import MotionAxis
from drivers.errors import ConnectionFailed, DeviceError, DeviceTimeout
from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.faults import FaultInjector, FaultKind

#: Faults a retried query must survive, with parameters for a 0.1 s reply timeout: the
#: delay is longer than one reply timeout and shorter than all three attempts.
QUERY_FAULTS = [
    (FaultKind.DROP, {}),
    (FaultKind.DELAY, {"delay_s": 0.15}),
    (FaultKind.SPLIT, {"chunks": 4, "gap_s": 0.01}),
    (FaultKind.GARBAGE, {"nbytes": 5}),
    (FaultKind.UNSOLICITED, {}),
]


def query_survives(faults: FaultInjector, kind: FaultKind, params: dict,
                   read: Callable[[], object], expected: object, *, times: int = 5) -> None:
    """``read()`` returns ``expected`` within 2 s although each reply meets ``kind``."""
    for _ in range(times):
        faults.schedule(kind, nth=1, **params)
        t0 = time.monotonic()
        assert read() == expected
        assert time.monotonic() - t0 < 2.0
    assert [k for _, k in faults.log] == [kind] * times


def random_fault_session(axis: MotionAxis, faults: FaultInjector, *, moves: int = 30) -> None:
    """Random faults: each move succeeds or raises a typed error naming its command."""
    for kind in (FaultKind.DROP, FaultKind.GARBAGE, FaultKind.SPLIT,
                 FaultKind.UNSOLICITED, FaultKind.DELAY):
        faults.randomly(kind, 0.05, gap_s=0.002, nbytes=3, delay_s=0.15)
    ok = typed = 0
    t0 = time.monotonic()
    for i in range(moves):
        try:
            axis.move_to((i % 5) - 2.0, wait=True, timeout=5)
            ok += 1
        except DeviceError as err:
            assert err.device == axis.name and err.command
            typed += 1
            time.sleep(0.2)  # let a late reply or a started move finish
    assert time.monotonic() - t0 < 60
    assert ok + typed == moves and ok >= moves // 2
    assert len(faults.log) >= 5


def _unplugged_error(transport: str) -> type[DeviceError]:
    # In-process the link raises; a pty stays open but the dead device answers nothing.
    return ConnectionFailed if transport == "url" else DeviceTimeout


def replug(axis: MotionAxis, emulator: FirmwareEmulator, transport: str,
           reopen: Callable[[], MotionAxis]) -> MotionAxis:
    """The cable is back: in-process close and open anew; on a pty the same port works."""
    if transport == "url":
        axis.close()
        return reopen()
    emulator.faults.reconnect()
    return axis


def unplug_during_query(axis: MotionAxis, emulator: FirmwareEmulator, transport: str,
                        reopen: Callable[[], MotionAxis], *, command: str) -> MotionAxis:
    """Unplug before a position query: a typed error naming ``command`` within 2 s.

    Returns the axis to use after the replug.
    """
    emulator.faults.schedule(FaultKind.DISCONNECT, nth=1)
    t0 = time.monotonic()
    with pytest.raises(_unplugged_error(transport)) as info:
        axis.position  # noqa: B018
    assert time.monotonic() - t0 < 2.0
    assert info.value.device == axis.name and info.value.command == command
    return replug(axis, emulator, transport, reopen)


def unplug_during_move(axis: MotionAxis, emulator: FirmwareEmulator, transport: str,
                       reopen: Callable[[], MotionAxis], *,
                       command: str | None = None) -> MotionAxis:
    """Unplug while waiting for a move: a typed error within 2 s, chained from its cause.

    The controller finishes the move on its own; the axis returned (after the replug) has
    come to rest, so the caller can check where.
    """
    emulator.faults.schedule(FaultKind.DISCONNECT, nth=1)
    t0 = time.monotonic()
    with pytest.raises(_unplugged_error(transport)) as info:
        axis.wait(10)
    assert time.monotonic() - t0 < 2.0
    assert info.value.device == axis.name and info.value.__cause__ is not None
    if command is not None:
        assert info.value.command == command
    axis = replug(axis, emulator, transport, reopen)
    deadline = time.monotonic() + 5.0
    while axis.is_moving and time.monotonic() < deadline:
        time.sleep(0.005)
    return axis
