"""Suite-wide fixtures: emulator URL handlers registered, a clean emulator registry."""

from __future__ import annotations

import pytest

from drivers.transport import add_url_handler_package
from hw_mocks import registry

add_url_handler_package("hw_mocks.urlhandler")


@pytest.fixture(autouse=True)
def _fresh_emulators():
    """Every test starts with freshly powered emulated devices."""
    registry.reset()
    yield
    registry.reset()
