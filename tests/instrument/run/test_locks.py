"""Locks between processes that say who holds them (instrument.run.locks)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest

from instrument.run.locks import LockHeld, hold, holder


def test_the_holder_is_named_while_it_holds_and_forgotten_after(tmp_path):
    path = tmp_path / "x.lock"
    told: list[str] = []
    with hold(path, "scatterlab resume x.h5"):
        me = f"process {os.getpid()}: scatterlab resume x.h5"
        assert holder(path) == me
        # another open file description (another thread here; a process alike) is refused
        with pytest.raises(LockHeld) as exc, hold(path, "second", on_wait=told.append):
            pass
        assert exc.value.holder == me and exc.value.path == path
        assert told == []  # no wait asked for: refused at once, nothing to announce
    assert path.read_text() == "" and holder(path) == "another process"


def test_a_waiter_is_told_once_then_gets_the_lock_when_it_is_released(tmp_path):
    path = tmp_path / "x.lock"
    told: list[str] = []
    release = threading.Event()
    got = threading.Event()

    def waiter() -> None:
        def on_wait(who: str) -> None:
            told.append(who)
            release.set()  # the holder lets go only once the waiter has said it waits

        with hold(path, "waiter", wait_s=120, poll_s=0.01, on_wait=on_wait):
            got.set()

    with hold(path, "first"):
        t = threading.Thread(target=waiter)
        t.start()
        assert release.wait(60)
    t.join(60)
    assert got.is_set() and told == [f"process {os.getpid()}: first"]


def test_a_killed_holder_leaves_no_lock(tmp_path):
    path = tmp_path / "x.lock"
    code = ("import os, sys; from instrument.run.locks import hold\n"
            f"with hold({str(path)!r}, 'doomed'):\n"
            "    print('held', flush=True); os.kill(os.getpid(), 9)\n")
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           timeout=120)
    assert child.stdout == "held\n" and child.returncode == -9
    assert holder(path).endswith(": doomed")  # what it wrote stays, the lock does not
    with hold(path, "next") as p:
        assert holder(p) == f"process {os.getpid()}: next"
