"""Faults on a device's answers that a driver must ride out by retrying an idempotent query.

Shared by the tests of the drivers that retry queries (SC10, FW102C): each case is
``(kind, params)`` for :meth:`hw_mocks.faults.FaultSchedule.schedule`, sized for a reply
timeout of 0.1 s (a delay longer than one timeout, shorter than all the attempts).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest

from hw_mocks.faults import FaultInjector, FaultKind

RETRYABLE = [
    (FaultKind.DROP, {}),
    (FaultKind.DELAY, {"delay_s": 0.15}),
    (FaultKind.SPLIT, {"chunks": 4, "gap_s": 0.01}),
    (FaultKind.GARBAGE, {"nbytes": 5}),
    (FaultKind.UNSOLICITED, {}),
]

retryable_faults = pytest.mark.parametrize("kind, params", RETRYABLE)


def assert_query_rides_out(read: Callable[[], Any], expected: Any, faults: FaultInjector,
                           kind: FaultKind, params: dict, *, times: int = 4) -> None:
    """``read()`` returns ``expected`` within 2 s each time one answer suffers the fault."""
    for _ in range(times):
        faults.schedule(kind, nth=1, **params)
        t0 = time.monotonic()
        assert read() == expected
        assert time.monotonic() - t0 < 2.0
    assert [k for _, k in faults.log[-times:]] == [kind] * times
