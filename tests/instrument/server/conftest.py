"""Fixtures of the server tests: server processes are always killed at teardown."""

from __future__ import annotations

import pytest

from tests.instrument.server.helpers import ServerProcess, fast_profile_text


@pytest.fixture
def bench_file(tmp_path):
    def make(**kw) -> str:
        path = tmp_path / "sim-fast.toml"
        path.write_text(fast_profile_text(**kw), encoding="utf-8")
        return path
    return make


@pytest.fixture
def start_server(tmp_path):
    started: list[ServerProcess] = []

    def start(bench, runs=None, **kw) -> ServerProcess:
        server = ServerProcess(bench, runs or tmp_path / "runs", **kw)
        started.append(server)
        return server

    yield start
    for server in started:
        server.kill()
