"""Fault scenarios shared by the tests of the serial motion drivers (SMC100, Zaber).

Built on the device-agnostic loops of :mod:`tests.drivers.fault_checks`.

Each helper drives one scenario through a driver on an emulator with a seeded fault
injector and asserts what every serial motion driver owes its user: recovery or a typed
error naming the device and the command after a bounded number of attempts, and the same
device state found again after a replug. "Bounded" is checked by counting, never by timing
(elapsed wall-clock time depends on the machine's load); a hang is caught by the suite's
``pytest-timeout``. The driver's test module supplies the axis, the emulator and
how to reopen it.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable
from typing import TypeVar

from drivers.base import MotionAxis
from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.faults import FaultInjector, FaultKind
from tests.drivers.fault_checks import random_fault_session, unplug_and_replug

_Device = TypeVar("_Device", bound=MotionAxis)

#: Reply timeout of the queries a driver sends while it connects in these tests (status,
#: the error latch, limits). Over a pty the replies come only when the emulator's thread
#: runs: under two busy loops the SMC100's connect-time ``TE``, which is never retried
#: (reading clears the latch), once missed the driver's default 0.5 s.
CONNECT_REPLY_TIMEOUT_S = 5.0


def open_patiently(cls: type[_Device], *args: object, **kw: object) -> _Device:
    """``cls(*args, **kw)``, connecting with :data:`CONNECT_REPLY_TIMEOUT_S`.

    The opened device then keeps the ``reply_timeout`` the caller asked for, or the
    driver's default: the tests that time replies out on purpose see the value they set.
    """
    wanted = kw.pop("reply_timeout",
                    inspect.signature(cls).parameters["reply_timeout"].default)
    device = cls(*args, reply_timeout=CONNECT_REPLY_TIMEOUT_S, **kw)
    device.reply_timeout = wanted  # type: ignore[attr-defined]
    return device


#: Faults a retried query must survive, with parameters for a 0.1 s reply timeout: the
#: delay is longer than one reply timeout, so the first attempt always times out.
QUERY_FAULTS = [
    (FaultKind.DROP, {}),
    (FaultKind.DELAY, {"delay_s": 0.15}),
    (FaultKind.SPLIT, {"chunks": 4, "gap_s": 0.01}),
    (FaultKind.GARBAGE, {"nbytes": 5}),
    (FaultKind.UNSOLICITED, {}),
]


#: Attempts after the first that a :data:`QUERY_FAULTS` test gives the driver. Over a real
#: pseudo-terminal the late reply, and the retry's reply queued behind it, reach the host
#: only when the emulator's thread runs: on a loaded box that thread once waited past all
#: three 0.1 s attempts (``DeviceTimeout`` after 3 attempts, SMC100 over a pty under two
#: busy loops at load 22). More attempts cost nothing when the replies come in time.
QUERY_RETRIES = 10


def query_survives(faults: FaultInjector, kind: FaultKind, params: dict,
                   read: Callable[[], object], expected: object, *, times: int = 5) -> None:
    """``read()`` returns ``expected`` although each reply meets ``kind``."""
    for _ in range(times):
        faults.schedule(kind, nth=1, **params)
        assert read() == expected
    assert [k for _, k in faults.log] == [kind] * times


def motion_fault_session(axis: MotionAxis, faults: FaultInjector, *, moves: int = 30) -> None:
    """Random faults: each move succeeds or raises a typed error naming its command."""
    got = random_fault_session(
        lambda i: axis.move_to((i % 5) - 2.0, wait=True, timeout=5), faults, n=moves,
        device=axis.name, after_failure=lambda: time.sleep(0.2))  # late replies, moves end
    assert got.right + got.failed == moves and got.right >= moves // 2
    assert len(faults.log) >= 5


def unplug_during_query(axis: MotionAxis, emulator: FirmwareEmulator, transport: str,
                        reopen: Callable[[], MotionAxis], *, command: str) -> MotionAxis:
    """Unplug before a position query: a typed error naming ``command``.

    Returns the axis to use after the replug.
    """
    return unplug_and_replug(axis, emulator.faults, transport, lambda: axis.position, reopen,
                             command=command)


def unplug_during_move(axis: MotionAxis, emulator: FirmwareEmulator, transport: str,
                       reopen: Callable[[], MotionAxis], *,
                       command: str | None = None) -> MotionAxis:
    """Unplug while waiting for a move: a typed error, chained from its cause.

    The controller finishes the move on its own; the axis returned (after the replug) has
    come to rest, so the caller can check where.
    """
    axis = unplug_and_replug(axis, emulator.faults, transport, lambda: axis.wait(60), reopen,
                             command=command)
    # The short reply timeout only made the dead link's DeviceTimeout quick; back on the
    # cable the reads below must not fail because a loaded host answered late.
    axis.reply_timeout = max(axis.reply_timeout, 5.0)
    deadline = time.monotonic() + 60.0  # returns as soon as the move has ended
    while axis.is_moving and time.monotonic() < deadline:
        time.sleep(0.005)
    return axis
