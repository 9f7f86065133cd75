"""The SR830's data storage (its trace buffer), driven by the emulator's clock.

Written from the SR830 manual (Rev. 2.5), chapter 5, "Data Storage Commands" and "Data
Transfer Commands". The buffer stores the two displays (CH1, CH2) at the sample rate
``SRAT i``: i = 0…13 for 62.5 mHz … 512 Hz (factors of two), 14 for "one point per
trigger" (``TRIG`` or the rear-panel trigger input). It holds up to 16383 points per
channel. ``SEND 0`` (one shot) stops storage when it is full; ``SEND 1`` (loop) keeps
storing, the oldest points overwritten. ``STRT`` starts or resumes, ``PAUS`` pauses,
``REST`` resets (clears the buffer, storage stopped), ``STRD`` starts after a delay of
0.5 s. With ``TSTR 1`` a trigger starts the scan.

This class keeps the state machine and the points; the emulator computes the display
values at each sample time (:meth:`DataStorage.due`) and stores them.

Emulator choices (documented, not from the manual): the first point of a scan is taken
at its start; changing ``SRAT`` or ``SEND`` resets the buffer (a scan of mixed rates
means nothing).
"""

from __future__ import annotations

from collections import deque

__all__ = ["BUFFER_POINTS", "SAMPLE_RATES_HZ", "TRIGGERED_RATE", "DataStorage"]

#: ``SRAT`` 0…13: 62.5 mHz × 2**i.
SAMPLE_RATES_HZ = tuple(0.0625 * 2.0**i for i in range(14))
#: ``SRAT 14``: one point per trigger.
TRIGGERED_RATE = 14
#: Points per channel the buffer holds.
BUFFER_POINTS = 16383
#: ``STRD``'s delay before the first point.
STRD_DELAY_S = 0.5

IDLE, RUNNING, PAUSED, DONE = "idle", "running", "paused", "done"


class DataStorage:
    """The trace buffer's state machine and contents."""

    def __init__(self) -> None:
        self.srat = 4  # 1 Hz
        self.send = 1  # loop
        self.tstr = 0
        self.state = IDLE
        self.points: deque[tuple[float, float]] = deque()
        self._start_t = 0.0
        self._taken = 0  # samples taken (or skipped) since the scan's (re)start time

    @property
    def scanning(self) -> bool:
        """True while points are being acquired (the status byte's SCN bit is clear)."""
        return self.state == RUNNING

    def reset(self) -> None:
        self.state = IDLE
        self.points.clear()
        self._taken = 0

    def start(self, at: float) -> None:
        """``STRT`` (``at`` = now) or ``STRD`` (``at`` = now + 0.5 s): start, or resume
        after ``PAUS``; nothing while running or once a one-shot scan is full."""
        if self.state in (IDLE, PAUSED):
            self.state = RUNNING
            self._start_t = at
            self._taken = 0

    def pause(self) -> None:
        if self.state == RUNNING:
            self.state = PAUSED

    def due(self, now: float) -> list[float]:
        """Sample times up to ``now`` not yet returned, to compute and :meth:`store`, oldest
        first. In loop mode only the last :data:`BUFFER_POINTS` are returned (older ones
        would be overwritten anyway); in one-shot mode no more than fit."""
        if self.state != RUNNING or self.srat == TRIGGERED_RATE:
            return []
        period = 1.0 / SAMPLE_RATES_HZ[self.srat]
        # Samples at start + k·period; k from the next untaken one to the last ≤ now.
        last = int((now - self._start_t) / period + 1e-9)
        first = self._taken
        if now < self._start_t or last < first:
            return []
        room = BUFFER_POINTS if self.send == 1 else BUFFER_POINTS - len(self.points)
        skipped_from = max(first, last + 1 - room)
        self._taken = last + 1
        return [self._start_t + k * period for k in range(skipped_from, last + 1)]

    def store(self, ch1: float, ch2: float) -> None:
        if len(self.points) >= BUFFER_POINTS:
            if self.send == 0:
                self.state = DONE
                return
            self.points.popleft()
        self.points.append((ch1, ch2))
        if self.send == 0 and len(self.points) >= BUFFER_POINTS:
            self.state = DONE

    def trace(self, channel: int, start: int, count: int) -> list[float] | None:
        """Points ``start`` … ``start + count − 1`` of CH``channel``; ``None`` if out of
        range (the SR830 refuses the query)."""
        if count < 1 or start < 0 or start + count > len(self.points):
            return None
        index = channel - 1
        return [self.points[k][index] for k in range(start, start + count)]
