"""Seeded fault injection at the transport seam.

Every frame an emulator sends passes through its :class:`FaultInjector`, which may drop,
delay, split, corrupt, prefix with garbage, precede with an unsolicited message, cut the
link, or put the device into an error state. Faults fire by schedule ("the 3rd reply")
or by probability from a seeded generator, so every faulty run can be replayed.

The injector only decides *what happens to bytes*; device-specific parts (what an
unsolicited message or an error state looks like) come from the emulator through the
:class:`FaultTarget` protocol.
"""

from __future__ import annotations

import enum
import itertools
import random
import threading
from dataclasses import dataclass, field
from typing import Protocol

__all__ = ["Delivery", "FaultInjector", "FaultKind", "FaultRule", "FaultSchedule", "FaultTarget",
           "HostWriteHold"]


class FaultKind(enum.Enum):
    DROP = "drop"                  # the reply never arrives
    DELAY = "delay"                # it arrives `delay_s` late, or once `hold` is set
    SPLIT = "split"                # it arrives in `chunks` pieces `gap_s` apart
    CORRUPT = "corrupt"            # `nbytes` random bit flips
    GARBAGE = "garbage"            # `nbytes` random bytes before it
    UNSOLICITED = "unsolicited"    # an unsolicited device message before it
    DISCONNECT = "disconnect"      # the link dies: reads and writes raise from now on
    ERROR_STATE = "error_state"    # the device enters an error state (`code` is passed on)


class FaultTarget(Protocol):
    def unsolicited_frame(self) -> bytes: ...

    def enter_error_state(self, code: str | None = None) -> None: ...


@dataclass
class FaultRule:
    """When and how a fault fires.

    ``nth`` fires on the n-th frame (1-based) counted from when the rule was added;
    otherwise ``probability`` is drawn per frame. ``times`` bounds how often it fires
    (``None`` = unbounded). ``on``: only frames that contain these bytes count and can be
    hit, so a test can aim at one command's reply (the SMC100's ``TE``, a Zaber move's
    ``BUSY``) without counting the replies before it: over a pty a loaded host may time
    out a query and retry it, which adds a reply and would move a counted fault.

    ``hold`` (``DELAY`` only; ``delay_s`` is then not used): the frame, and everything
    sent after it, waits on the wire until the test sets this event, however long that
    is. A reply late by ``delay_s`` of wall-clock time is late only if the host's reading
    thread ran in time, which a loaded machine does not promise; a held reply is late by
    construction: the test lets it go once the driver has given up. A hold never set is
    a lost reply (the link stays open). ``until_host_writes`` (``DELAY`` only): held until
    the host next writes to the device, so that a retried query's late first reply
    arrives just ahead of the retry's own, whatever the load (the host writes again only
    after it gave up on the first).
    """

    kind: enum.Enum  # a FaultKind, or an injector's own kind (e.g. USB faults)
    nth: int | None = None
    probability: float = 0.0
    times: int | None = 1
    delay_s: float = 1.0
    chunks: int = 3
    gap_s: float = 0.01
    nbytes: int = 1
    code: str | None = None
    on: bytes | None = None
    hold: threading.Event | None = None
    until_host_writes: bool = False
    fired: int = 0
    _base: int = field(default=0, repr=False)
    _matched: int = field(default=0, repr=False)

    def __post_init__(self) -> None:
        if self.nth is None and not 0.0 < self.probability <= 1.0:
            raise ValueError("a rule needs nth >= 1 or 0 < probability <= 1")
        if self.nth is not None and self.nth < 1:
            raise ValueError("nth counts from 1")
        if (self.hold is not None or self.until_host_writes) and self.kind is not FaultKind.DELAY:
            raise ValueError("only a DELAY fault can hold its frame")
        if self.hold is not None and self.until_host_writes:
            raise ValueError("a frame is held until an event or until the host writes, "
                             "not both")


class HostWriteHold(threading.Event):
    """The hold of a ``until_host_writes`` fault: the link sets it when the host next
    writes to the device."""


@dataclass(frozen=True)
class Delivery:
    """A piece of bytes to deliver ``delay_s`` after the frame was produced and, where
    ``hold`` is given, not before that event is set."""

    delay_s: float
    data: bytes
    hold: threading.Event | None = None


class FaultSchedule:
    """Seeded rules that decide, event by event, which faults fire.

    Shared by every injector: an *event* is whatever the injector counts (a frame the device
    sends, a bulk-OUT transfer the host writes). Thread-safe; ``log`` records every firing
    as ``(event_number, kind)``.
    """

    def __init__(self, seed: int = 0) -> None:
        self._rng = random.Random(seed)
        self._rules: list[FaultRule] = []
        self._count = 0
        self._lock = threading.RLock()
        self.log: list[tuple[int, enum.Enum]] = []

    def add(self, rule: FaultRule) -> FaultRule:
        with self._lock:
            rule._base = self._count
            self._rules.append(rule)
        return rule

    def schedule(self, kind: enum.Enum, nth: int = 1, **params) -> FaultRule:
        """Fire ``kind`` on the ``nth`` event from now."""
        return self.add(FaultRule(kind, nth=nth, **params))

    def randomly(self, kind: enum.Enum, probability: float, times: int | None = None,
                 **params) -> FaultRule:
        """Fire ``kind`` on each event with ``probability``."""
        return self.add(FaultRule(kind, probability=probability, times=times, **params))

    def clear(self) -> None:
        """Remove all rules."""
        with self._lock:
            self._rules.clear()

    @property
    def events_seen(self) -> int:
        return self._count

    def next_event(self, frame: bytes | None = None) -> list[FaultRule]:
        """Count one event; return the rules that fire on it, in the order added.

        ``frame``: the event's bytes, for rules with ``on`` (an event without bytes never
        matches them).
        """
        with self._lock:
            self._count += 1
            n = self._count
            firing = [r for r in self._rules if self._fires(r, n, frame)]
            for rule in firing:
                rule.fired += 1
                self.log.append((n, rule.kind))
            self._rules = [r for r in self._rules if r.times is None or r.fired < r.times]
            return firing

    def _fires(self, rule: FaultRule, n: int, frame: bytes | None) -> bool:
        if rule.times is not None and rule.fired >= rule.times:
            return False
        if rule.on is not None:
            if frame is None or rule.on not in frame:
                return False
            rule._matched += 1
            n = rule._base + rule._matched
        if rule.nth is not None:
            return n - rule._base == rule.nth
        return self._rng.random() < rule.probability


class FaultInjector(FaultSchedule):
    """Applies :class:`FaultRule` s to the frames a device sends."""

    def __init__(self, seed: int = 0) -> None:
        super().__init__(seed)
        self.disconnected = False

    def clear(self) -> None:
        """Remove all rules and reconnect the link."""
        with self._lock:
            super().clear()
            self.disconnected = False

    def reconnect(self) -> None:
        self.disconnected = False

    @property
    def frames_seen(self) -> int:
        return self.events_seen

    def process(self, frame: bytes, target: FaultTarget) -> list[Delivery]:
        """What actually goes on the wire for ``frame``."""
        with self._lock:
            out = [Delivery(0.0, frame)]
            for rule in self.next_event(frame):
                out = self._apply(rule, out, target)
            return out

    def _apply(self, rule: FaultRule, out: list[Delivery], target: FaultTarget
               ) -> list[Delivery]:
        kind = rule.kind
        data = b"".join(d.data for d in out)
        if kind is FaultKind.DROP:
            return []
        if kind is FaultKind.DELAY:
            hold = HostWriteHold() if rule.until_host_writes else rule.hold
            if hold is not None:  # late by its release, not by a time
                return [Delivery(d.delay_s, d.data, hold) for d in out]
            return [Delivery(d.delay_s + rule.delay_s, d.data, d.hold) for d in out]
        if kind is FaultKind.SPLIT:
            k = max(1, min(rule.chunks, len(data)))
            cuts = sorted(self._rng.sample(range(1, len(data)), k - 1)) if k > 1 else []
            bounds = [0, *cuts, len(data)]
            return [Delivery(i * rule.gap_s, data[a:b])
                    for i, (a, b) in enumerate(itertools.pairwise(bounds))]
        if kind is FaultKind.CORRUPT:
            buf = bytearray(data)
            for _ in range(rule.nbytes):
                if buf:
                    buf[self._rng.randrange(len(buf))] ^= 1 << self._rng.randrange(8)
            return [Delivery(out[0].delay_s if out else 0.0, bytes(buf),
                             out[0].hold if out else None)]
        if kind is FaultKind.GARBAGE:
            junk = bytes(self._rng.randrange(256) for _ in range(rule.nbytes))
            return [Delivery(0.0, junk), *out]
        if kind is FaultKind.UNSOLICITED:
            return [Delivery(0.0, target.unsolicited_frame()), *out]
        if kind is FaultKind.DISCONNECT:
            self.disconnected = True
            return []
        if kind is FaultKind.ERROR_STATE:
            target.enter_error_state(rule.code)
            return out
        raise AssertionError(kind)
