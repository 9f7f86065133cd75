"""Clocks for the emulators: real, scaled, manual and self-advancing.

Emulated hardware keeps its own notion of time so that tests can run a 20-second stage
move without waiting 20 seconds. Every emulator asks its clock ``now()`` (seconds,
monotonic) whenever it processes a command or is polled, and computes motion from that.

- :class:`ScaledClock` runs ``speed`` times faster than the wall clock (``speed=1`` is
  real time; used for benchmarks of scan efficiency and for the pty server).
- :class:`ManualClock` moves only when told (unit tests of motion profiles).
- :class:`SteppingClock` advances a fixed step on every reading, so a driver's poll loop
  makes simulated time pass deterministically and without real waiting.
- :class:`HostPacedClock` moves only when the host waits (its waits are routed to
  :meth:`~_Holdable.advance`), when bytes cross the emulated wire, and, while the host
  waits for a reply the device holds back, to the moment that reply is due
  (:meth:`HostPacedClock.run_to`). An emulator whose readings depend on elapsed time (the
  SR830's output filter and noise) then gives the same readings however fast or loaded
  the machine is: a seeded run's data are a function of the seed and the plan only.

Every clock can be *held* (:meth:`~_Holdable.held`): while held, emulated time stands still
except for explicit :meth:`~_Holdable.advance` calls, and on release it runs on from where
it stood, without a jump. A test that must observe a state in the middle of a motion ("the
axis is still moving", "the stop came before the target") holds the clock around the
observation instead of hoping that the machine is fast enough to look in time.

An emulator reads the clock once per command (:meth:`~_Holdable.instant`): a reply built
from several readings (a position, then a BUSY flag) could otherwise mix two moments. On
a loaded machine the emulator's thread can be descheduled between the readings, and on a
fast clock (``speed=200``) one millisecond of wall time is long enough for a move to end
between them, so a reply would say IDLE with the position of mid-move.
"""

from __future__ import annotations

import abc
import contextlib
import threading
import time
from collections.abc import Iterator
from typing import Protocol

__all__ = ["Clock", "HoldableClock", "HostPacedClock", "ManualClock", "ScaledClock",
           "SteppingClock", "instant", "wire_time_s"]


class Clock(Protocol):
    def now(self) -> float:
        """Seconds on a monotonic time line."""
        ...


class HoldableClock(Protocol):
    """A clock a test can stop and advance by hand (every clock of this module is one)."""

    def now(self) -> float: ...

    def advance(self, dt: float) -> float: ...

    def held(self) -> contextlib.AbstractContextManager[HoldableClock]: ...


class _Holdable(abc.ABC):
    """Holding for the clocks: a count of holds, and time that only :meth:`advance` moves.

    Subclasses keep their reading in ``_t`` while held and implement :meth:`_freeze`
    (take the present reading into ``_t``) and :meth:`_thaw` (run on from ``_t``).
    """

    _lock: threading.Lock
    _t: float
    _holds: int = 0

    @contextlib.contextmanager
    def instant(self) -> Iterator[float]:
        """Read the clock once for the ``with`` block, in the calling thread.

        Every :meth:`now` from this thread inside the block returns that one reading (a
        :class:`SteppingClock` steps once), so what an emulator computes for one command
        belongs to one moment however long the computation takes. :meth:`advance` (and
        :meth:`HostPacedClock.run_to`) from the same thread move the reading along; other
        threads see the clock run as usual. Blocks nest (the outermost reading holds).
        """
        pins = self._pins()
        if getattr(pins, "t", None) is not None:
            yield pins.t
            return
        pins.t = self.now()
        try:
            yield pins.t
        finally:
            pins.t = None

    def _pins(self) -> threading.local:
        # Created on first use (the clocks' constructors do not call a common one);
        # dict.setdefault keeps two threads from creating two.
        pins: threading.local = self.__dict__.setdefault("_pin", threading.local())
        return pins

    def _pinned(self) -> float | None:
        """The reading this thread's :meth:`instant` block holds, else ``None``."""
        pins = self.__dict__.get("_pin")
        return None if pins is None else getattr(pins, "t", None)

    def _repin(self, t: float) -> None:
        """This thread moved the clock to ``t``: an :meth:`instant` block follows it."""
        pins = self.__dict__.get("_pin")
        if pins is not None and getattr(pins, "t", None) is not None:
            pins.t = t

    @contextlib.contextmanager
    def held(self) -> Iterator[_Holdable]:
        """Stop emulated time for the ``with`` block (holds nest; time runs on after the
        outermost). Thread-safe: emulator threads reading the clock meanwhile see it stand."""
        with self._lock:
            if self._holds == 0:
                self._freeze()
            self._holds += 1
        try:
            yield self
        finally:
            with self._lock:
                self._holds -= 1
                if self._holds == 0:
                    self._thaw()

    @property
    def is_held(self) -> bool:
        with self._lock:
            return self._holds > 0

    def advance(self, dt: float) -> float:
        """Move time forward by ``dt`` seconds at once; return the new reading."""
        if dt < 0:
            raise ValueError("time cannot run backwards")
        with self._lock:
            if self._holds == 0:
                self._freeze()
                self._t += dt
                self._thaw()
            else:
                self._t += dt
            t = self._t
        self._repin(t)
        return t

    @abc.abstractmethod
    def now(self) -> float:
        """Seconds on a monotonic time line."""

    @abc.abstractmethod
    def _freeze(self) -> None:
        """Stop emulated time (called under the lock when the first hold starts)."""

    @abc.abstractmethod
    def _thaw(self) -> None:
        """Let emulated time run on from where it stood (the last hold ended)."""


class ScaledClock(_Holdable):
    """Wall-clock time multiplied by ``speed`` (1.0 = real time)."""

    def __init__(self, speed: float = 1.0) -> None:
        if not speed > 0:
            raise ValueError("speed must be > 0")
        self.speed = float(speed)
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self._t = 0.0

    def now(self) -> float:
        pinned = self._pinned()
        if pinned is not None:
            return pinned
        with self._lock:
            if self._holds:
                return self._t
            return self._running()

    def _running(self) -> float:
        return (time.monotonic() - self._t0) * self.speed

    def _freeze(self) -> None:
        self._t = self._running()

    def _thaw(self) -> None:
        # Choose the origin so that the running reading starts at the held one.
        self._t0 = time.monotonic() - self._t / self.speed


class ManualClock(_Holdable):
    """Time that moves only through :meth:`advance` or :meth:`set` (always held)."""

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        pinned = self._pinned()
        if pinned is not None:
            return pinned
        with self._lock:
            return self._t

    def _freeze(self) -> None:
        pass  # nothing but advance() and set() moves this clock anyway

    def _thaw(self) -> None:
        pass

    def set(self, t: float) -> None:
        with self._lock:
            if t < self._t:
                raise ValueError("time cannot run backwards")
            self._t = float(t)
        self._repin(float(t))


class SteppingClock(_Holdable):
    """Each reading advances time by ``step`` seconds (deterministic, no real waiting);
    while held, readings do not step."""

    def __init__(self, step: float = 0.01, start: float = 0.0) -> None:
        if not step > 0:
            raise ValueError("step must be > 0")
        self.step = float(step)
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        pinned = self._pinned()
        if pinned is not None:
            return pinned
        with self._lock:
            if not self._holds:
                self._t += self.step
            return self._t

    def _freeze(self) -> None:
        pass  # the reading is _t already

    def _thaw(self) -> None:
        pass


def instant(clock: Clock) -> contextlib.AbstractContextManager[object]:
    """``clock.instant()`` where the clock has one (every clock here), else a no-op."""
    method = getattr(clock, "instant", None)
    return method() if method is not None else contextlib.nullcontext()


def wire_time_s(n_bytes: int, baudrate: float) -> float:
    """Seconds ``n_bytes`` take on an asynchronous serial line: ten bits a byte (start bit,
    eight data bits, stop bit: 8N1)."""
    return 10.0 * n_bytes / baudrate


class HostPacedClock(ManualClock):
    """Emulated time paced by the host instead of the wall clock.

    It stands still except when

    - the host waits: the driver's waiting function (``sleep=``) sleeps and then calls
      :meth:`advance` with the same seconds (``hw_mocks.urlhandler.protocol_simsr830.host_sleep``
      builds one);
    - bytes cross the emulated wire: the emulator advances it by their
      :func:`wire_time_s` (a query and its reply take their time at the line's rate);
    - the host waits for a reply the device holds back (an SR830 busy with ``AGAN``): the
      emulator lets it run to the moment the reply is due (:meth:`run_to`), as the real
      time the host spends waiting would.

    Everything else the host does (computing, being descheduled on a loaded machine,
    moving other devices) takes no emulated time, so the emulated times of the device's
    readings follow from the host's sequence of commands and waits alone. Holding it
    (:meth:`~_Holdable.held`) changes nothing: it never runs by itself.
    """

    #: Emulators check this to advance the clock by wire time and run it to due replies.
    paced_by_host = True

    def run_to(self, t: float) -> float:
        """Move time forward to ``t`` (nothing if it is there already); return the reading."""
        with self._lock:
            self._t = max(self._t, float(t))
            t = self._t
        self._repin(t)
        return t
