"""Where the GUI thread is when its heartbeat is late: stack samples and gc pauses.

A watchdog thread checks the heartbeat every millisecond; while the heartbeat is more
than ``late_ms`` overdue, it samples the GUI thread's Python stack
(``sys._current_frames``) every ``every_ms`` and counts the innermost frames of the
project's, pyqtgraph's and Qt-wrapper code. Garbage collections are timed with
``gc.callbacks`` (on whichever thread triggered them). The sampler needs the interpreter
lock to take a sample, so a stall in which another thread holds it is seen as the GUI
thread's stack once the lock is free; the other threads' stacks are sampled too, to say
who was running.

Used by ``benchmarks/bench_gui.py --server --stalls``.
"""

from __future__ import annotations

import collections
import gc
import sys
import threading
import time
import traceback

__all__ = ["StallSampler"]


def _where(frame, depth: int = 6) -> str:
    """The innermost ``depth`` frames as ``file:function:line`` (file without its folder)."""
    out = []
    for fs in traceback.extract_stack(frame)[-depth:]:
        out.append(f"{fs.filename.rsplit('/', 1)[-1]}:{fs.name}:{fs.lineno}")
    return " < ".join(reversed(out))


class StallSampler:
    def __init__(self, beats: list[float], *, late_ms: float = 20.0, every_ms: float = 2.0,
                 ) -> None:
        self.beats = beats  # the heartbeat's list of fire times (perf_counter), appended
        self.late = late_ms / 1000.0
        self.every = every_ms / 1000.0
        self.gui = threading.get_ident()
        self.gui_stacks: collections.Counter[str] = collections.Counter()
        self.other_stacks: collections.Counter[str] = collections.Counter()
        self.gc_pauses: list[tuple[int, float, str]] = []  # generation, s, thread
        self.n_samples = 0
        self._gc_t0: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="stall-sampler",
                                        daemon=True)

    def _gc(self, phase: str, info: dict) -> None:
        ident = threading.get_ident()
        if phase == "start":
            self._gc_t0[ident] = time.perf_counter()
        elif ident in self._gc_t0:
            name = "gui" if ident == self.gui else threading.current_thread().name
            self.gc_pauses.append((info["generation"],
                                   time.perf_counter() - self._gc_t0.pop(ident), name))

    def start(self) -> None:
        gc.callbacks.append(self._gc)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        gc.callbacks.remove(self._gc)

    def _watch(self) -> None:
        names = {}
        while not self._stop.wait(0.001):
            if not self.beats or time.perf_counter() - self.beats[-1] < self.late:
                continue
            frames = sys._current_frames()
            gui = frames.get(self.gui)
            if gui is None:
                continue
            self.n_samples += 1
            self.gui_stacks[_where(gui)] += 1
            if not names:
                names = {t.ident: t.name for t in threading.enumerate()}
            for ident, frame in frames.items():
                if ident not in (self.gui, threading.get_ident()):
                    self.other_stacks[f"[{names.get(ident, ident)}] {_where(frame, 3)}"] += 1
            time.sleep(self.every)

    def report(self, top: int = 12) -> str:
        lines = [f"{self.n_samples} samples of the GUI thread while its heartbeat was more "
                 f"than {self.late * 1e3:.0f} ms late"]
        for where, n in self.gui_stacks.most_common(top):
            lines.append(f"  {n:5d}  {where}")
        lines.append("other threads at the same moments:")
        for where, n in self.other_stacks.most_common(top):
            lines.append(f"  {n:5d}  {where}")
        by_thread = collections.defaultdict(list)
        for gen, s, name in self.gc_pauses:
            by_thread[(name, gen)].append(s)
        lines.append("garbage collections (thread, generation: count, total, worst):")
        for (name, gen), ss in sorted(by_thread.items()):
            lines.append(f"  {name} gen {gen}: {len(ss)}, {sum(ss) * 1e3:.1f} ms, "
                         f"worst {max(ss) * 1e3:.1f} ms")
        return "\n".join(lines)
