"""kill -9 at random moments: every file opens, committed points are intact, and resume
finishes with no gap and no duplicate (docs/decisions/0010)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest

from instrument.run.journal import read_journal
from instrument.run.runner import resume_run
from instrument.run.storage import journal_path, recover
from tests.instrument.helpers import ideal_bench
from tests.instrument.run.killed_run import SHAPE

ROOT = Path(__file__).resolve().parents[3]


def _kill_once(tmp: Path, rng: np.random.Generator, n_points: int) -> dict:
    child = subprocess.Popen(
        [sys.executable, "-m", "tests.instrument.run.killed_run", str(tmp), str(n_points)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    path = Path(child.stdout.readline().strip())
    time.sleep(float(rng.uniform(0.0, 0.6)))
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    assert path.exists(), child.stderr.read()
    committed = [r for r in read_journal(journal_path(path))[0] if r["t"] == "point"]
    # 1. The file opens with plain h5py, untouched, and what it holds agrees with the
    #    journal (its scalar rows may lag behind the journal, never disagree). A kill in
    #    the middle of H5Fflush can leave a dataset's metadata pointing past the end of the
    #    file (ADR 0010's context; seen once in ~60 kills): its rows are then unreadable,
    #    and step 2 must rebuild them from the journal.
    with h5py.File(path, "r") as f:
        try:
            rows = f["entry/points/index"][:]
        except OSError:
            rows = None
        if rows is not None:
            assert len(rows) <= len(committed) + 1
            for k, i in enumerate(rows[: len(committed)]):
                assert i == committed[k]["index"]
    # 2. After recovery every committed point is intact: values and frame bytes.
    report = recover(path)
    assert report.n_points == len(committed) and report.frames_lost == 0
    with h5py.File(path, "r") as f:
        e = f["entry"]
        idx = e["points/index"][:]
        planned = e["plan/planned_targets"][:]
        assert list(idx) == [r["index"] for r in committed]
        assert np.allclose(e["points/positions"][:], planned[idx])
        crcs = [fr[4] for r in committed for fr in r["frames"]]
        frames = e["data/frames"] if crcs else np.zeros((0, *SHAPE))
        assert frames.shape == (len(crcs), *SHAPE)
        for k in range(len(crcs)):
            assert zlib.crc32(np.ascontiguousarray(frames[k]).tobytes()) == crcs[k]
    # 3. resume finishes the same file with no gap and no duplicate.
    engine = resume_run(path, ideal_bench(shape=SHAPE), fsync=False, catalog=False)
    engine.run()
    with h5py.File(path, "r") as f:
        idx = list(f["entry/points/index"][:])
        n_planned = f["entry"].attrs["n_planned"]
        assert f["entry"].attrs["status"] == "finished"
        assert f["entry/data/frames"].shape[0] == 2 * n_planned
    assert sorted(idx) == list(range(n_planned)) and len(set(idx)) == len(idx)
    return {"committed": len(committed), "planned": int(n_planned)}


@pytest.mark.slow
def test_kill_minus_nine_at_random_moments(tmp_path):
    rng = np.random.default_rng(20260122)
    results = [_kill_once(tmp_path / f"k{i}", rng, 240) for i in range(20)]
    committed = [r["committed"] for r in results]
    # The kills landed at different moments, including mid-run ones.
    assert len(set(committed)) >= 5
    assert any(0 < c < r["planned"] for c, r in zip(committed, results, strict=True))
