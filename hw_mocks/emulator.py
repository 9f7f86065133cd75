"""The base of every firmware emulator: device-side byte handling with a clock and faults.

An emulator is the device end of a serial cable. Bytes from the host go into
:meth:`FirmwareEmulator.receive`, which returns the complete frames the device sends back;
:meth:`FirmwareEmulator.poll` returns frames the device sends on its own (move finished,
periodic status). How the frames reach the host (in-process pyserial link or a real
pseudo-terminal) and what faults befall them is the job of :mod:`hw_mocks.link`.

Emulators keep controller state behind one re-entrant lock, because the link, the pty
server and the virtual bench (which reads stage positions) may call from different
threads. Each :meth:`FirmwareEmulator.receive` and each look for unprompted frames (the
links call :meth:`FirmwareEmulator.poll` inside :meth:`FirmwareEmulator.instant`) runs at
one instant of the emulator's clock, so a reply never mixes a position of one moment with
a state of a later one (:func:`hw_mocks.clock.instant`).
"""

from __future__ import annotations

import contextlib
import threading
from abc import ABC, abstractmethod
from typing import ClassVar

from hw_mocks.clock import Clock, HostPacedClock, ScaledClock, instant, wire_time_s
from hw_mocks.faults import FaultInjector

__all__ = ["FirmwareEmulator", "clock_from_options"]


def clock_from_options(options: dict[str, str]) -> Clock:
    """Clock from URL options: ``speed=<factor>`` (scaled wall clock, default 1) or
    ``step=<seconds>`` (advances on every reading)."""
    from hw_mocks.clock import SteppingClock

    if "step" in options:
        return SteppingClock(float(options["step"]))
    return ScaledClock(float(options.get("speed", 1.0)))


class FirmwareEmulator(ABC):
    """Device side of a byte protocol.

    Parameters
    ----------
    name
        Instance name (the host part of the URL, e.g. ``simapt://sample_theta``).
    clock
        Time source for motion and timing.
    seed
        Seed of the fault injector's random generator.
    """

    #: URL scheme served (``simapt``...), set by subclasses.
    scheme: ClassVar[str] = ""
    #: Baud rate the device runs at; a link opened at another rate sees garbage.
    baudrate: ClassVar[int] = 9600

    def __init__(self, name: str, *, clock: Clock | None = None, seed: int = 0) -> None:
        self.name = name
        self.clock: Clock = clock if clock is not None else ScaledClock(1.0)
        self.faults = FaultInjector(seed)
        self.lock = threading.RLock()
        self._rx = bytearray()
        self.connections = 0
        #: Every byte received, for tests that need to see what the host sent.
        self.received_log = bytearray()

    def instant(self) -> contextlib.AbstractContextManager[object]:
        """Run the ``with`` block at one reading of the emulator's clock (this thread)."""
        return instant(self.clock)

    def receive(self, data: bytes) -> list[bytes]:
        """Accept bytes from the host; return the frames to send back, in order.

        The commands are executed at one instant of the emulator's clock.
        """
        with self.lock, self.instant():
            self.received_log += data
            self._rx += data
            # On a host-paced clock (hw_mocks.clock.HostPacedClock) the bytes take their
            # wire time, the command's before it runs and the reply's after.
            clock = self.clock
            if isinstance(clock, HostPacedClock):
                clock.advance(wire_time_s(len(data), self.baudrate))
            frames = self._handle_input(self._rx)
            if isinstance(clock, HostPacedClock) and frames:
                clock.advance(wire_time_s(sum(map(len, frames)), self.baudrate))
            return frames

    def poll(self) -> list[bytes]:
        """Frames the device sends unprompted at the present time (default: none)."""
        return []

    def on_connect(self) -> list[bytes]:
        """Called when a host opens the link; returns frames already in the pipe."""
        with self.lock:
            self.connections += 1
            self._rx.clear()
        return []

    def on_disconnect(self) -> None:
        """Called when the host closes the link."""

    @abstractmethod
    def _handle_input(self, buf: bytearray) -> list[bytes]:
        """Consume complete requests from ``buf`` (in place); return reply frames."""

    @abstractmethod
    def unsolicited_frame(self) -> bytes:
        """A message the device may send at any time (for fault injection)."""

    @abstractmethod
    def enter_error_state(self, code: str | None = None) -> None:
        """Put the controller into an error state (for fault injection)."""
