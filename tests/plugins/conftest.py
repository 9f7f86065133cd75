"""The plugin tests need the example plugin installed, as the README's test command and
``.ci/run`` install it (``pip install -e ".[dev]" -e examples/plugin_driver``); without it
each test fails saying so, rather than with an unknown driver."""

from __future__ import annotations

import importlib.util

import pytest


@pytest.fixture(autouse=True)
def _example_plugin_installed():
    if importlib.util.find_spec("example_meter") is None:
        pytest.fail("the example plugin is not installed in this environment: run "
                    "pip install -e examples/plugin_driver (the README's test command does)",
                    pytrace=False)
