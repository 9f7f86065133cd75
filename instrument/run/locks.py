"""Exclusive locks between processes that say who holds them.

A lock is an ``flock`` on a file of its own: the kernel drops it when its holder dies, so
a killed process leaves no stale lock. The holder writes its process id and what it is
doing into the file, so one that finds the lock taken can say at once who holds it
(:func:`holder`) instead of waiting in silence or failing with the C library's words.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path

__all__ = ["LockHeld", "hold", "holder"]


class LockHeld(RuntimeError):
    """The lock is held by another process (``holder`` says who, when it could be read)."""

    def __init__(self, message: str, path: Path, holder: str) -> None:
        super().__init__(message)
        self.path = path
        self.holder = holder


def holder(path: str | Path) -> str:
    """Who holds the lock file ``path``, as its holder wrote it (``process 123: fit``),
    or ``another process`` when that cannot be read."""
    try:
        text = Path(path).read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError):
        text = ""
    return text.splitlines()[0] if text else "another process"


@contextlib.contextmanager
def hold(path: str | Path, what: str, *, wait_s: float = 0.0, poll_s: float = 0.2,
         on_wait: Callable[[str], None] | None = None) -> Iterator[Path]:
    """Hold the exclusive lock on ``path`` (created if missing) for the block, writing
    ``process PID: what`` into it.

    When another process holds it, ``on_wait(holder)`` is called once, then the lock is
    tried every ``poll_s`` for up to ``wait_s`` seconds (0: not at all).

    Raises
    ------
    LockHeld
        Still held by another process after ``wait_s``.
    """
    path = Path(path)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        deadline = time.monotonic() + wait_s
        told = False
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                who = holder(path)
                if time.monotonic() >= deadline:
                    raise LockHeld(f"{path} is held by {who}", path, who) from None
                if on_wait is not None and not told:
                    on_wait(who)
                    told = True
                time.sleep(poll_s)
        try:
            with contextlib.suppress(OSError):  # a full disk: held all the same, unnamed
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"process {os.getpid()}: {what}\n".encode(), 0)
            yield path
        finally:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)  # nobody holds it now
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)
