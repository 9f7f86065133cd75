"""Disk full mid-run (a real EFBIG from the kernel): the run pauses with a clear error,
the file stays valid, and resume completes it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import h5py

from instrument.run.runfile import read_events
from instrument.run.runner import resume_run
from instrument.run.storage import recover
from tests.instrument.helpers import ideal_bench

ROOT = Path(__file__).resolve().parents[3]


def test_write_error_pauses_with_clear_error_and_file_stays_valid(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "tests.instrument.run.full_disk_run", str(tmp_path), "1000000"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    lines = out.stdout.splitlines()
    path = Path(lines[0])
    assert any(line.startswith("FAULT storage:") and line.endswith("-> pause")
               for line in lines), out.stdout + out.stderr
    assert any(line.startswith("PAUSED storage:") for line in lines)
    assert "LIGHT False" in lines
    end = next(line for line in lines if line.startswith("END"))
    assert end.startswith("END paused")
    # The file opens with plain h5py as left by the failed process, closed as paused ...
    with h5py.File(path, "r") as f:
        assert f["entry"].attrs["status"] == "paused"
        n_rows = f["entry/points/index"].shape[0]
    # ... with the storage fault and the pause in its event log, like any fault's
    assert _storage_pause_logged(path)
    report = recover(path)
    assert 0 < report.n_points < len(report.header.planned_label)
    assert report.n_points == n_rows and report.frames_lost == 0 and not report.rebuilt
    # ... and, with space again, the run finishes in the same file.
    engine = resume_run(path, ideal_bench(shape=(64, 64)), fsync=False, catalog=False)
    engine.run()
    with h5py.File(path, "r") as f:
        idx = list(f["entry/points/index"][:])
        assert f["entry"].attrs["status"] == "finished"
    assert sorted(idx) == list(range(len(report.header.planned_label)))


def test_write_failing_inside_hdf5_leaves_a_repairable_file(tmp_path):
    """Fallback without the space reservation: HDF5's own flush fails half-way."""
    out = subprocess.run(
        [sys.executable, "-m", "tests.instrument.run.full_disk_run", str(tmp_path), "300000",
         "unreserved"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    lines = out.stdout.splitlines()
    path = Path(lines[0])
    assert any(line.startswith("FAULT storage:") and "File too large" in line
               for line in lines), out.stdout + out.stderr
    end = next(line for line in lines if line.startswith("END"))
    report = recover(path)  # pads what the failed write cut off, keeps committed rows
    assert f"END paused {report.n_points}/" in end
    # the fault and the pause went into the journal; the recovery put them into the log
    assert _storage_pause_logged(path)
    assert report.n_points > 0 and report.frames_lost == 0
    with h5py.File(path, "r") as f:
        assert list(f["entry/points/index"][:]) == sorted(report.done)
    engine = resume_run(path, ideal_bench(shape=(64, 64)), fsync=False, catalog=False)
    engine.run()
    with h5py.File(path, "r") as f:
        idx = list(f["entry/points/index"][:])
    assert sorted(idx) == list(range(len(report.header.planned_label)))


def _storage_pause_logged(path: Path) -> bool:
    """The run's event log holds a storage fault whose action is a pause, then a pause."""
    kinds = [(e["kind"], e.get("device"), e.get("action")) for e in read_events(path)]
    return (("fault", "storage", "pause") in kinds and ("paused", None, None) in kinds
            and kinds.index(("fault", "storage", "pause")) < kinds.index(("paused", None, None)))
