"""The GUI's local server: started once per runs folder as a child process, found again
by the next GUI, stopped by ``scatterlab gui --stop-server``."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import pytest

from instrument.client import BenchClient
from instrument.client.local import LOCAL_NICE, LOCAL_STATE, local_server, stop_local_server


def _thread_niceness(pid: int) -> set[int]:
    """The niceness of each thread of process ``pid`` (Linux keeps one per thread)."""
    out = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
            out.add(os.getpriority(os.PRIO_PROCESS, int(task.name)))
    return out


@pytest.mark.timeout(600)
def test_a_local_server_is_started_once_found_again_and_stopped(bench_file, tmp_path):
    runs = tmp_path / "runs"
    first = local_server(str(bench_file()), runs)
    try:
        assert first.started and first.alive() and first.url.startswith("http://127.0.0.1:")
        again = local_server("sim", runs)  # the next GUI: the same server, whatever bench
        assert not again.started and again.pid == first.pid and again.url == first.url
        with BenchClient(first.url) as c:
            assert c.status()["connected"]
        if Path(f"/proc/{first.pid}/task").is_dir():
            # below the GUI's priority, every thread of it (ADR 0084's amendment)
            want = min(19, os.getpriority(os.PRIO_PROCESS, 0) + LOCAL_NICE)
            assert _thread_niceness(first.pid) == {want}
            # in this process's session (its scheduling group under autogroups, where
            # the niceness counts) but not in its process group (a Ctrl-C here)
            assert os.getsid(first.pid) == os.getsid(0)
            assert os.getpgid(first.pid) == first.pid != os.getpgid(0)
        assert "stopped the local server" in stop_local_server(runs)
        assert not first.alive() and not (runs / LOCAL_STATE).exists()
        assert stop_local_server(runs).startswith("no local server is running")
    finally:
        first.stop(10.0)


def test_a_server_that_cannot_start_says_why(tmp_path):
    from instrument.client.local import LocalServerError

    with pytest.raises(LocalServerError, match="did not start"):
        local_server(str(tmp_path / "no-such-profile.toml"), tmp_path / "runs")
