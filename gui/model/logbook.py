"""The operator's log without Qt: warnings and errors from the engine, the pipelines, the
bench and Python's logging, kept (bounded), filtered and copied as text.

Entries come from many threads; :class:`LogBook` takes a lock. What becomes an entry:
engine events (:func:`from_event`: faults by severity, pauses, run ends that are not
"finished"), command results that were refused or failed (:func:`from_result`), analysis
notes and warnings, and records of Python's ``logging`` (drivers log protocol oddities)
through :class:`LogBookHandler`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass

from gui.model import format as fmt
from gui.model.faults import describe
from instrument.run.events import (
    AxisHomed,
    Event,
    Fault,
    Paused,
    Resumed,
    RunFinished,
    RunStarted,
)

__all__ = ["LEVELS", "LogBook", "LogBookHandler", "LogEntry", "from_event", "from_result"]

LEVELS = ("debug", "info", "warning", "error")


@dataclass(frozen=True)
class LogEntry:
    time: float
    level: str    # one of LEVELS
    source: str   # "engine", "bench", "fit", "drivers.thorlabs_apt" …
    message: str

    def text(self) -> str:
        stamp = time.strftime("%H:%M:%S", time.localtime(self.time))
        return f"{stamp} {self.level.upper():7s} {self.source}: {self.message}"


class LogBook:
    """The last ``maxlen`` entries, newest last."""

    def __init__(self, maxlen: int = 5000) -> None:
        self._entries: deque[LogEntry] = deque(maxlen=maxlen)
        self._lock = threading.Lock()
        self.total = 0

    def add(self, entry: LogEntry | None) -> LogEntry | None:
        if entry is None:
            return None
        with self._lock:
            self._entries.append(entry)
            self.total += 1
        return entry

    def log(self, level: str, source: str, message: str) -> LogEntry:
        return self.add(LogEntry(time.time(), level, source, message))

    def entries(self, *, min_level: str = "debug", text: str = "") -> list[LogEntry]:
        """Entries at or above ``min_level`` whose line contains ``text`` (any case)."""
        floor = LEVELS.index(min_level)
        needle = text.lower()
        with self._lock:
            items = list(self._entries)
        return [e for e in items if LEVELS.index(e.level) >= floor
                and (not needle or needle in e.text().lower())]

    def as_text(self, **filters) -> str:
        return "\n".join(e.text() for e in self.entries(**filters))

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()


def from_event(ev: Event) -> LogEntry | None:
    """The log entry of an engine event (``None`` for live values)."""
    now = time.time()
    match ev:
        case Fault():
            row = describe(ev, now=now)
            return LogEntry(now, row.severity if row.severity != "info" else "warning",
                            f"engine/{ev.device}", f"{ev.cause} → {ev.action}")
        case Paused():
            return LogEntry(now, "warning", "engine", f"paused: {ev.reason}")
        case Resumed():
            return LogEntry(now, "info", "engine", "resumed")
        case AxisHomed():
            return LogEntry(now, "info", f"engine/{ev.device}",
                            f"homed by the run (it was not homed) in "
                            f"{fmt.duration(ev.elapsed_s)}; now at {ev.position:.6g}")
        case RunStarted():
            return LogEntry(now, "info", "engine", f"run {ev.run_id} started: {ev.n_total} "
                            f"points ({ev.n_done} already done), file {ev.path}")
        case RunFinished():
            level = "info" if ev.status == "finished" else "warning"
            note = f"; {ev.message}" if ev.message else ""
            return LogEntry(now, level, "engine", f"run {ev.status}: {ev.n_done} of "
                            f"{ev.n_total} points{note}")
    return None


def from_result(result) -> LogEntry | None:
    """The log entry of a session command's result: refusals and failures only."""
    if result.ok:
        return None
    level = "warning" if result.refused else "error"
    return LogEntry(time.time(), level, "bench", result.message)


class LogBookHandler(logging.Handler):
    """A ``logging`` handler that puts records into a :class:`LogBook` and calls
    ``on_entry`` (from the logging thread)."""

    def __init__(self, book: LogBook, on_entry=None, level: int = logging.INFO) -> None:
        super().__init__(level)
        self.book = book
        self.on_entry = on_entry

    def emit(self, record: logging.LogRecord) -> None:
        try:
            level = ("error" if record.levelno >= logging.ERROR else
                     "warning" if record.levelno >= logging.WARNING else
                     "info" if record.levelno >= logging.INFO else "debug")
            entry = self.book.add(LogEntry(record.created, level, record.name,
                                           record.getMessage()))
            if self.on_entry is not None:
                self.on_entry(entry)
        except Exception:  # logging must never raise into the caller
            self.handleError(record)
