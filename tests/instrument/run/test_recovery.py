"""Damaged run files: every repair said and recorded, lost points measured again, files
without a journal recovered from what they hold (issue 12 §1)."""

from __future__ import annotations

import os
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest

from instrument.plans import build_plan, parse_plan
from instrument.run.catalog import Catalog
from instrument.run.events import PointCompleted
from instrument.run.health import inspect_run_file
from instrument.run.layout import FRAMES_LOST, end_of_allocation, journal_path, table_chunk_rows
from instrument.run.recovery import recover
from instrument.run.runfile import RunFileError, check_run_file, read_run, read_summary
from instrument.run.runner import recover_run, resume_run, start_run
from instrument.run.storage import FrameData, PointRecord, RunStore
from tests.instrument.helpers import ideal_bench, inplane_plan


def finished_run(folder: Path) -> Path:
    """A finished in-plane run on the ideal bench: 6 points, one 8×8 frame each."""
    bench = ideal_bench(shape=(8, 8), noise_dn=20.0)
    plan = build_plan(parse_plan(inplane_plan(step=40.0)), bench.profile)
    engine = start_run(plan, bench, runs_dir=folder, fsync=False)
    assert engine.run().value == "finished"
    return Path(engine.store.path)


def frame_chunks(path: Path) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """(frame_point, [(byte offset, size)] per frame) of a run file."""
    with h5py.File(path, "r") as f:
        ds = f["entry/data/frames"]
        spans = [(ds.id.get_chunk_info_by_coord((k, 0, 0)).byte_offset,
                  ds.id.get_chunk_info_by_coord((k, 0, 0)).size) for k in range(ds.shape[0])]
        return f["entry/data/frame_point"][()], spans


def cut_through_frames(path: Path) -> tuple[int, set[int]]:
    """Cut the file short inside its frame data; returns the cut and the points whose
    frames lie (partly) beyond it — exactly the frames the cut destroyed."""
    owners, spans = frame_chunks(path)
    order = sorted(range(len(spans)), key=lambda k: spans[k][0])
    cut = spans[order[len(order) // 2]][0] + 4  # inside the middle frame's chunk
    lost = {int(owners[k]) for k, (off, size) in enumerate(spans) if off + size > cut}
    os.truncate(path, cut)
    return cut, lost


def test_a_cut_finished_run_is_repaired_said_and_recorded(tmp_path):
    path = finished_run(tmp_path)
    n = read_summary(path).n_points
    _, expected = cut_through_frames(path)
    assert 0 < len(expected) < n
    report = recover_run(path)  # what `scatterlab resume` does first
    assert report.status == "finished"
    assert set(report.points_lost) == expected and set(report.lost) == expected
    text = " ".join(report.repairs)
    assert "cut short" in text and "frames of point(s)" in text and "status 2" in text
    if report.original is not None:  # rebuilt: the damaged original kept beside it
        assert report.original.exists() and report.original.name in text
    # nothing is repaired twice: a second recovery is silent but still knows the loss
    again = recover(path)
    assert again.repairs == () and set(again.lost) == expected
    # the repair is in the run file's event log, in the catalog, and in the summary
    with h5py.File(path, "r") as f:
        log = [s for s in f["entry/events/log"].asstr()[()] if '"repaired"' in s]
        status = dict(zip(f["entry/points/index"][()], f["entry/points/status"][()],
                          strict=True))
    assert len(log) == 1
    assert {i for i, s in status.items() if s == FRAMES_LOST} == expected
    with Catalog(tmp_path) as cat:
        (row,) = cat.repairs(report.header.run_id)
    assert set(row.points_lost) == expected and row.what == report.repairs
    assert set(read_summary(path).lost) == expected


def test_remeasure_lost_runs_exactly_those_points_into_the_same_file(tmp_path):
    path = finished_run(tmp_path)
    original = read_run(path)
    cut_through_frames(path)
    lost = set(recover_run(path).lost)
    engine = resume_run(path, ideal_bench(shape=(8, 8), noise_dn=20.0), fsync=False,
                        remeasure_lost=True)
    measured = []
    engine.subscribe(lambda ev: measured.append(ev.index)
                     if isinstance(ev, PointCompleted) else None)
    assert engine.run().value == "finished"
    assert sorted(measured) == sorted(lost)
    run = read_run(path)
    assert run.status == "finished" and run.n_points == original.n_points
    assert list(run.index) == list(original.index)  # one row per point, same rows
    assert np.all(run.point_status == 0)
    for row in range(run.n_points):
        light, _, _ = run.frames_of(row)
        assert light.max() > 0  # real frames, not the zeros that stood in
    with h5py.File(path, "r") as f:
        notes = dict(zip(f["entry/points/index"][()], f["entry/points/note"].asstr()[()],
                         strict=True))
        frame_point = f["entry/data/frame_point"][()]
    assert all("re-measured" in notes[i] for i in lost)
    assert np.count_nonzero(frame_point == -1) == len(lost)  # the superseded frames
    report = recover(path)
    assert report.lost == () and report.repairs == ()
    assert read_summary(path).lost == ()


def test_a_remeasure_killed_half_way_keeps_what_it_committed(tmp_path):
    path = finished_run(tmp_path)
    cut_through_frames(path)
    lost = sorted(recover(path).lost)
    assert len(lost) >= 2
    store, done = RunStore.reopen(path, fsync=False)
    assert set(store.lost) == set(lost) and set(lost) <= done
    frame = FrameData(np.full((8, 8), 123, np.uint16), 1000.0, True, 0.0, 0.0)
    store.append(PointRecord(lost[0], "sample", 0.0, 0.0, (0.0, 0.0), frames=[frame]))
    store.abandon()  # killed before the next point and before the status record
    report = recover(path)
    assert report.lost == tuple(lost[1:]) and report.status == "finished"
    run = read_run(path)
    row = int(np.flatnonzero(run.index == lost[0])[0])
    light, _, _ = run.frames_of(row)
    assert np.all(light == 123) and run.point_status[row] == 0
    # and a second --remeasure-lost takes only what is still lost
    engine = resume_run(path, ideal_bench(shape=(8, 8)), fsync=False, remeasure_lost=True)
    measured = []
    engine.subscribe(lambda ev: measured.append(ev.index)
                     if isinstance(ev, PointCompleted) else None)
    engine.run()
    assert sorted(measured) == lost[1:]


def test_a_cut_run_file_without_journal_is_named_and_what_is_readable_recovered(tmp_path):
    path = finished_run(tmp_path)
    planned = read_summary(path).n_planned
    journal_path(path).unlink()
    cut_through_frames(path)
    cut_copy = path.read_bytes()
    state = inspect_run_file(path)
    assert state.state == "damaged" and state.is_run and not state.has_journal
    assert "damaged scatterlab run file" in state.message and "no journal" in state.message
    assert "truncated file" not in state.message and "eof" not in state.message
    assert f"of {planned} planned" in state.message
    with pytest.raises(RunFileError) as exc:  # every analysis says the same
        check_run_file(path, "fit")
    assert str(exc.value) == state.message
    report = recover_run(path)
    assert report.journal_rebuilt and report.original.name.endswith(".corrupt")
    assert report.original.read_bytes() == cut_copy  # the original untouched beside it
    assert journal_path(path).exists()
    # what the message said is readable is what was recovered, frames and all
    assert set(report.done) - set(report.lost) == set(state.readable)
    assert set(report.lost) == set(state.unreadable)
    assert "journal was missing" in report.repairs[0] and "cut short" in report.repairs[0]
    assert inspect_run_file(path).ok
    # resumable now: the points whose records were cut off are measured again
    engine = resume_run(path, ideal_bench(shape=(8, 8)), fsync=False, remeasure_lost=True)
    assert engine.run().value == "finished"
    s = read_summary(path)
    assert s.lost == () and s.n_points == planned and s.status == "finished"


def test_an_intact_run_file_copied_without_its_journal_is_resumed_from_what_it_holds(
        tmp_path):
    path = finished_run(tmp_path)
    before = read_run(path)
    with h5py.File(path, "r") as f:
        frames = f["entry/data/frames"][()]
    journal_path(path).unlink()
    report = recover_run(path)
    assert report.journal_rebuilt and report.original.name.endswith(".orig")
    assert report.lost == () and report.done == set(before.index.tolist())
    assert "journal was missing" in report.repairs[0]
    after = read_run(path)
    assert list(after.index) == list(before.index) and after.status == "finished"
    np.testing.assert_array_equal(after.positions, before.positions)
    with h5py.File(path, "r") as f:
        np.testing.assert_array_equal(f["entry/data/frames"][()], frames)
    assert recover(path).repairs == ()


def test_a_finished_file_gives_back_its_reserved_space_and_sizes_its_chunks(tmp_path):
    path = finished_run(tmp_path)
    assert path.stat().st_size == end_of_allocation(path)
    with h5py.File(path, "r") as f:
        n = int(f["entry"].attrs["n_planned"])
        assert f["entry/points/signal"].chunks == (table_chunk_rows(n),)
        crcs = [zlib.crc32(np.ascontiguousarray(x).tobytes())
                for x in f["entry/data/frames"][()]]
    assert recover(path).repairs == ()  # and the trimmed file is a healthy run file
    assert len(crcs) == read_summary(path).n_frames


def test_a_missing_run_file_with_its_journal_is_rebuilt_and_said_so(tmp_path):
    path = finished_run(tmp_path)
    n = read_summary(path).n_points
    path.unlink()
    report = recover(path)
    assert report.rebuilt and report.original is None
    assert "it was missing" in report.repairs[0] and "kept as" not in report.repairs[0]
    assert len(report.lost) == n  # no frame could be salvaged: every point said lost
    assert read_summary(path).n_points == n
