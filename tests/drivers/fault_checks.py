"""Fault-injection loops shared by the serial drivers' tests.

Each helper drives one operation of a driver through many injected faults and counts the
outcomes; the calling test states what its protocol allows (how many wrong values a
protocol without checksum may let through, how many typed failures a session may have).
Every failure must be a typed :class:`~drivers.errors.DeviceError` naming the device and
the command; anything else propagates and fails the test.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import serial

from drivers.errors import ConnectionFailed, DeviceError, DeviceTimeout, ProtocolError
from hw_mocks.faults import FaultInjector, FaultKind
from tests.waiting import wait_for

#: The fault kinds of a "random faults on a long session" test.
SESSION_FAULTS = (FaultKind.DROP, FaultKind.GARBAGE, FaultKind.SPLIT, FaultKind.UNSOLICITED,
                  FaultKind.DELAY)


@dataclass
class Outcomes:
    """How a series of faulty operations ended."""

    right: int = 0
    wrong: int = 0
    failed: int = 0


def corrupted_reads(read: Callable[[], float], is_right: Callable[[float], bool],
                    faults: FaultInjector, *, n: int, device: str, command: str) -> Outcomes:
    """``n`` reads, each with one bit flipped in the first reply: count right and wrong
    values and typed failures (which must name ``device`` and ``command``)."""
    outcomes = Outcomes()
    for _ in range(n):
        faults.schedule(FaultKind.CORRUPT, nth=1, nbytes=1)
        try:
            value = read()
        except (ProtocolError, DeviceTimeout) as err:
            assert err.device == device and err.command == command, err
            outcomes.failed += 1
            continue
        if is_right(value):
            outcomes.right += 1
        else:
            outcomes.wrong += 1
    return outcomes


def random_fault_session(operation: Callable[[int], None], faults: FaultInjector, *, n: int,
                         device: str, probability: float = 0.05,
                         after_failure: Callable[[], None] | None = None) -> Outcomes:
    """Arm :data:`SESSION_FAULTS` at random, run ``operation(i)`` ``n`` times; ``right``
    counts successes, ``failed`` typed errors (which must name ``device`` and a command)."""
    for kind in SESSION_FAULTS:
        faults.randomly(kind, probability, gap_s=0.002, nbytes=3, delay_s=0.15)
    outcomes = Outcomes()
    for i in range(n):
        try:
            operation(i)
            outcomes.right += 1
        except DeviceError as err:
            assert err.device == device and err.command, err
            outcomes.failed += 1
            if after_failure is not None:
                after_failure()
    return outcomes


def unplug_and_replug(device, faults: FaultInjector, transport: str,
                      operation: Callable[[], object], reopen: Callable[[], object], *,
                      command: str | None):
    """Pull the cable at the next frame and put it back; return the device to go on with.

    ``operation`` must then fail with the transport's typed error naming
    the device and ``command``: in-process the link raises (ConnectionFailed); a pty stays
    open but the dead instrument answers nothing (DeviceTimeout after the retries);
    ``command=None`` accepts any command (a wait polls several). Back
    on: an in-process device is closed and ``reopen()`` ed (reaching the same emulator); a
    pty's port works again as it is.
    """
    faults.schedule(FaultKind.DISCONNECT, nth=1)
    expected = ConnectionFailed if transport == "url" else DeviceTimeout
    try:
        operation()
    except expected as err:
        assert err.device == device.name, err
        assert command is None or err.command == command, err
        assert err.__cause__ is not None
    else:
        raise AssertionError(f"no {expected.__name__} after the cable was pulled")
    if transport == "url":
        device.close()
        return reopen()
    faults.reconnect()
    return device


def lose_or_hold_reply(faults: FaultInjector, *, late: bool, on: bytes | None = None
                       ) -> threading.Event | None:
    """Lose the next reply (the next one containing ``on``), or, ``late``, hold it on the
    wire until the returned event is set: a reply that is late whatever the machine's
    load, where one late by a wall-clock delay arrives in time when the driver's thread
    is descheduled."""
    if not late:
        faults.schedule(FaultKind.DROP, nth=1, on=on)
        return None
    release = threading.Event()
    faults.schedule(FaultKind.DELAY, nth=1, hold=release, on=on)
    return release


def let_held_reply_arrive(release: threading.Event, port: serial.SerialBase) -> None:
    """Let a held reply (:func:`lose_or_hold_reply`) go and return once it is in the
    host's input buffer (``port``, the driver's side of the link), so the driver's next
    command meets it as stale input, as it would a reply that came after the driver gave
    up."""
    release.set()
    wait_for(lambda: port.in_waiting > 0,  # type: ignore[attr-defined]  # every real port has it
             what="the held reply in the host's input buffer")
