"""Carrying emulator frames to the host: the in-process pyserial link and the queue.

:class:`OutboundQueue` holds the bytes a device has sent but the host has not read yet,
each with the time it reaches the host's buffer. Frames pass through the emulator's
fault injector on their way in, so a delayed reply really arrives late (after the
driver timed out) and order is kept as on a wire.

:class:`EmulatedSerial` is a ``serial.SerialBase`` whose other end is an emulator. URL
handler modules (``hw_mocks.urlhandler.protocol_<scheme>``) subclass it, so
``serial.serial_for_url("simapt://sample_theta?model=K10CR1")`` opens one.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable

import serial
from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from hw_mocks import registry
from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.faults import HostWriteHold

__all__ = ["EmulatedSerial", "OutboundQueue"]


class OutboundQueue:
    """Bytes in flight from the device to the host, released at their arrival time.

    A frame held by a ``DELAY`` fault (:attr:`hw_mocks.faults.FaultRule.hold`) has no
    arrival time until its event is set: it arrives when the queue first sees the event
    set, and nothing behind it overtakes it.
    """

    def __init__(self) -> None:
        self._items: deque[tuple[float, bytes, threading.Event | None]] = deque()
        self._held = 0  # frames still held: the reads' hot path skips the scan when none
        self._last = 0.0
        self._lock = threading.Lock()

    def push(self, frames: list[bytes], emulator: FirmwareEmulator) -> None:
        now = time.monotonic()
        with self._lock:
            for frame in frames:
                for delivery in emulator.faults.process(frame, emulator):
                    # A wire keeps order: nothing overtakes a late frame.
                    at = max(now + delivery.delay_s, self._last)
                    self._items.append((at, delivery.data, delivery.hold))
                    self._held += delivery.hold is not None
                    self._last = at

    def host_wrote(self) -> None:
        """The host wrote to the device: frames held until then
        (:class:`~hw_mocks.faults.HostWriteHold`) go."""
        with self._lock:
            if not self._held:
                return
            for _, _, hold in self._items:
                if isinstance(hold, HostWriteHold):
                    hold.set()

    def _release_held(self) -> None:
        """Stamp the held frames whose event is now set with an arrival time (the lock is
        held by the caller)."""
        if not self._held:
            return
        now = time.monotonic()
        for i, (at, data, hold) in enumerate(self._items):
            if hold is None:
                continue
            if not hold.is_set():
                return  # it and what is behind it wait (every read stops at it)
            self._items[i] = (max(at, now), data, None)
            self._held -= 1
            self._last = max(self._last, at, now)

    def _first_arrived(self, now: float) -> bool:
        return bool(self._items) and self._items[0][2] is None and self._items[0][0] <= now

    def take(self, n: int, *, until: float | None = None) -> bytes:
        """Up to ``n`` bytes that have arrived by now (and by ``until``, when given).

        ``until`` is the deadline of the read asking: a frame that arrives after it is not
        part of that read, even when the reading thread was descheduled past its deadline
        and only looks later. Without this a late frame (a ``DELAY`` fault) could be taken
        in time on a loaded machine, and a test of the late-reply recovery would pass or
        fail with the machine's load.
        """
        out = bytearray()
        with self._lock:
            self._release_held()
            now = time.monotonic() if until is None else min(time.monotonic(), until)
            while len(out) < n and self._first_arrived(now):
                at, data, _ = self._items.popleft()
                room = n - len(out)
                out += data[:room]
                if len(data) > room:
                    self._items.appendleft((at, data[room:], None))
        return bytes(out)

    def arrived(self) -> int:
        with self._lock:
            self._release_held()
            now = time.monotonic()
            total = 0
            for at, data, hold in self._items:
                if hold is not None or at > now:
                    break
                total += len(data)
            return total

    def next_arrival(self) -> float | None:
        """When the first frame in flight arrives (``None``: nothing in flight, or it is
        held)."""
        with self._lock:
            self._release_held()
            if not self._items or self._items[0][2] is not None:
                return None
            return self._items[0][0]

    def drop_arrived(self) -> int:
        """Discard what has reached the host buffer (what reset_input_buffer does)."""
        dropped = 0
        with self._lock:
            self._release_held()
            now = time.monotonic()
            while self._first_arrived(now):
                dropped += len(self._items.popleft()[1])
        return dropped


class EmulatedSerial(SerialBase):
    """A serial port whose far end is a firmware emulator (in-process).

    Subclasses set :attr:`scheme` and :attr:`factory`. A link opened at a baud rate other
    than the emulator's delivers nothing in either direction, as a real mismatch would
    (the device sees framing errors and never answers).
    """

    scheme: str = ""
    factory: Callable[[str, dict[str, str]], FirmwareEmulator] | None = None

    #: Longest sleep while waiting for bytes; keeps reads responsive to late frames.
    _POLL_S = 0.0005

    def open(self) -> None:
        if self._port is None:
            raise SerialException("port must be configured before it can be used")
        if self.is_open:
            raise SerialException("port is already open")
        scheme, name, options = registry.parse_url(self.portstr)
        if scheme != self.scheme:
            raise SerialException(f"expected a {self.scheme}:// URL, got {self.portstr!r}")
        factory = type(self).factory
        if factory is None:
            raise SerialException(f"no emulator factory for {scheme}://")
        self.emulator = registry.get_or_create(scheme, name, factory, options)
        self.emulator.faults.reconnect()
        self._queue = OutboundQueue()
        self._queue.push(self.emulator.on_connect(), self.emulator)
        self.is_open = True

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            self.emulator.on_disconnect()

    def _reconfigure_port(self) -> None:
        pass  # settings live in SerialBase; the baud rate is checked on each transfer

    def _update_rts_state(self) -> None:
        pass  # an FTDI link honours RTS; nothing to emulate beyond accepting it

    def _update_dtr_state(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass

    # -- I/O --------------------------------------------------------------------
    def _check(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        if self.emulator.faults.disconnected:
            raise SerialException(f"{self.portstr}: device disconnected")

    def _baud_ok(self) -> bool:
        return self._baudrate == self.emulator.baudrate

    def write(self, data: bytes) -> int:
        self._check()
        data = bytes(data)
        if self._baud_ok():
            self._queue.host_wrote()
            self._queue.push(self.emulator.receive(data), self.emulator)
        return len(data)

    def _pump(self) -> None:
        with self.emulator.instant():
            frames = self.emulator.poll()
        if frames and self._baud_ok():
            self._queue.push(frames, self.emulator)

    def read(self, size: int = 1) -> bytes:
        self._check()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        out = bytearray()
        while len(out) < size:
            self._check()
            self._pump()
            out += self._queue.take(size - len(out), until=deadline)
            if len(out) >= size or self._timeout == 0:
                break
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            pause = self._POLL_S
            nxt = self._queue.next_arrival()
            if nxt is not None and nxt > now:
                pause = min(max(nxt - now, 0.0), 0.005)
            if deadline is not None:
                pause = min(pause, max(deadline - now, 0.0))
            time.sleep(pause)
        return bytes(out)

    @property
    def in_waiting(self) -> int:
        self._check()
        self._pump()
        return self._queue.arrived()

    def reset_input_buffer(self) -> None:
        self._check()
        self._pump()
        self._queue.drop_arrived()

    def reset_output_buffer(self) -> None:
        self._check()

    def flush(self) -> None:
        self._check()


# pyserial resolves a handler module's ``Serial``; keep the base importable as such too.
Serial = EmulatedSerial
_ = serial  # the package must be importable where handlers are registered
