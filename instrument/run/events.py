"""Events the run engine publishes to its subscribers.

Subscribers are called **on the engine's worker thread**, in order, and must return
quickly; a GUI hands each event to its own thread (a Qt signal, or the thread-safe
:class:`EventQueue` below that a timer drains). A subscriber that raises stops nothing:
it is unsubscribed, its error is reported once on stderr, and the run goes on.
"""

from __future__ import annotations

import queue
from dataclasses import dataclass

__all__ = [
    "AxisHomed",
    "Event",
    "EventQueue",
    "Fault",
    "Paused",
    "PointCompleted",
    "Progress",
    "Resumed",
    "RunFinished",
    "RunStarted",
]


@dataclass(frozen=True)
class RunStarted:
    run_id: str
    path: str
    plan_kind: str
    n_total: int
    n_done: int          # > 0 when a run is resumed
    estimated_s: float


@dataclass(frozen=True)
class PointCompleted:
    """A point has been acquired and handed to storage; live values for plots.

    Its record is committed to the run file before the next point acquires anything
    (docs/decisions/0010); a kill before that loses this point and no other.
    """

    index: int
    label: str
    status: str          # "ok" | "skipped"
    positions: dict[str, float]
    angles: tuple[float, float, float, float] | None
    exposure_us: float
    power_w: float
    signal: float
    retries: int
    nd_slot: int = -1    # the neutral-density filter's wheel slot it was read through


@dataclass(frozen=True)
class AxisHomed:
    """The engine homed an axis the plan moves (it was not homed when the run started)."""

    device: str
    position: float      # read back after the home
    elapsed_s: float     # how long the home took


@dataclass(frozen=True)
class Progress:
    n_done: int
    n_total: int
    elapsed_s: float
    eta_s: float


@dataclass(frozen=True)
class Fault:
    device: str
    cause: str
    action: str          # "retry 1/3", "rehome", "skip point", "pause", "abort"
    index: int | None


@dataclass(frozen=True)
class Paused:
    reason: str
    index: int | None    # the next point to run


@dataclass(frozen=True)
class Resumed:
    index: int | None


@dataclass(frozen=True)
class RunFinished:
    status: str          # "finished" | "aborted" | "paused" | "failed"
    n_done: int
    n_total: int
    n_skipped: int
    path: str
    elapsed_s: float
    message: str


#: Any event of a run, as subscribers receive them.
Event = (RunStarted | PointCompleted | Progress | Fault | Paused | Resumed | RunFinished
         | AxisHomed)


class EventQueue:
    """A subscriber that queues events for another thread to :meth:`drain`.

    It never blocks the worker thread (which drives the hardware). ``maxsize`` > 0 bounds
    the backlog a slow client can build up: while ``maxsize`` or more events wait,
    *live-value* events (:class:`Progress`, :class:`PointCompleted`: each is superseded
    by the next) are counted in ``dropped`` instead of queued. Lifecycle events (started,
    fault, paused, resumed, finished) are always queued.
    """

    def __init__(self, maxsize: int = 0) -> None:
        self._q: queue.Queue[Event] = queue.Queue()
        self.maxsize = int(maxsize)
        self.dropped = 0

    def __call__(self, event: Event) -> None:
        if (self.maxsize > 0 and isinstance(event, (Progress, PointCompleted))
                and self._q.qsize() >= self.maxsize):
            self.dropped += 1
            return
        self._q.put(event)

    def drain(self) -> list[Event]:
        out = []
        while True:
            try:
                out.append(self._q.get_nowait())
            except queue.Empty:
                return out

    def get(self, timeout: float | None = None) -> Event:
        return self._q.get(timeout=timeout)
