"""The main job made durable: `scatterlab run` on the emulated sim bench killed with -9
mid-scan, then `scatterlab resume` finishes the same file."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest

from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.run.journal import read_journal
from instrument.run.storage import journal_path

ROOT = Path(__file__).resolve().parents[3]

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "kill and resume"
[sample]
name = "sim-grey"
[scan]
theta_i = [30.0]
theta_r = [-60.0, -45.0, 0.0, 15.0, 30.0, 45.0, 60.0, 75.0]
[acquisition]
mode = "fixed"
exposure_us = 2000
"""


@pytest.mark.slow
@pytest.mark.timeout(900)  # two runs on a bench at 5× real time
def test_cli_run_killed_then_resumed(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    out = tmp_path / "runs"
    # The sim bench with its stages at 5× real time (not 20×): each move takes a few
    # tenths of a second, so the run is seconds long and cannot end between two looks.
    bench = tmp_path / "sim-slow.toml"
    bench.write_text(load_profile("sim").source_text.replace("speed=20", "speed=5"),
                     encoding="utf-8")
    log = tmp_path / "run.log"  # a file, not a pipe: a full pipe nobody reads would block it
    with open(log, "w", encoding="utf-8") as sink:
        child = subprocess.Popen(
            [sys.executable, "-m", "instrument.cli", "run", str(plan), "--bench", str(bench),
             "--out", str(out)], cwd=ROOT, stdout=sink, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 120
    path = None
    while path is None:
        for line in log.read_text(encoding="utf-8").splitlines():
            if "writing " in line:
                path = Path(line.split("writing ", 1)[1].strip())
        assert time.monotonic() < deadline and child.poll() is None, log.read_text()
        time.sleep(0.02)
    while True:  # kill once two points are committed, looking while the process is frozen
        os.kill(child.pid, signal.SIGSTOP)
        records = read_journal(journal_path(path))[0]
        if sum(r["t"] == "point" for r in records) >= 2:
            break
        assert time.monotonic() < deadline, "the run never committed two points"
        os.kill(child.pid, signal.SIGCONT)
        time.sleep(0.02)
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    with h5py.File(path, "r") as f:  # opens as the killed process left it
        assert f["entry"].attrs["status"] == "running"
    assert main(["resume", str(path), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "run finished: 8 of 8 points" in text
    with h5py.File(path, "r") as f:
        idx = list(f["entry/points/index"][:])
        assert f["entry"].attrs["status"] == "finished"
    assert sorted(idx) == list(range(8))
    assert main(["runs", "--out", str(out), "--status", "finished"]) == 0
    assert path.stem in capsys.readouterr().out
