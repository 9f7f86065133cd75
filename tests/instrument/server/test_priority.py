"""``scatterlab serve --nice N``: every thread of the server process runs at the lower
priority, those started before the call too; a niceness outside 0…19 is refused before
anything starts."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from instrument.server.main import ServeRefused, serve
from instrument.server.priority import MAX_NICE, lower_priority

linux = pytest.mark.skipif(not Path("/proc/self/task").is_dir(),
                           reason="per-thread niceness is read from /proc (Linux)")

# In a child process: lowering a priority cannot be undone without privileges.
CHILD = textwrap.dedent("""
    import os, threading
    from instrument.server.priority import lower_priority

    started, done = threading.Event(), threading.Event()
    def before():
        started.set()
        done.wait(60)
    early = threading.Thread(target=before)
    early.start()
    started.wait(60)
    base = os.getpriority(os.PRIO_PROCESS, 0)
    now = lower_priority(4)
    late = []
    later = threading.Thread(target=lambda: late.append(
        os.getpriority(os.PRIO_PROCESS, 0)))
    later.start(); later.join(60)
    print(base, now, os.getpriority(os.PRIO_PROCESS, early.native_id), late[0])
    done.set()
""")


@linux
def test_every_thread_before_and_after_the_call_is_lowered():
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                         timeout=120, check=True, cwd=Path(__file__).resolve().parents[3])
    base, now, early, late = map(int, out.stdout.split())
    want = min(MAX_NICE, base + 4)
    assert (now, early, late) == (want, want, want)


@pytest.mark.parametrize("nice", [-1, MAX_NICE + 1, 100])
def test_a_niceness_out_of_range_is_refused_naming_the_option(nice):
    before = os.getpriority(os.PRIO_PROCESS, 0)
    with pytest.raises(ValueError, match=r"--nice .*0 \(unchanged\) to 19"):
        lower_priority(nice)
    assert os.getpriority(os.PRIO_PROCESS, 0) == before


def test_zero_changes_nothing():
    before = os.getpriority(os.PRIO_PROCESS, 0)
    assert lower_priority(0) == before == os.getpriority(os.PRIO_PROCESS, 0)


def test_serve_refuses_a_bad_niceness_before_it_binds_or_opens_anything(tmp_path):
    with pytest.raises(ServeRefused, match="--nice 20"):
        serve("sim", listen="127.0.0.1:0", runs=tmp_path / "runs", nice=20,
              say=lambda line: None)
    assert not (tmp_path / "runs").exists()
