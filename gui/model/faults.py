"""What a fault means and what the operator may do about it (Qt-free).

The engine reports every fault with the device, the cause and the action it took
(:class:`instrument.run.events.Fault`; ADR 0011): a retry, a re-home, a skipped point, a
pause or an abort. :func:`describe` turns one into a row of the fault panel with its
severity and a sentence saying what happened. :func:`recovery_for` says which choices
the operator has when the run is paused: after a point's fault, **retry** the point,
**skip** it (stored as skipped) or **abort** the run; after a storage fault, retry or
abort (the point is taken again once the file is recovered); after the operator's own
pause, resume or abort.
"""

from __future__ import annotations

import enum
import time
from collections import deque
from dataclasses import dataclass, field

from instrument.run.events import Fault, Paused

__all__ = ["FaultLog", "FaultRow", "PauseKind", "Recovery", "describe", "point_number",
           "recovery_for"]


def point_number(index: int | None) -> str:
    """The point as the operator counts it: the engine's plan index is 0-based, the
    progress count (``28/57 points``) counts from 1, so plan index 27 is point 28."""
    return "" if index is None else str(int(index) + 1)


class Recovery(enum.Enum):
    RETRY = "retry"
    SKIP = "skip point"
    ABORT = "abort"
    RESUME = "resume"


class PauseKind(enum.Enum):
    OPERATOR = "operator"
    DEVICE_FAULT = "device fault"
    STORAGE_FAULT = "storage fault"


@dataclass(frozen=True)
class FaultRow:
    time: float
    device: str
    cause: str
    action: str
    index: int | None
    severity: str   # "info" (a retry that may well succeed) | "warning" | "error"
    meaning: str


def describe(ev: Fault, *, now: float | None = None) -> FaultRow:
    """The fault panel's row for one fault event."""
    action = ev.action
    where = "" if ev.index is None else f" at point {point_number(ev.index)}"
    if action.startswith("retry"):
        severity = "info"
        meaning = f"{ev.device} failed{where}; the engine tries again ({action})"
    elif action == "rehome":
        severity = "warning"
        meaning = f"{ev.device} kept failing{where}; the engine re-homes it and tries once more"
    elif action == "skip point":
        severity = "warning"
        meaning = (f"point {point_number(ev.index)} is stored as skipped ({ev.device} "
                   "failed); the run goes on")
    elif action == "pause":
        severity = "error"
        meaning = (f"the run is paused{where}: {ev.device} failed and its policy is to wait "
                   "for the operator (bench made safe: axes stopped, light off)")
    elif action == "abort":
        severity = "error"
        meaning = f"the run is aborted{where} because {ev.device} failed"
    elif action.startswith("light off"):
        severity = "warning"
        meaning = f"{ev.device} is slow{where}: the light is off while the engine waits"
    else:
        severity = "warning"
        meaning = f"{ev.device}{where}: {action}"
    return FaultRow(time.time() if now is None else now, ev.device, ev.cause, action,
                    ev.index, severity, meaning)


@dataclass(frozen=True)
class PauseState:
    kind: PauseKind
    reason: str
    index: int | None
    choices: tuple[Recovery, ...]
    question: str


def recovery_for(paused: Paused, last_fault: Fault | None) -> PauseState:
    """What the operator may do about a pause: it follows a fault whose action was
    ``pause`` (reported just before, at the same point) or the operator's request."""
    if last_fault is not None and last_fault.action == "pause" and (
            last_fault.index == paused.index or last_fault.device == "storage"):
        if last_fault.device == "storage":
            return PauseState(PauseKind.STORAGE_FAULT, paused.reason, paused.index,
                              (Recovery.RETRY, Recovery.ABORT),
                              "Storage failed. Free space or fix the disk, then retry (the "
                              "file is recovered from its journal and the point taken "
                              "again), or abort.")
        return PauseState(PauseKind.DEVICE_FAULT, paused.reason, paused.index,
                          (Recovery.RETRY, Recovery.SKIP, Recovery.ABORT),
                          f"{last_fault.device} failed at point {paused.index}: "
                          f"{last_fault.cause}. Fix it (cable, power, obstruction), then "
                          "retry the point, skip it (stored as skipped), or abort the run.")
    return PauseState(PauseKind.OPERATOR, paused.reason, paused.index,
                      (Recovery.RESUME, Recovery.ABORT),
                      f"Paused ({paused.reason}). Resume or abort.")


@dataclass
class FaultLog:
    """Every fault of a run, newest last (bounded: a fault storm cannot eat the memory)."""

    maxlen: int = 10_000
    rows: deque[FaultRow] = field(default_factory=deque)
    total: int = 0

    def add(self, ev: Fault) -> FaultRow:
        row = describe(ev)
        self.rows.append(row)
        self.total += 1
        while len(self.rows) > self.maxlen:
            self.rows.popleft()
        return row

    def clear(self) -> None:
        self.rows.clear()
        self.total = 0
