"""Waiting on events in tests without depending on how fast or loaded the machine is.

A test waits for a condition (a move ended, a frame arrived, a thread got somewhere) by
polling it, never by sleeping a guessed time. The timeout only bounds a hang: it is
generous (a passing test returns as soon as the condition holds), and a test never asserts
that something happened *within* a wall-clock time.
"""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["EVENT_TIMEOUT_S", "wait_for"]

#: Default bound on a wait for an event, in seconds.
EVENT_TIMEOUT_S = 60.0


def wait_for(cond: Callable[[], object], timeout: float = EVENT_TIMEOUT_S,
             what: str = "condition") -> None:
    """Poll ``cond`` until true; :class:`AssertionError` naming ``what`` after ``timeout``."""
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(0.002)
