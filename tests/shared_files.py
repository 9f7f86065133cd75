"""Files a test module makes once per test session, whichever pytest-xdist worker asks.

A module-scoped fixture that runs a scan on the emulated bench (a sphere capture, a
photon-transfer sweep) is made once per *worker process* that runs one of the module's
tests, and ``--dist worksteal`` spreads a module's tests over several workers: the same
seeded scan was rendered two or three times in one run of the suite, 10-20 s of CPU each.
:func:`made_once` makes it once per session: the first worker to ask makes it in a folder
all workers share (the session's base temporary folder), the others wait for it, and each
gets its own copy, so a test that writes next to the file (an analysis's results) never
touches another worker's.

Only for what is deterministic (seeded emulators and noise): a worker's copy holds what it
would have measured itself (only the run's clock times differ, which these tests do not
read). Without xdist (``-n 0``) it simply makes the file.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

__all__ = ["MAKE_TIMEOUT_S", "made_once"]

#: Bound on the wait for another worker's make (a hang, not a slow machine: generous).
MAKE_TIMEOUT_S = 900.0


@contextlib.contextmanager
def _locked(path: Path, what: str) -> Iterator[None]:
    """An exclusive ``flock`` on ``path``, polled so that the wait has a bound."""
    with open(path, "a", encoding="utf-8") as fd:
        deadline = time.monotonic() + MAKE_TIMEOUT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise AssertionError(f"timed out after {MAKE_TIMEOUT_S:g} s waiting "
                                         f"for another test process to make {what}") from None
                time.sleep(0.05)
        try:
            yield
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)


def made_once(tmp_path_factory: pytest.TempPathFactory, name: str,
              make: Callable[[Path], Path]) -> Path:
    """``make(folder)`` writes into the empty ``folder`` and returns the path of what it
    made there; returns that path in a copy of the folder private to this process."""
    own = tmp_path_factory.mktemp(name)
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        return make(own)
    # every worker's base temporary folder is a child of the session's
    shared_root = tmp_path_factory.getbasetemp().parent / "made-once"
    shared_root.mkdir(exist_ok=True)
    shared = shared_root / name
    with _locked(shared_root / f"{name}.lock", name):
        if not (shared / ".made").is_file():
            # made in this process's own folder, as without xdist, then published
            made = make(own)
            partial = shared_root / f"{name}.{os.getpid()}.partial"
            shutil.rmtree(partial, ignore_errors=True)
            shutil.copytree(own, partial)
            (partial / ".made").write_text(str(made.relative_to(own)), encoding="utf-8")
            partial.rename(shared)
            return made
    relative = (shared / ".made").read_text(encoding="utf-8")
    shutil.copytree(shared, own, dirs_exist_ok=True)
    (own / ".made").unlink()
    return own / relative
