"""Run files and their journal: layout, durability bookkeeping, recovery, catalog."""

from __future__ import annotations

import math
import time
import zlib

import h5py
import numpy as np
import pytest

from instrument.run.catalog import Catalog, RunRow
from instrument.run.journal import Journal, read_journal
from instrument.run.runfile import read_summary
from instrument.run.storage import (
    FrameData,
    PointRecord,
    RunHeader,
    RunStore,
    StorageError,
    journal_path,
    recover,
)


def header(n=5) -> RunHeader:
    return RunHeader(
        run_id="r1", plan_kind="brdf_in_plane", plan_name="p", plan_text="[plan]",
        profile_text="[bench]", bench_name="b", sample_name="s", sample_description="",
        axes=("sample_theta", "detector_theta"),
        planned_targets=[[float(i), 2.0 * i] for i in range(n)],
        planned_angles=[[float(i), 0, float(i), 180] for i in range(n)],
        planned_label=["sample"] * n, planned_light=[True] * n,
        planned_exposure_us=[math.nan] * n, acquisition_policy="{}",
        retry_policies='{"sample_theta": {"attempts": 3}}',
        identities={"sample_theta": {"vendor": "v", "serial": "1"}},
        device_kinds={"sample_theta": "NXpositioner", "camera": "NXdetector"},
        geometry={"kind": "in_plane"}, calibration={"dark": "run-0"},
        software_version="test", created=time.time())


def rec(i, frames=0, rng=None) -> PointRecord:
    rng = rng or np.random.default_rng(i)
    fr = [FrameData(rng.integers(0, 4095, (16, 24)).astype(np.uint16), 100.0 * (k + 1),
                    True, time.time(), 0.0) for k in range(frames)]
    return PointRecord(i, "sample", time.time(), time.time(), (float(i), 2.0 * i),
                       (float(i), 0.0, float(i), 180.0), 100.0, 1e-3 * i, 0.5 * i, frames=fr)


def test_layout_is_nexus_style_and_plain_h5py_reads_it(tmp_path):
    path = tmp_path / "r1.h5"
    store = RunStore.create(path, header(), fsync=False)
    for i in range(3):
        store.append(rec(i, frames=2))
    store.close("finished")
    with h5py.File(path, "r") as f:
        e = f["entry"]
        assert e.attrs["NX_class"] == "NXentry" and e.attrs["status"] == "finished"
        assert e["instrument"].attrs["NX_class"] == "NXinstrument"
        assert e["instrument/sample_theta"].attrs["NX_class"] == "NXpositioner"
        assert e["instrument/sample_theta"].attrs["serial"] == "1"
        assert "attempts" in e["instrument/sample_theta"].attrs["retry_policy"]
        assert e["sample"].attrs["NX_class"] == "NXsample"
        assert e["data"].attrs["signal"] == "signal"
        assert e["calibration"].attrs["dark"] == "run-0"
        assert e["plan/plan_text"][()] == b"[plan]"
        assert list(e["points/index"][:]) == [0, 1, 2]
        assert np.allclose(e["points/positions"][:], [[0, 0], [1, 2], [2, 4]])
        assert list(e["points/frame_start"][:]) == [0, 2, 4]
        assert e["data/frames"].shape == (6, 16, 24)
        assert e["data/frames"].chunks == (1, 16, 24)
        assert list(e["data/frame_point"][:]) == [0, 0, 1, 1, 2, 2]
        assert np.array_equal(e["data/frames"][3], rec(1, frames=2).frames[1].data)
        assert np.allclose(e["data/signal"][:], [0, 0.5, 1.0])
    s = read_summary(path)
    assert (s.n_points, s.n_frames, s.status) == (3, 6, "finished")


def test_compression_only_when_it_pays(tmp_path):
    store = RunStore.create(tmp_path / "a.h5", header(), fsync=False)
    flat = PointRecord(0, "sample", 0, 0, (0, 0),
                       frames=[FrameData(np.full((64, 64), 100, np.uint16), 1, True, 0, 0)])
    store.append(flat)
    store.close("finished")
    with h5py.File(tmp_path / "a.h5") as f:
        assert f["entry/data/frames"].compression == "gzip"
    store = RunStore.create(tmp_path / "b.h5", header(), fsync=False)
    store.append(rec(0, frames=1))  # white noise over 12 bits: gzip does not pay
    store.close("finished")
    with h5py.File(tmp_path / "b.h5") as f:
        assert f["entry/data/frames"].compression is None


def test_journal_discards_torn_tail(tmp_path):
    p = tmp_path / "j"
    j = Journal(p, fsync=False)
    for i in range(3):
        j.append({"i": i})
    j.close()
    with open(p, "ab") as f:
        f.write(b"deadbeef {\"i\": 3")  # torn by a crash mid-write
    records, _good = read_journal(p)
    assert [r["i"] for r in records] == [0, 1, 2]
    j = Journal(p, fsync=False)  # reopening truncates the tail and appends after it
    j.append({"i": 3})
    j.close()
    assert [r["i"] for r in read_journal(p)[0]] == [0, 1, 2, 3]
    data = bytearray(p.read_bytes())
    data[12] ^= 0x01  # a flipped bit in record 0 invalidates it and everything after
    p.write_bytes(bytes(data))
    assert read_journal(p)[0] == []


def test_recover_truncates_uncommitted_and_resume_appends(tmp_path):
    path = tmp_path / "r1.h5"
    store = RunStore.create(path, header(), fsync=False)
    store.append(rec(0, frames=1))
    store.append(rec(1, frames=1))
    # Simulate a crash after point 2's frames reached the file but before its commit:
    store._write_frames(2, rec(2, frames=1).frames)
    store._h5.flush()
    store.abandon()
    report = recover(path)
    assert report.done == {0, 1} and report.n_frames == 2 and not report.rebuilt
    with h5py.File(path) as f:
        assert f["entry/data/frames"].shape[0] == 2
        assert f["entry"].attrs["status"] == "interrupted"
    store, done = RunStore.reopen(path, fsync=False)
    assert done == {0, 1}
    for i in (2, 3, 4):
        store.append(rec(i, frames=1))
    store.close("finished")
    with h5py.File(path) as f:
        assert list(f["entry/points/index"][:]) == [0, 1, 2, 3, 4]
        assert list(f["entry/data/frame_point"][:]) == [0, 1, 2, 3, 4]
        assert np.array_equal(f["entry/data/frames"][2], rec(2, frames=1).frames[0].data)


def test_scalar_rows_lag_in_hdf5_but_recover_from_journal(tmp_path):
    path = tmp_path / "r1.h5"
    store = RunStore.create(path, header(), fsync=False, sync_interval_s=3600)
    for i in range(4):
        store.append(rec(i))
    store.abandon()  # killed: rows only in the journal
    with h5py.File(path) as f:  # the file opens, rows not yet there
        assert f["entry/points/index"].shape[0] < 4
    report = recover(path)
    assert report.n_points == 4
    with h5py.File(path) as f:
        assert list(f["entry/points/index"][:]) == [0, 1, 2, 3]
        assert np.allclose(f["entry/points/power_w"][:], [0, 1e-3, 2e-3, 3e-3])


def test_unreadable_hdf5_is_rebuilt_from_journal(tmp_path):
    path = tmp_path / "r1.h5"
    store = RunStore.create(path, header(), fsync=False)
    for i in range(3):
        store.append(rec(i))
    store.close("paused")
    path.write_bytes(b"\0" * 4096)  # the HDF5 file is destroyed
    report = recover(path)
    assert report.rebuilt and report.n_points == 3
    assert (tmp_path / "r1.h5.corrupt").exists()
    with h5py.File(path) as f:
        assert list(f["entry/points/index"][:]) == [0, 1, 2]
        assert "recovered_from" in f["entry"].attrs


def test_disk_full_is_refused_before_writing(tmp_path):
    path = tmp_path / "r1.h5"
    store = RunStore.create(path, header(), fsync=False)
    store.append(rec(0, frames=1))
    store.min_free_bytes = 1 << 62  # the filesystem is "full" for this run
    with pytest.raises(StorageError, match="disk nearly full") as exc:
        store.append(rec(1, frames=1))
    assert exc.value.errno == 28  # ENOSPC
    store.abandon()
    report = recover(path)
    assert report.done == {0}
    with h5py.File(path) as f:
        assert f["entry/data/frames"].shape[0] == 1


def test_not_a_run(tmp_path):
    with pytest.raises(StorageError, match="no such run file"):
        recover(tmp_path / "nothing.h5")
    assert not journal_path(tmp_path / "nothing.h5").exists()
    with pytest.raises(StorageError, match="is a folder"):
        recover(tmp_path)
    (tmp_path / "text.h5").write_text("hello")
    with pytest.raises(StorageError, match="not a scatterlab run file"):
        recover(tmp_path / "text.h5")
    with h5py.File(tmp_path / "plain.h5", "w") as f:
        f["x"] = 1
    with pytest.raises(StorageError, match="not a scatterlab run file"):
        recover(tmp_path / "plain.h5")
    # A run file copied without its journal: named as a run, and why it cannot resume.
    path = tmp_path / "r1.h5"
    RunStore.create(path, header(), fsync=False).close("paused")
    journal_path(path).rename(tmp_path / "elsewhere")
    with pytest.raises(StorageError, match=r"journal r1\.h5\.journal is missing"):
        recover(path)
    (tmp_path / "elsewhere").write_bytes(b"garbage\n")
    (tmp_path / "elsewhere").rename(journal_path(path))
    with pytest.raises(StorageError, match="no intact run header"):
        recover(path)


def test_catalog_filters(tmp_path):
    with Catalog(tmp_path) as cat:
        for i, (sample, kind, status) in enumerate([("grey", "brdf_in_plane", "finished"),
                                                    ("white", "dark", "paused"),
                                                    ("grey-2", "brdf_in_plane", "paused")]):
            cat.add(RunRow(f"r{i}", sample, kind, "p", "sim", status, 1000.0 + i, None, i,
                           10, f"/x/r{i}.h5"))
        assert [r.run_id for r in cat.find()] == ["r2", "r1", "r0"]
        assert [r.run_id for r in cat.find(sample="grey")] == ["r2", "r0"]
        assert [r.run_id for r in cat.find(status="paused", kind="brdf_in_plane")] == ["r2"]
        assert [r.run_id for r in cat.find(since=1001.5)] == ["r2"]
        cat.update("r1", status="finished", n_points=10, ended=2000.0)
        row = cat.get("r1")
        assert (row.status, row.n_points, row.ended) == ("finished", 10, 2000.0)



def test_catalog_marks_a_killed_run_interrupted_but_leaves_a_live_one(tmp_path):
    from instrument.plans import build_plan, parse_plan
    from instrument.run.runner import start_run
    from tests.instrument.helpers import ideal_bench, inplane_plan

    bench = ideal_bench()
    plan = build_plan(parse_plan(inplane_plan(step=40.0)), bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False)
    run_id, path = engine.store.header.run_id, engine.store.path
    with Catalog(tmp_path) as cat:
        cat.refresh_live()  # the file is held open by this (live) run: row unchanged
        assert cat.get(run_id).status == "created"
    engine.run()
    n = len(plan.points)
    # A process killed mid-run: its row still says "running" and its journal holds
    # some points and no final status (drop the status record and the last 2 points).
    records, _ = read_journal(journal_path(path))
    kept = [r for r in records if r["t"] != "status"]
    kept = kept[: [k for k, r in enumerate(kept) if r["t"] == "point"][-2]]
    journal_path(path).unlink()
    j = Journal(journal_path(path), fsync=False)
    for r in kept:
        j.append(r)
    j.close()
    with Catalog(tmp_path) as cat:
        cat.update(run_id, status="running", n_points=0)
        cat.refresh_live()
        row = cat.get(run_id)
        assert (row.status, row.n_points) == ("interrupted", n - 2)
        assert [r.run_id for r in cat.find(status="interrupted")] == [run_id]
        # A run that ended but whose last catalog update was lost takes the journal's word.
        cat.update(run_id, status="paused")
        records[-1]["status"] = "aborted"
        Journal(journal_path(path), fsync=False).append(records[-1])
        assert cat.refresh(cat.get(run_id)).status == "aborted"
        assert cat.get(run_id).status == "aborted"


def test_points_whose_frames_a_damaged_file_lost_are_marked_for_good(tmp_path):
    from instrument.run.storage import FRAMES_LOST

    path = tmp_path / "r1.h5"
    store = RunStore.create(path, header(6), fsync=False)
    for i in range(3):
        store.append(rec(i, frames=2))
    store.close("paused")
    path.write_bytes(b"\0" * 4096)  # the HDF5 file is destroyed: no frame survives
    report = recover(path)
    assert report.rebuilt and report.points_lost == (0, 1, 2) and report.frames_lost == 6
    store, done = RunStore.reopen(path, fsync=False)  # a second recovery, then new points
    assert done == {0, 1, 2}
    for i in range(3, 6):
        store.append(rec(i, frames=2))
    store.close("finished")
    report = recover(path)
    assert report.points_lost == () and report.frames_lost == 0
    with h5py.File(path) as f:
        e = f["entry"]
        status = dict(zip(e["points/index"][:], e["points/status"][:], strict=True))
        assert status == {0: FRAMES_LOST, 1: FRAMES_LOST, 2: FRAMES_LOST, 3: 0, 4: 0, 5: 0}
        assert "frames lost" in e["points/note"].asstr()[0]
        assert e.attrs["frames_lost"] == 6 and e.attrs["status"] == "finished"
        frames = e["data/frames"][:]
        assert not frames[:6].any()  # zeros stand in for the lost frames...
        crc = zlib.crc32(np.ascontiguousarray(frames[6]).tobytes())
        assert crc == zlib.crc32(rec(3, frames=2).frames[0].data.tobytes())  # ...new intact
