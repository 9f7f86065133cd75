"""Adaptive plans in the engine: the plan grows in the run file crash-safely, the guard's
refusals reach the plan, and a run killed mid-way resumes to the same decisions
(docs/decisions/0091)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from instrument.plans.adaptive import (
    AdaptiveReplayError,
    History,
    Proposal,
    UnknownAdaptivePlan,
    signed_in_plane,
)
from instrument.plans.build import build_plan
from instrument.run.journal import read_journal
from instrument.run.layout import grow_plan_tables, header_from_file, journal_path, new_run_file
from instrument.run.recovery import recover
from instrument.run.runfile import read_planned, read_run, read_summary
from instrument.run.runner import resume_run
from tests.instrument.run.adaptive_bench import lobe_bench, lobe_plan, start

ROOT = Path(__file__).resolve().parents[3]


def _planned_angles(path: Path) -> np.ndarray:
    return read_planned(path).angles


def _check_complete(path: Path) -> None:
    with h5py.File(path, "r") as f:
        e = f["entry"]
        idx = sorted(e["points/index"][()])
        n = int(e.attrs["n_planned"])
        assert e.attrs["status"] == "finished"
        assert e["plan/planned_angles"].shape[0] == n
    assert idx == list(range(n))  # every planned point once: no gap, no duplicate


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted sharp-lobe run on the lobe bench."""
    engine = start(tmp_path_factory.mktemp("ref"), lobe_plan())
    assert engine.run().value == "finished", engine.snapshot()
    return engine.store.path


def test_adaptive_run_grows_the_planned_table(reference):
    planned = read_planned(reference)
    n_base = len(build_plan(lobe_plan().base, lobe_bench().profile).points)
    assert len(planned.label) > n_base + 4  # at least two refinement batches
    _check_complete(reference)
    records, _ = read_journal(journal_path(reference))
    decisions = [r for r in records if r["t"] == "planned"]
    assert decisions[0]["first"] == n_base
    assert sum(len(d["points"]) for d in decisions) == len(planned.label) - n_base
    # the refinement sits around the peak (θr = θi = 30°): within the plan's ±15° window
    # of the fitted peak, half of it on the lobe's flanks (α = 0.05: FWHM ≈ 7°)
    tr = np.array([signed_in_plane(a)[1] for a in planned.angles[n_base:]])
    assert np.all(np.abs(tr - 30.0) <= 17.0)
    assert np.median(np.abs(tr - 30.0)) <= 8.0
    # the reader sees the grown plan and every measured point
    run = read_run(reference)
    assert run.n_points == len(planned.label)
    desc = json.loads(read_summary(reference).adaptive)
    assert desc["name"] == "sharp_lobe" and desc["seed"] == 0


def test_recover_extends_a_planned_table_the_file_lacks(reference, tmp_path):
    """A kill between the journal's decision and the file's table write: the journal
    stands, recovery writes the table."""
    path = tmp_path / reference.name
    path.write_bytes(reference.read_bytes())
    journal_path(path).write_bytes(journal_path(reference).read_bytes())
    want = _planned_angles(reference)
    with h5py.File(path, "r+") as f:
        for name in ("planned_angles", "planned_targets", "planned_label", "planned_light",
                     "planned_exposure_us"):
            f["entry/plan"][name].resize(20, axis=0)
    report = recover(path)
    assert len(report.header.planned_label) == len(want)
    np.testing.assert_array_equal(_planned_angles(path), want)
    _check_complete(path)


def test_kill_mid_adaptive_run_then_resume_decides_the_same(reference, tmp_path):
    n_base = len(build_plan(lobe_plan().base, lobe_bench().profile).points)
    kill_at = n_base + 5  # inside the second refinement batch
    child = subprocess.run(
        [sys.executable, "-m", "tests.instrument.run.adaptive_bench", str(tmp_path),
         str(kill_at)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert child.returncode == -9, child.stderr
    path = Path(child.stdout.splitlines()[0])
    records, _ = read_journal(journal_path(path))
    done = {r["index"] for r in records if r["t"] == "point"}
    assert kill_at - 1 in done and max(done) <= kill_at
    assert len([r for r in records if r["t"] == "planned"]) == 2
    # resumed from the file's own description (the registered plan, its seed)
    engine = resume_run(path, lobe_bench(), fsync=False, catalog=False)
    assert engine.run().value == "finished"
    _check_complete(path)
    np.testing.assert_allclose(_planned_angles(path), _planned_angles(reference), atol=1e-9)


def test_resume_with_a_plan_that_decides_otherwise_is_refused(reference, tmp_path):
    path = tmp_path / reference.name
    path.write_bytes(reference.read_bytes())
    journal_path(path).write_bytes(journal_path(reference).read_bytes())
    with pytest.raises(AdaptiveReplayError, match="decided other points"):
        resume_run(path, lobe_bench(), fsync=False, catalog=False,
                   adaptive=lobe_plan(seed=7))


class _Probe:
    """Proposes one point in the beam, one below the sample's horizon and one good point;
    then stops, keeping what it was told."""

    def __init__(self) -> None:
        self.seen: list[History] = []
        self.inner = lobe_plan()

    @property
    def base(self):
        return self.inner.base

    def describe(self):
        return {"name": "probe", "seed": 0, "params": {}}

    def propose(self, history: History):
        self.seen.append(history)
        if len(self.seen) == 1:
            return [Proposal(30.0, -30.0), Proposal(30.0, 95.0), Proposal(30.0, 45.0)]
        return None


def test_guard_refusal_reaches_the_plan_not_the_run(tmp_path):
    probe = _Probe()
    engine = start(tmp_path, probe)
    assert engine.run().value == "finished"
    first, second = probe.seen
    assert first.refused == () and len(first.points) == len(second.points) - 1
    reasons = {r.proposal.theta_r: r.reason for r in second.refused}
    assert set(reasons) == {-30.0, 95.0}
    assert "beam" in reasons[-30.0] or "source" in reasons[-30.0]
    assert second.points[-1].theta_r == pytest.approx(45.0)
    events = [r for r in read_journal(journal_path(engine.store.path))[0]
              if r["t"] == "event" and r.get("kind") == "refused"]
    assert {e["theta_r"] for e in events} == {-30.0, 95.0}
    _check_complete(engine.store.path)
    # a resume cannot rebuild a plan this program does not know, and says what to do
    with pytest.raises(UnknownAdaptivePlan, match="pass the plan object"):
        resume_run(engine.store.path, lobe_bench(), fsync=False, catalog=False)


# ------------------------------------------------------------------- the growing table
_angle = st.floats(-89.0, 89.0, allow_nan=False)
_row = st.builds(lambda a, b, lab, e: {"targets": [a, b], "angles": [abs(a), 0.0, abs(b),
                                                                       180.0],
                                       "label": lab, "light": True, "exposure_us": e},
                 _angle, _angle, st.sampled_from(["sample", "dark"]),
                 st.one_of(st.just(math.nan), st.floats(1.0, 1e6)))


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(base=st.integers(1, 4), batches=st.lists(st.lists(_row, min_size=1, max_size=5),
                                                max_size=4))
def test_a_plan_grown_in_batches_reads_as_one_planned_at_once(tmp_path, base, batches):
    """Extending the file batch by batch (as the run does, and as recovery does from the
    journal) leaves the same tables as a file created with every point planned."""
    from tests.instrument.run.test_storage import header

    h0 = replace(header(base), adaptive='{"name": "probe"}')
    grown_path, once_path = tmp_path / "grown.h5", tmp_path / "once.h5"
    for p in (grown_path, once_path):
        p.unlink(missing_ok=True)
    h = h0
    with new_run_file(grown_path, h0) as f:
        for rows in batches:
            h = h.with_planned(rows)
            grow_plan_tables(f["entry/plan"], h)
    new_run_file(once_path, h).close()
    with h5py.File(grown_path) as g, h5py.File(once_path) as o:
        for name in ("planned_targets", "planned_angles", "planned_light",
                     "planned_exposure_us", "planned_label"):
            np.testing.assert_array_equal(g["entry/plan"][name][()], o["entry/plan"][name][()])
        assert g["entry"].attrs["n_planned"] == base + sum(map(len, batches))
        assert header_from_file(g).planned_label == h.planned_label
        assert header_from_file(g).adaptive == h0.adaptive
