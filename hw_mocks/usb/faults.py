"""USB-specific faults that the byte-level :class:`hw_mocks.faults.FaultInjector` cannot express.

The shared injector acts on what the *device sends* (bulk-IN transfers): drop, delay,
split, corrupt, garbage, disconnect (ENODEV), SCPI error states. What happens to what the
*host sends* is USB-specific and lives here:

``WRITE_TIMEOUT``
    The device accepts the first packet of a bulk-OUT transfer and then NAKs the rest,
    so the host's write times out with part of the transfer delivered. Only
    INITIATE_ABORT_BULK_OUT discards that partial transfer (USBTMC 1.0 §4.2.1.2).
``STALL_OUT``
    The device halts the bulk-OUT endpoint (as it does on a malformed header); the write
    fails with EPIPE until the host clears the halt.

Rules fire on the n-th bulk-OUT transfer from now or with a seeded probability, like
:class:`hw_mocks.faults.FaultRule`, so a failing run replays exactly.
"""

from __future__ import annotations

import enum
import random
import threading
from dataclasses import dataclass, field

__all__ = ["UsbFaultKind", "UsbFaultRule", "UsbFaults"]


class UsbFaultKind(enum.Enum):
    WRITE_TIMEOUT = "write_timeout"
    STALL_OUT = "stall_out"


@dataclass
class UsbFaultRule:
    """``nth`` fires on the n-th bulk-OUT write (1-based, counted from when the rule was
    added); otherwise ``probability`` is drawn per write. ``times`` bounds the firings."""

    kind: UsbFaultKind
    nth: int | None = None
    probability: float = 0.0
    times: int | None = 1
    fired: int = 0
    _base: int = field(default=0, repr=False)

    def __post_init__(self) -> None:
        if self.nth is None and not 0.0 < self.probability <= 1.0:
            raise ValueError("a rule needs nth >= 1 or 0 < probability <= 1")
        if self.nth is not None and self.nth < 1:
            raise ValueError("nth counts from 1")


class UsbFaults:
    """Seeded schedule of host-to-device (bulk-OUT) faults; ``log`` lists what fired."""

    def __init__(self, seed: int = 0) -> None:
        self._rng = random.Random(seed)
        self._rules: list[UsbFaultRule] = []
        self._count = 0
        self._lock = threading.Lock()
        self.log: list[tuple[int, UsbFaultKind]] = []

    def schedule(self, kind: UsbFaultKind, nth: int = 1, times: int | None = 1
                 ) -> UsbFaultRule:
        """Fire ``kind`` on the ``nth`` bulk-OUT write from now."""
        return self._add(UsbFaultRule(kind, nth=nth, times=times))

    def randomly(self, kind: UsbFaultKind, probability: float, times: int | None = None
                 ) -> UsbFaultRule:
        """Fire ``kind`` on each bulk-OUT write with ``probability``."""
        return self._add(UsbFaultRule(kind, probability=probability, times=times))

    def clear(self) -> None:
        with self._lock:
            self._rules.clear()

    def _add(self, rule: UsbFaultRule) -> UsbFaultRule:
        with self._lock:
            rule._base = self._count
            self._rules.append(rule)
        return rule

    def next_write(self) -> UsbFaultKind | None:
        """Count one bulk-OUT write; the fault it suffers, if any (first rule wins)."""
        with self._lock:
            self._count += 1
            n = self._count
            hit: UsbFaultKind | None = None
            for rule in self._rules:
                if rule.times is not None and rule.fired >= rule.times:
                    continue
                fires = (n - rule._base == rule.nth) if rule.nth is not None else (
                    self._rng.random() < rule.probability)
                if fires and hit is None:
                    rule.fired += 1
                    hit = rule.kind
                    self.log.append((n, rule.kind))
            self._rules = [r for r in self._rules if r.times is None or r.fired < r.times]
            return hit
