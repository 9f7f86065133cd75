"""Shared GUI-test helpers: a fast simulated bench, a recording session listener (waiting on
events: :mod:`tests.waiting`)."""

from __future__ import annotations

import threading

from instrument.bench.profile import BenchProfile, load_profile, parse_profile

#: Emulator clock factor of the fast test benches (the built-in profiles use 20).
FAST = 200


def fast_profile(name: str = "sim", speed: int = FAST) -> BenchProfile:
    """A built-in simulated profile with its stage clocks ``speed`` times the wall clock."""
    text = load_profile(name).source_text
    for slow in ("speed=20", "speed=50"):
        text = text.replace(slow, f"speed={speed}")
    return parse_profile(text, source=f"built-in profile {name!r}, speed={speed}")


class Recorder:
    """A SessionListener that keeps everything it is told."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.state_updates = 0
        self.last_states: dict = {}
        self.results: list = []
        self.connections: list = []
        self.runs: list = []

    def states(self, states) -> None:
        with self.lock:
            self.state_updates += 1
            self.last_states = states

    def result(self, result) -> None:
        with self.lock:
            self.results.append(result)

    def connection(self, status) -> None:
        with self.lock:
            self.connections.append(status)

    def run_changed(self, run) -> None:
        with self.lock:
            self.runs.append(run)

    def results_of(self, kind) -> list:
        with self.lock:
            return [r for r in self.results if isinstance(r.command, kind)]
