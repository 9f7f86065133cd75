"""Shared fixtures of the light-field tests."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).parents[3] / "benchmarks" / "bench_lightfield_validation.py"


@pytest.fixture(scope="module")
def bench():
    """The validation matrix's script as a module (its scenes, renders, scoring)."""
    spec = importlib.util.spec_from_file_location("bench_lightfield_validation", BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop(spec.name, None)
