"""Suite-wide fixtures: emulator URL handlers registered, a clean emulator registry."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

from drivers.transport import add_url_handler_package
from hw_mocks import registry
from hw_mocks.sim.world import reset_worlds

add_url_handler_package("hw_mocks.urlhandler")

# Property tests: no per-example deadline (a loaded 2-core CI box is not a slow parser), and
# in CI a derandomised, replayable sequence of examples, like every other seeded test.
settings.register_profile(
    "scatterlab", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile(
    "ci", parent=settings.get_profile("scatterlab"), derandomize=True, database=None)
settings.load_profile("ci" if os.environ.get("CI") else "scatterlab")


@pytest.fixture(autouse=True)
def _fresh_emulators():
    """Every test starts with freshly powered emulated devices and no virtual worlds."""
    registry.reset()
    reset_worlds()
    yield
    registry.reset()
    reset_worlds()
