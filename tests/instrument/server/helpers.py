"""Shared pieces of the server tests: a fast emulated bench, small plans, a server process
on a random loopback port that is always killed at teardown."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

from instrument.bench.profile import load_profile

ROOT = Path(__file__).resolve().parents[3]

#: Stage clocks this many times the wall clock.
FAST = 200


def fast_profile_text(*, pause_on_detector_fault: bool = False, speed: int = FAST) -> str:
    """The built-in sim bench with stages at ``speed`` times real time; optionally a
    detector arm whose failure pauses the run for the operator (instead of the default
    retry policy)."""
    text = load_profile("sim").source_text
    for slow in ("speed=20", "speed=50"):
        text = text.replace(slow, f"speed={speed}")
    if pause_on_detector_fault:
        text = text.replace("[devices.camera_z]", "[devices.detector_theta.retry]\n"
                            "attempts = 1\nbackoff_s = 0.0\non_failure = \"pause\"\n\n"
                            "[devices.camera_z]")
    return text


def plan_text(name: str, theta_r: list[float], theta_i: float = 20.0) -> str:
    """A small in-plane plan read by the power meter only (no camera frames: quick)."""
    return f"""
[plan]
kind = "brdf_in_plane"
name = "{name}"
[sample]
name = "server-test"
[scan]
theta_i = [{theta_i}]
theta_r = {theta_r!r}
[acquisition]
mode = "fixed"
exposure_us = 1000
detectors = ["power_meter"]
"""


class ServerProcess:
    """``scatterlab serve`` (through :mod:`tests.instrument.server.sim_server`) on a random
    loopback port; :meth:`kill` sends SIGKILL."""

    def __init__(self, bench: Path, runs: Path, *, env: dict[str, str] | None = None,
                 args: tuple[str, ...] = (), listen: str = "127.0.0.1:0") -> None:
        """``listen``: a fixed port to restart a server on where a killed one was."""
        self.bench, self.runs = bench, runs
        full_env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        full_env.pop("SCATTERLAB_SERVER", None)
        full_env.pop("SCATTERLAB_KEY", None)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.instrument.server.sim_server", "--bench",
             str(bench), "--runs", str(runs), "--listen", listen, "--no-fsync",
             *args],
            cwd=ROOT, env=full_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True)
        self.lines: list[str] = []
        self.url = self._read_url()
        # keep reading its output, so that a full pipe never blocks the server
        self._reader = threading.Thread(target=self._drain, daemon=True)
        self._reader.start()

    def _read_url(self) -> str:
        for line in self.proc.stdout:
            self.lines.append(line)
            m = re.search(r"serving bench .* on (https?://127\.0\.0\.1:\d+)", line)
            if m:
                return m.group(1)
        raise AssertionError("the server did not start:\n" + "".join(self.lines))

    def _drain(self) -> None:
        with contextlib.suppress(ValueError, OSError):
            for line in self.proc.stdout:
                self.lines.append(line)

    def kill(self) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(60)

    def stop(self) -> int:
        """SIGTERM: the server aborts a run (resumable) and exits."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(120)
