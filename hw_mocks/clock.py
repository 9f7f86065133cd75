"""Clocks for the emulators: real, scaled, manual and self-advancing.

Emulated hardware keeps its own notion of time so that tests can run a 20-second stage
move without waiting 20 seconds. Every emulator asks its clock ``now()`` (seconds,
monotonic) whenever it processes a command or is polled, and computes motion from that.

- :class:`ScaledClock` runs ``speed`` times faster than the wall clock (``speed=1`` is
  real time; used for benchmarks of scan efficiency and for the pty server).
- :class:`ManualClock` moves only when told (unit tests of motion profiles).
- :class:`SteppingClock` advances a fixed step on every reading, so a driver's poll loop
  makes simulated time pass deterministically and without real waiting.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol

__all__ = ["Clock", "ManualClock", "ScaledClock", "SteppingClock"]


class Clock(Protocol):
    def now(self) -> float:
        """Seconds on a monotonic time line."""
        ...


class ScaledClock:
    """Wall-clock time multiplied by ``speed`` (1.0 = real time)."""

    def __init__(self, speed: float = 1.0) -> None:
        if not speed > 0:
            raise ValueError("speed must be > 0")
        self.speed = float(speed)
        self._t0 = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._t0) * self.speed


class ManualClock:
    """Time that moves only through :meth:`advance` or :meth:`set`."""

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._t

    def advance(self, dt: float) -> float:
        if dt < 0:
            raise ValueError("time cannot run backwards")
        with self._lock:
            self._t += dt
            return self._t

    def set(self, t: float) -> None:
        with self._lock:
            if t < self._t:
                raise ValueError("time cannot run backwards")
            self._t = float(t)


class SteppingClock:
    """Each reading advances time by ``step`` seconds (deterministic, no real waiting)."""

    def __init__(self, step: float = 0.01, start: float = 0.0) -> None:
        if not step > 0:
            raise ValueError("step must be > 0")
        self.step = float(step)
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            self._t += self.step
            return self._t
