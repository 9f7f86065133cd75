"""The simulated camera's worker threads: its renderers and its sensor split large arrays
into blocks of pixels and compute them here (NumPy releases the GIL in its loops).

A block is :data:`BLOCK_PIXELS` pixels: the ~40 float64 temporaries of a block's pupil
rays (128 KiB each) stay within a core's L2 cache, which a 10⁵-pixel piece's do not
(BENCHMARKS.md "main job"). Every pixel is computed exactly as in one piece.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

__all__ = ["BLOCK_PIXELS", "THREADS", "in_blocks"]

#: Worker threads (at most; the machine's cores) and the pixels of one block of work.
THREADS = max(1, min(4, os.cpu_count() or 1))
BLOCK_PIXELS = 16384

_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    """The shared worker threads, started on first use."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(THREADS, thread_name_prefix="simcam-worker")
        return _POOL


def in_blocks(calls: list[tuple]) -> list:
    """``[fn(*args) for fn, *args in calls]``, computed by the worker threads when there
    are several calls and threads (each call exactly as on its own)."""
    if len(calls) <= 1 or THREADS <= 1:
        return [fn(*args) for fn, *args in calls]
    futures = [_pool().submit(fn, *args) for fn, *args in calls]
    return [f.result() for f in futures]
