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

Rules fire on the n-th bulk-OUT transfer from now or with a seeded probability through the
shared :class:`hw_mocks.faults.FaultSchedule`, so a failing run replays exactly.
"""

from __future__ import annotations

import enum

from hw_mocks.faults import FaultSchedule

__all__ = ["UsbFaultKind", "UsbFaults"]


class UsbFaultKind(enum.Enum):
    WRITE_TIMEOUT = "write_timeout"
    STALL_OUT = "stall_out"


class UsbFaults(FaultSchedule):
    """Seeded schedule of host-to-device (bulk-OUT) faults; ``log`` lists what fired."""

    def next_write(self) -> UsbFaultKind | None:
        """Count one bulk-OUT write; the fault it suffers, if any (first rule wins)."""
        firing = self.next_event()
        # this schedule holds only UsbFaultKind rules; the base class types them loosely
        return firing[0].kind if firing else None  # type: ignore[return-value]
