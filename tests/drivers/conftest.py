"""Fixtures of the serial drivers' tests: the two transports and the pty servers to stop.

A driver's tests run once in-process through its emulator's URL (``"url"``) and once
through a real pseudo-terminal (``"pty"``); ``servers`` collects the pty servers a test
starts and closes them afterwards.
"""

from __future__ import annotations

import pytest

from hw_mocks.pty_server import PtyServer


@pytest.fixture(params=["url", "pty"])
def transport(request):
    return request.param


@pytest.fixture
def servers():
    started: list[PtyServer] = []
    yield started
    for server in started:
        server.close()


@pytest.fixture
def cleanup():
    """Devices and servers to close after the test, whatever happened (last first)."""
    items: list = []
    yield items
    for item in reversed(items):
        item.close()

