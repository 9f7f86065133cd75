"""Background jobs (analyses, snapshots, the planner's search) with results as signals.

Work that takes longer than a frame — a BRDF fit, a reconstruction, writing a snapshot,
the speed/accuracy sweep — runs on a worker thread of a small pool; its result (or its
exception) comes back to the GUI thread as the :attr:`Background.finished` signal. The GUI
thread never waits for one.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from PySide6.QtCore import QObject, Signal

__all__ = ["Background", "JobDone"]


@dataclass(frozen=True)
class JobDone:
    job_id: int
    name: str
    result: Any
    error: BaseException | None
    elapsed_s: float


class Background(QObject):
    """A pool of worker threads whose finished jobs are reported as signals."""

    finished = Signal(object)  # JobDone
    started = Signal(int, str)

    def __init__(self, workers: int = 1, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="gui-job")
        self._ids = itertools.count(1)
        self.running: dict[int, str] = {}
        self.closed = False
        self.finished.connect(self._forget)

    def submit(self, name: str, fn: Callable[[], Any]) -> int | None:
        """Run ``fn`` on a worker; ``None`` once the pool is shut down (window closing)."""
        if self.closed:
            return None
        job_id = next(self._ids)
        self.running[job_id] = name
        t0 = time.monotonic()

        def done(fut: Future) -> None:  # on the worker thread: only emit
            err = fut.exception()
            self.finished.emit(JobDone(job_id, name, None if err else fut.result(), err,
                                       time.monotonic() - t0))

        fut = self._pool.submit(fn)
        fut.add_done_callback(done)
        self.started.emit(job_id, name)
        return job_id

    def _forget(self, done: JobDone) -> None:
        self.running.pop(done.job_id, None)

    def shutdown(self, wait: bool = True) -> None:
        self.closed = True
        self._pool.shutdown(wait=wait, cancel_futures=True)
