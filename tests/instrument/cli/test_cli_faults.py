"""Faults that end in one clear line, never a traceback or silence, through the command
line on the emulated ``sim`` bench: a disk below the free-space margin at the start and in
the middle of a run (an injected measure of free space, no disk is filled); a cut run file
without its journal, read the same way by every analysis and by ``resume``."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import pytest

from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.run.layout import journal_path
from instrument.run.paths import writer_lock_path
from instrument.run.results import LOCK_WAIT_S, RunBusy, run_lock
from instrument.run.runfile import read_events, read_summary
from instrument.run.storage import free_space_probe

#: A run without frames (power meter only, 21 points): seconds on the emulated bench, and
#: long enough that its status, written last, lies beyond its points table in the file.
SCALAR_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "cli faults"
order = "raster"
[sample]
name = "sim-grey"
[scan]
theta_i = [20.0, 40.0]
theta_r = {start = -80, stop = 80, step = 16}
skip_beam_points = true
[acquisition]
mode = "fixed"
exposure_us = 2000
detectors = ["power_meter"]
"""

ANALYSES = ("fit", "reconstruct", "locate", "spheres")
ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture
def scalar_run(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(SCALAR_PLAN)
    out = tmp_path / "runs"
    assert main(["run", str(plan), "--out", str(out), "--no-fsync", "--quiet"]) == 0
    capsys.readouterr()
    return next(out.glob("*.h5")), out


def _words_of_every_analysis(path, capsys) -> str:
    messages = set()
    for command in ANALYSES:
        assert main([command, str(path)]) == 2
        messages.add(capsys.readouterr().out)
    (message,) = messages  # the same words from every analysis
    return message


def test_a_cut_run_without_journal_is_salvaged_as_every_command_says(scalar_run, capsys):
    """Cut before its points table: the run record (plan, bench) reads, the status written
    at the end does not. The analyses promise a salvage; ``resume`` keeps the promise."""
    path, out = scalar_run
    with h5py.File(path) as f:
        cut = f["entry/points/index"].id.get_chunk_info(0).byte_offset
    journal_path(path).unlink()
    with open(path, "r+b") as fh:
        fh.truncate(cut)
    message = _words_of_every_analysis(path, capsys)
    assert "no journal" in message and "of 21 planned" in message
    assert (f"`scatterlab resume {path}` makes a new run file of the readable points "
            "(the damaged one is kept beside it as .corrupt) and measures the rest"
            ) in message
    assert "nothing" not in message
    rc = main(["resume", str(path), "--out", str(out), "--no-fsync", "--quiet"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "journal was missing" in text and "nothing" not in text
    assert path.with_suffix(".h5.corrupt").exists()
    summary = read_summary(path)
    assert summary.n_points == 21 and summary.status == "finished"


def test_a_run_cut_inside_its_run_record_reads_unrecoverable_everywhere(scalar_run, capsys):
    """Cut inside the plan record: nothing can be rebuilt, and every command, ``resume``
    included, says so in the same sentence."""
    path, out = scalar_run
    with h5py.File(path) as f:
        cut = f["entry/plan/plan_text"].id.get_offset()
    journal_path(path).unlink()
    with open(path, "r+b") as fh:
        fh.truncate(cut)
    message = _words_of_every_analysis(path, capsys)
    assert message.startswith("error: ") and "nothing in it can be recovered" in message
    assert main(["resume", str(path), "--out", str(out), "--quiet"]) == 2
    assert capsys.readouterr().out == message


#: A run with frames (64 × 64 px: quick), so that every point's write checks free space.
FRAME_PLAN = SCALAR_PLAN.replace('detectors = ["power_meter"]', 'detectors = ["camera"]')
MiB = 1 << 20


class SmallDisk:
    """Free space as a filling disk reports it: plenty for the first ``calls`` checks
    (the run file's creation is the first, each point's write one more), then ``free``."""

    def __init__(self, calls: int, free: int = 10 * MiB) -> None:
        self.left, self.free = calls, free

    def __call__(self, folder) -> int:
        self.left -= 1
        return 1 << 40 if self.left >= 0 else self.free


@pytest.fixture
def small_camera_bench(tmp_path):
    text = load_profile("sim").source_text.replace(
        "simcam://camera?world=sim&seed=1", "simcam://camera?world=sim&seed=1&width=64&height=64")
    path = tmp_path / "sim_small.toml"
    path.write_text(text)
    return path


def test_a_run_on_a_disk_below_the_margin_is_refused_in_one_line(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(SCALAR_PLAN)
    out = tmp_path / "runs"
    with free_space_probe(lambda folder: 10 * MiB):
        assert main(["run", str(plan), "--out", str(out), "--quiet"]) == 2
    captured = capsys.readouterr()
    assert captured.out.splitlines()[-1] == (  # after the plan's note on left-out points
        f"error: disk nearly full: 10.0 MiB free in {out.resolve()}, the run keeps at least "
        "64.0 MiB free; free space or choose another folder for run files, then start the "
        "run again")
    assert "resume" not in captured.out + captured.err
    assert not list(out.glob("*.h5*"))  # no run file, so nothing to resume


@pytest.fixture
def paused_run(tmp_path, capsys, small_camera_bench):
    """A run that a disk filling after three points paused: (its file, the options of
    ``run``/``resume`` here, what ``run`` printed)."""
    plan = tmp_path / "p.toml"
    plan.write_text(FRAME_PLAN)
    out = tmp_path / "runs"
    argv = ["--out", str(out), "--bench", str(small_camera_bench), "--quiet", "--no-fsync"]
    with free_space_probe(SmallDisk(calls=4)):  # creation and three points fit
        assert main(["run", str(plan), *argv]) == 1
    text = capsys.readouterr().out
    return next(out.glob("*.h5")).resolve(), argv, text


def test_a_disk_full_pause_and_its_resolution_are_in_the_event_log(paused_run, capsys):
    path, argv, text = paused_run
    assert "run paused: 3 of 21 points" in text and "disk nearly full" in text
    events = read_events(path)
    (fault,) = [e for e in events if e["kind"] == "fault"]
    assert fault["device"] == "storage" and fault["action"] == "pause"
    assert "disk nearly full: 10.0 MiB free" in fault["cause"]
    # the axes the run homed come first (each a "homed" line); then the storage fault
    assert [e["kind"] for e in events if e["kind"] != "homed"] == ["fault", "paused"]
    assert main(["resume", str(path), *argv[2:]]) == 0  # space freed
    capsys.readouterr()
    kinds = [e["kind"] for e in read_events(path) if e["kind"] != "homed"]
    assert kinds[:3] == ["fault", "paused", "resumed"]
    assert read_summary(path).n_points == 21


def _wait_for(condition, what: str, timeout_s: float = 120.0) -> None:
    """Poll ``condition`` until true; the timeout only catches a hang, it times nothing."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_the_second_of_two_resumes_says_who_continues_the_run(paused_run):
    path, argv, _text = paused_run  # 3 of 21 points
    lock = writer_lock_path(path)
    first = subprocess.Popen([sys.executable, "-m", "instrument.cli", "resume", str(path),
                              *argv[:2], "--quiet", "--no-fsync"], cwd=ROOT,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        _wait_for(lambda: lock.is_file() and f"process {first.pid}:" in lock.read_text(),
                  "the first resume to hold the run")
        os.kill(first.pid, signal.SIGSTOP)  # it holds the run for as long as we look
        try:
            second = subprocess.run([sys.executable, "-m", "instrument.cli", "resume",
                                     str(path), *argv[:2], "--quiet"], cwd=ROOT,
                                    capture_output=True, text=True, timeout=300)
        finally:
            os.kill(first.pid, signal.SIGCONT)
        assert second.returncode == 2
        assert "Traceback" not in second.stderr + second.stdout
        assert second.stdout == (
            f"error: run {path.name} is being continued by process {first.pid}: scatterlab "
            f"resume {path.name} (lock {lock}); wait for it to end, or stop it, then resume "
            "again\n")
        text, _ = first.communicate(timeout=300)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert first.returncode == 0, text
    assert read_summary(path).n_points == 21
    with h5py.File(path) as f:
        index = list(f["entry/points/index"][()])
    assert sorted(index) == list(range(21))  # none twice: the loser wrote nothing


def test_a_fit_on_a_locked_run_says_at_once_who_holds_it_and_how_long_it_waits(scalar_run):
    path, _out = scalar_run
    path = path.resolve()
    with run_lock(path, what="scatterlab batch fit") as lock:
        fit = subprocess.Popen([sys.executable, "-m", "instrument.cli", "fit", str(path)],
                               cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: lines.put(fit.stdout.readline()), daemon=True).start()
        try:
            first = lines.get(timeout=120)  # said while the lock is still held
        except queue.Empty:
            fit.kill()
            raise
        assert first == (f"waiting: another analysis of {path.name} (process {os.getpid()}: "
                         f"scatterlab batch fit) is writing its results; this one starts "
                         f"when it ends (at most {LOCK_WAIT_S:g} s)\n")
        assert fit.poll() is None  # still waiting for the lock
        # another thread of this process is refused at once, naming the holder
        with (pytest.raises(RunBusy, match=f"process {os.getpid()}: scatterlab batch fit"),
              run_lock(path, wait_s=0)):
            pass
    rest, err = fit.communicate(timeout=300)  # the lock is free: the fit goes on
    assert "Traceback" not in err + rest
    assert fit.returncode == 2 and rest == "error: point 0 has no frames\n"  # its own end
    assert lock.read_text() == ""  # nobody holds it now


def test_resuming_a_file_that_is_no_run_leaves_no_lock_beside_it(tmp_path, capsys):
    notes = tmp_path / "notes.h5"
    notes.write_text("not an HDF5 file")
    assert main(["resume", str(notes), "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().out == (f"error: {notes} is not a scatterlab run file (not an "
                                       "HDF5 file)\n")
    assert not writer_lock_path(notes).exists()
