"""A run in progress, as a script or a notebook holds it: progress, pause, resume, abort,
and its events as an iterator or a callback.

The engine runs on its own thread (ADR 0011); the handle never touches the hardware
itself. Its events come through an :class:`~instrument.run.events.EventQueue` subscribed
before the run starts, so a script that asks for them late still sees every lifecycle
event (started, faults, pauses, finished); only superseded live values (progress, points)
are dropped when a reader falls more than ``MAX_BACKLOG`` events behind.
"""

from __future__ import annotations

import queue
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from instrument.run.engine import EngineState
from instrument.run.events import Event, EventQueue, Fault, Paused, RunFinished

if TYPE_CHECKING:
    from instrument.run.engine import RunEngine
    from instrument.scripting.results import Run

__all__ = ["RunHandle", "RunProgress", "RunTimeout"]

#: Live-value events kept for a reader that has fallen behind (lifecycle events: all).
MAX_BACKLOG = 10_000


class RunTimeout(TimeoutError):
    """A wait on a run ended before the run did (the run goes on)."""


@dataclass(frozen=True)
class RunProgress:
    """Where a run stands: points stored, points planned, seconds since it started."""

    n_done: int
    n_total: int
    elapsed_s: float
    state: str

    @property
    def fraction(self) -> float:
        return self.n_done / self.n_total if self.n_total else 1.0


class RunHandle:
    """A started run. Made by :meth:`ScriptBench.run`, not directly.

    ``status`` is ``"running"``, ``"paused"``, ``"finished"``, ``"aborted"`` or
    ``"failed"``; :meth:`wait` blocks until the run ends, :meth:`result` opens its file.
    """

    def __init__(self, engine: RunEngine, *, on_event: Callable[[Event], Any] | None = None
                 ) -> None:
        self._engine = engine
        self._queue = EventQueue(maxsize=MAX_BACKLOG)
        self._pending: deque[Event] = deque()
        self._pause_asked = False
        self._finished: RunFinished | None = None
        self._faults: list[Fault] = []
        self._engine.subscribe(self._record)
        self._engine.subscribe(self._queue)
        if on_event is not None:
            self._engine.subscribe(on_event)

    def _record(self, ev: Event) -> None:  # on the engine's thread: no blocking here
        if isinstance(ev, Fault):
            self._faults.append(ev)
        elif isinstance(ev, RunFinished):
            self._finished = ev

    # ------------------------------------------------------------------ state
    @property
    def path(self) -> Path:
        """The run file (it exists from the moment the run was made)."""
        return Path(self._engine.store.path)

    @property
    def status(self) -> str:
        return self._engine.state.value

    @property
    def done(self) -> bool:
        """True once the run has ended (finished, aborted, failed, or stopped paused)."""
        return self._engine.state is not EngineState.IDLE and not self._engine.alive

    @property
    def progress(self) -> RunProgress:
        snap = self._engine.snapshot()
        return RunProgress(snap.n_done, snap.n_total, snap.elapsed_s, snap.state.value)

    @property
    def faults(self) -> tuple[Fault, ...]:
        """Every fault the run met, with what the engine did about it."""
        return tuple(self._faults)

    @property
    def finished(self) -> RunFinished | None:
        """The run's last event (status, counts, message), once it has ended."""
        return self._finished

    # ---------------------------------------------------------------- control
    def pause(self, reason: str = "paused from a script") -> None:
        """Pause at the end of the current point (the run file stays open)."""
        self._pause_asked = True
        self._engine.pause(reason)

    def paused_by_the_engine(self, ev: Event) -> bool:
        """Whether ``ev`` is a pause nobody asked for through this handle (a fault that
        needs an answer, a full disk)."""
        return isinstance(ev, Paused) and not self._pause_asked

    def resume(self, *, skip_point: bool = False) -> None:
        """Continue a paused run; after a fault's pause, ``skip_point`` stores the failed
        point as skipped instead of trying it again."""
        self._pause_asked = False
        self._engine.resume(skip_point=skip_point)

    def abort(self, timeout: float | None = 60.0) -> str:
        """Stop motion now, turn the light off and close the file; wait up to ``timeout``
        seconds for that and return the status."""
        self._engine.abort()
        return self.wait(timeout)

    def wait(self, timeout: float | None = None) -> str:
        """Block until the run ends; return its status.

        Raises
        ------
        RunTimeout
            ``timeout`` seconds passed first (the run goes on; wait again or abort).
        """
        state = self._engine.wait(timeout)
        if self._engine.alive:
            raise RunTimeout(f"{self.path.name} still {state.value} after {timeout} s; "
                             "wait again, or abort()")
        return state.value

    def events(self, timeout: float | None = None) -> Iterator[Event]:
        """The run's events in order, from its start, until it ends. One reader only:
        events a loop has taken are gone for a second loop.

        ``timeout``: the longest wait for the next event; :class:`RunTimeout` after it.
        """
        while True:
            ev = self._next(timeout)
            yield ev
            if isinstance(ev, RunFinished):
                return

    def _next(self, timeout: float | None) -> Event:
        if self._pending:
            return self._pending.popleft()
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                return self._queue.get(timeout=0.2)
            except queue.Empty:
                if self.done:  # every event is queued before the engine's thread ends
                    self._pending.extend(self._queue.drain())
                    if self._pending:
                        return self._pending.popleft()
                    if self._finished is not None:
                        return self._finished
                    raise RunTimeout(f"{self.path.name} ended without a final event "
                                     f"(status {self.status})") from None
                if deadline is not None and time.monotonic() > deadline:
                    raise RunTimeout(f"no event from {self.path.name} for {timeout} s "
                                     f"(status {self.status})") from None

    def result(self) -> Run:
        """The run file, opened for analysis (:func:`instrument.open_run`); waits for the
        run to end first."""
        from instrument.scripting.results import open_run

        self.wait()
        return open_run(self.path)

    def __repr__(self) -> str:
        p = self.progress
        return f"<RunHandle {self.path.name}: {p.state}, {p.n_done}/{p.n_total} points>"
