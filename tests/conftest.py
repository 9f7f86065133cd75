"""Suite-wide fixtures: emulator URL handlers registered, a clean emulator registry."""

from __future__ import annotations

import pytest

from drivers.transport import add_url_handler_package
from hw_mocks import registry
from hw_mocks.sim.world import reset_worlds

add_url_handler_package("hw_mocks.urlhandler")


@pytest.fixture(autouse=True)
def _fresh_emulators():
    """Every test starts with freshly powered emulated devices and no virtual worlds."""
    registry.reset()
    reset_worlds()
    yield
    registry.reset()
    reset_worlds()
