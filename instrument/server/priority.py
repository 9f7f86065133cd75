"""The server process's CPU priority (``scatterlab serve --nice N``).

A zero-latency bench lets the engine run flat out: the server's engine, writer and event
threads then keep every core of a small bench PC busy, and a GUI on the same PC (the local
server that ``scatterlab gui`` starts, :mod:`instrument.client.local`) waits for a CPU
between its event-loop passes — its heartbeat's worst delay was 60–65 ms on a 2-core box
with its own work per pass at most 12–18 ms (BENCHMARKS.md, gui). A niceness above 0 lets
the kernel give the window the CPU first whenever both want it; when nothing else wants the
CPU the server runs as fast as before (niceness is a weight between runnable tasks, not a
cap). See docs/decisions/0084 (amendment of 2026-11-27, the local server's priority).

Two Linux details decide whether it works:

* Linux keeps a niceness per thread, and ``nice(2)``/``setpriority(PRIO_PROCESS, 0, …)``
  change the calling thread's only: threads started before the call (a BLAS pool started
  at import) would keep the old one. :func:`lower_priority` sets every thread listed in
  ``/proc/self/task``; threads started afterwards inherit it from their creator.
* With *autogroups* (``/proc/sys/kernel/sched_autogroup_enabled``, on in most desktop
  distributions) the scheduler first shares the CPUs between sessions (each ``setsid``,
  each terminal) and applies a thread's niceness only against the threads of its own
  session (sched(7), "The autogroup feature"). The GUI therefore starts its local server
  in its own session's scheduling group — a process group of its own, not a session
  (:mod:`instrument.client.local`) — where the niceness ranks the server below the
  window. (Raising the niceness of a session of the server's own instead,
  ``/proc/self/autogroup``, ranks it below *every* busy session on the PC: on a shared
  2-core machine the run then barely started, BENCHMARKS.md gui.) A server typed in a
  terminal is in that terminal's group and ranks below the other programs of that
  terminal only.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

__all__ = ["MAX_NICE", "lower_priority"]

#: The highest niceness (the lowest priority) POSIX systems accept.
MAX_NICE = 19


def lower_priority(nice: int) -> int:
    """Raise this process's niceness by ``nice`` (0 … :data:`MAX_NICE`; 0 changes nothing)
    for every thread it has now and will start; the niceness it runs at afterwards.

    An unprivileged process may only lower its own priority, which is all this does.

    Raises
    ------
    ValueError
        ``nice`` outside 0 … 19 (the message names the option).
    OSError
        The system has no niceness (Windows): the caller says the option is not supported.
    """
    if not 0 <= nice <= MAX_NICE:
        raise ValueError(f"--nice {nice}: give a niceness from 0 (unchanged) to {MAX_NICE} "
                         "(the lowest priority)")
    if not hasattr(os, "setpriority"):
        raise OSError("--nice: this system has no process niceness (use 0)")
    base = os.getpriority(os.PRIO_PROCESS, 0)
    target = min(MAX_NICE, base + nice)
    if nice == 0:
        return base
    tasks = Path("/proc/self/task")
    tids = [int(t.name) for t in tasks.iterdir()] if tasks.is_dir() else [0]
    for tid in tids:
        # a thread that ended since the listing is no longer there to lower
        with contextlib.suppress(ProcessLookupError):
            os.setpriority(os.PRIO_PROCESS, tid, target)
    # the calling thread last (tid 0 above when there is no /proc): new threads inherit it
    os.setpriority(os.PRIO_PROCESS, 0, target)
    return os.getpriority(os.PRIO_PROCESS, 0)

