"""The run engine on ideal (zero-latency) devices: events, pause/resume/abort, HDR,
storage errors, resume without gaps or duplicates."""

from __future__ import annotations

import threading

import h5py
import numpy as np
import pytest

from instrument.plans import build_plan, parse_plan
from instrument.run.engine import EngineState
from instrument.run.events import (
    EventQueue,
    Fault,
    Paused,
    PointCompleted,
    Progress,
    Resumed,
    RunFinished,
    RunStarted,
)
from instrument.run.runner import plan_from_run, resume_run, start_run
from instrument.run.storage import recover
from tests.instrument.helpers import ideal_bench, inplane_plan


def _run(tmp_path, text=None, bench=None, **kw):
    bench = bench or ideal_bench()
    plan = build_plan(parse_plan(text or inplane_plan()), bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False, **kw)
    q = EventQueue()
    engine.subscribe(q)
    return engine, q, plan, bench


def _indices(path):
    with h5py.File(path) as f:
        return list(f["entry/points/index"][:])


def test_run_events_and_file(tmp_path):
    engine, q, plan, bench = _run(tmp_path)
    assert engine.run() is EngineState.FINISHED
    events = q.drain()
    assert isinstance(events[0], RunStarted) and events[0].n_total == len(plan.points)
    assert isinstance(events[-1], RunFinished) and events[-1].status == "finished"
    done = [e for e in events if isinstance(e, PointCompleted)]
    assert [e.index for e in done] == list(range(len(plan.points)))
    prog = [e for e in events if isinstance(e, Progress)]
    assert prog[-1].n_done == prog[-1].n_total and prog[-1].eta_s == 0
    # Live values: the ideal camera gives (1 DN/us × exposure + 10 DN offset) / exposure.
    assert done[0].signal == pytest.approx((1000 + 10) / 1000)
    assert done[0].power_w == pytest.approx(1e-3)
    assert sorted(_indices(engine.store.path)) == list(range(len(plan.points)))
    with h5py.File(engine.store.path) as f:
        pos = f["entry/points/positions"][:]
        planned = f["entry/plan/planned_targets"][:]
        idx = f["entry/points/index"][:]
        assert np.allclose(pos, planned[idx])
        assert np.allclose(f["entry/points/theta_i"][:], planned[idx, 0])
        assert f["entry/data/frames"].shape[0] == len(plan.points)
    assert bench.source.is_on is False  # the light is off after the run


def test_pause_resume_at_point_boundary(tmp_path):
    engine, q, plan, bench = _run(tmp_path)
    paused = threading.Event()

    def on(ev):
        if isinstance(ev, PointCompleted) and ev.index == 3:
            engine.pause("test pause")
        if isinstance(ev, Paused):
            assert bench.source._on is False  # safe while paused
            paused.set()

    engine.subscribe(on)
    engine.start()
    assert paused.wait(60)
    assert engine.state is EngineState.PAUSED and engine.n_done == 4
    snap = engine.snapshot()
    assert (snap.state, snap.n_done, snap.n_total) == (EngineState.PAUSED, 4, len(plan.points))
    assert snap.pause_reason == "test pause" and snap.path == str(engine.store.path)
    engine.resume()
    assert engine.wait(60) is EngineState.FINISHED
    kinds = [type(e).__name__ for e in q.drain()]
    assert kinds.index("Paused") < kinds.index("Resumed") < kinds.index("RunFinished")
    assert sorted(_indices(engine.store.path)) == list(range(len(plan.points)))


def test_abort_finalises_and_resume_completes(tmp_path):
    engine, _q, plan, bench = _run(tmp_path)
    engine.subscribe(lambda ev: engine.abort()
                     if isinstance(ev, PointCompleted) and ev.index == 5 else None)
    assert engine.run() is EngineState.ABORTED
    path = engine.store.path
    with h5py.File(path) as f:  # finalised: plain h5py opens it
        assert f["entry"].attrs["status"] == "aborted"
        n = f["entry/points/index"].shape[0]
    assert 6 <= n < len(plan.points)
    assert bench.source._on is False
    engine2 = resume_run(path, ideal_bench(), fsync=False)
    assert engine2.n_done == n
    assert engine2.run() is EngineState.FINISHED
    idx = _indices(path)
    assert sorted(idx) == list(range(len(plan.points))) and len(idx) == len(set(idx))


def test_auto_exposure_hdr_brackets_and_dark(tmp_path):
    # Bright scene: 50 DN/us saturates 12 bits at the 1000 us start exposure.
    bench = ideal_bench(brightness=lambda: 50.0)
    text = inplane_plan(mode="auto", dark="per_point").replace(
        'dark = "per_point"', 'dark = "per_point"\nhdr = true\nhdr_factor = 4.0')
    engine, _q, _plan, bench = _run(tmp_path, text, bench=bench)
    assert engine.run() is EngineState.FINISHED
    with h5py.File(engine.store.path) as f:
        light = f["entry/data/frame_light"][:]
        exp = f["entry/data/frame_exposure_us"][:]
        point = f["entry/data/frame_point"][:]
        sat = f["entry/data/frame_saturated"][:]
        first = point == f["entry/points/index"][0]
        # First point: 1000 us saturated (kept as an HDR bracket), then 250, 62.5 us.
        assert list(exp[first & light]) == [1000.0, 250.0, 62.5]
        assert list(sat[first & light] > 0) == [True, True, False]
        assert list(exp[first & ~light]) == [1000.0, 250.0, 62.5]  # a dark per bracket
        signal = f["entry/points/signal"][0]
        assert signal == pytest.approx(50.0, rel=1e-3)  # dark (10 DN offset) subtracted
        assert f["entry/points/exposure_us"][0] == 62.5
        assert '"hdr": true' in f["entry/plan/acquisition_policy"][()].decode()


def test_storage_error_pauses_then_continues_without_gap(tmp_path):
    engine, q, plan, bench = _run(tmp_path)
    paused = threading.Event()
    filled = []

    def on(ev):
        if isinstance(ev, PointCompleted) and ev.index == 4 and not filled:
            filled.append(1)
            engine.store.min_free_bytes = 1 << 62  # the disk fills up
        if isinstance(ev, Paused):
            paused.set()

    engine.subscribe(on)
    engine.start()
    assert paused.wait(60)
    events = q.drain()
    faults = [e for e in events if isinstance(e, Fault)]
    assert faults and faults[0].device == "storage" and "disk nearly full" in faults[0].cause
    assert "free space" in faults[0].cause
    assert bench.source._on is False
    # The file is closed and valid while paused: it opens and holds the committed points.
    report = recover(engine.store.path)
    assert report.done in (set(range(4)), set(range(5)))
    with h5py.File(engine.store.path) as f:
        assert sorted(f["entry/points/index"][:]) == sorted(report.done)
    # Space is freed; on resume the engine reopens (and recovers) the same file.
    engine.store.min_free_bytes = 1 << 20
    engine.resume()
    assert engine.wait(60) is EngineState.FINISHED
    idx = _indices(engine.store.path)
    assert sorted(idx) == list(range(len(plan.points))) and len(idx) == len(set(idx))
    assert any(isinstance(e, Resumed) for e in q.drain())


def test_plan_from_run_is_the_stored_plan(tmp_path):
    engine, _q, plan, bench = _run(tmp_path)
    engine.run()
    again = plan_from_run(engine.store.path, bench)
    assert [p.target_dict() for p in again.points] == [p.target_dict() for p in plan.points]
    assert [p.angles for p in again.points] == [p.angles for p in plan.points]


def test_subscriber_errors_do_not_stop_the_run(tmp_path, capsys):
    engine, _q, _plan, _bench = _run(tmp_path)

    def broken(ev):
        raise RuntimeError("GUI bug")

    engine.subscribe(broken)
    assert engine.run() is EngineState.FINISHED
    assert "GUI bug" in capsys.readouterr().err


def test_bench_missing_what_the_plan_needs_is_refused_before_anything(tmp_path):
    from instrument.plans import PlanError

    bench = ideal_bench()
    del bench.devices["source"]
    del bench.devices["power_meter"]
    plan = build_plan(parse_plan(inplane_plan(dark="per_point")), bench.profile)
    with pytest.raises(PlanError) as exc:
        start_run(plan, bench, runs_dir=tmp_path)
    msg = str(exc.value)
    assert "no power meter" in msg and "no\n" not in msg and "light source" in msg
    assert not list(tmp_path.iterdir())  # no run file was created
    assert all(a.moves == 0 for a in bench.axes.values())


def test_lightfield_plan_with_dark_at_start(tmp_path):
    text = """
[plan]
kind = "lightfield"
[sample]
name = "wall"
[scan]
camera_z = { start = 0.0, stop = 10.0, step = 2.5 }
detector_theta = 40.0
[acquisition]
exposure_us = 500
frames = 3
dark = "start"
detectors = ["camera"]
"""
    engine, _q, plan, _bench = _run(tmp_path, text)
    assert [p.label for p in plan.points] == ["dark"] + ["lightfield"] * 5
    assert engine.run() is EngineState.FINISHED
    with h5py.File(engine.store.path) as f:
        e = f["entry"]
        assert list(e["data/frame_light"][:]) == [False] + [True] * 5
        frames = e["data/frames"]
        assert frames.dtype == np.float32  # three frames averaged per point
        assert frames[0].mean() == pytest.approx(10.0)  # dark: the offset only
        assert frames[1].mean() == pytest.approx(510.0)
        z = e["points/positions"][:, list(plan.axes).index("camera_z")]
        assert np.allclose(z[1:], [0.0, 2.5, 5.0, 7.5, 10.0])
        assert np.all(np.isnan(e["points/theta_i"][:]))  # no scattering geometry


def test_a_slow_gui_client_never_blocks_the_worker_and_gets_every_lifecycle_event(tmp_path):
    import threading

    from instrument.run.events import Progress, RunFinished, RunStarted

    engine, _q, plan, _bench = _run(tmp_path)
    slow = EventQueue(maxsize=2)  # a client that reads nothing until the run ends
    engine.subscribe(slow)
    gone = EventQueue()
    engine.subscribe(gone)
    engine.unsubscribe(gone)  # a window closed before the run: it hears nothing
    engine.unsubscribe(gone)  # twice is harmless
    seen_on: set[str] = set()
    engine.subscribe(lambda ev: seen_on.add(threading.current_thread().name))
    assert engine.run() is EngineState.FINISHED  # would hang if the queue blocked
    events = slow.drain()
    assert isinstance(events[0], RunStarted) and isinstance(events[-1], RunFinished)
    live = [e for e in events if isinstance(e, (Progress, PointCompleted))]
    # RunStarted took one of the two places; every later live event beyond the second
    # place was dropped (there is at least one Progress per point).
    assert len(live) == 1 and slow.dropped >= len(plan.points)
    assert gone.drain() == []
    assert seen_on == {"run-engine"}  # subscribers run on the worker thread


def test_a_stalled_write_turns_the_light_off_reports_and_the_run_goes_on(tmp_path,
                                                                          monkeypatch):
    import threading

    from instrument.run import engine as engine_mod
    from instrument.run.events import Fault

    # The stall limit is far above any healthy write on a loaded machine (a 0.05 s limit
    # reported ordinary writes as stalls there); the stalled write waits until the fault is
    # seen, so the test takes the limit's time and no more.
    monkeypatch.setattr(engine_mod, "STORAGE_STALL_S", 5.0)
    engine, q, plan, bench = _run(tmp_path)
    store = engine.store
    real_append = store.append
    release = threading.Event()

    def stalling_append(rec):  # the disk stops answering while point 1 is written
        if rec.index == 1:
            assert release.wait(120)
        real_append(rec)

    monkeypatch.setattr(store, "append", stalling_append)
    light_during_stall = []

    def on(ev):
        if isinstance(ev, Fault) and ev.device == "storage":
            light_during_stall.append(bench.source._on)
            release.set()

    engine.subscribe(on)
    assert engine.run() is EngineState.FINISHED
    faults = [e for e in q.drain() if isinstance(e, Fault)]
    assert len(faults) == 1 and "taken over 5 s" in faults[0].cause
    assert faults[0].action == "light off, waiting for the write"
    assert light_during_stall == [False]
    with h5py.File(engine.store.path) as f:
        e = f["entry"]
        idx = list(e["points/index"][:])
        assert sorted(idx) == list(range(len(plan.points)))
        # The light came back for the next point: its frames are lit (dark level 10 DN).
        after = next(k for k, i in enumerate(idx) if i == faults[0].index)
        assert e["points/signal"][after] > 0.5


def test_catalog_row_follows_a_running_run(tmp_path, monkeypatch):
    from instrument.run import runner
    from instrument.run.catalog import Catalog
    from instrument.run.events import Progress

    monkeypatch.setattr(runner, "CATALOG_PROGRESS_S", 0.0)
    bench = ideal_bench()
    plan = build_plan(parse_plan(inplane_plan()), bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False)  # catalog on
    run_id = engine.store.header.run_id
    seen = []
    reader = Catalog(tmp_path)  # another connection, as `scatterlab runs` would open

    def on(ev):
        if isinstance(ev, Progress):
            row = reader.get(run_id)
            seen.append((row.status, row.n_points, ev.n_done))

    engine.subscribe(on)
    assert engine.run() is EngineState.FINISHED
    reader.close()
    assert len(seen) >= len(plan.points)
    assert all(status == "running" and n == done for status, n, done in seen)


def test_frame_subscribers_see_each_stored_points_main_frame_before_its_event(tmp_path):
    bench = ideal_bench(shape=(4, 6))
    plan = build_plan(parse_plan(inplane_plan(step=30.0, mode="auto")), bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False)
    seen: list[tuple[str, int, float]] = []

    def on_frame(index, frame):
        assert frame.data.shape == (4, 6) and frame.light
        seen.append(("frame", index, frame.exposure_us))

    def on_event(ev):
        if isinstance(ev, PointCompleted):
            seen.append(("point", ev.index, ev.exposure_us))

    engine.subscribe_frames(on_frame)
    engine.subscribe(on_event)
    assert engine.run() is EngineState.FINISHED
    frames = [s for s in seen if s[0] == "frame"]
    assert len(frames) == len(plan.points)
    for k in range(0, len(seen), 2):  # each frame just before its point, same exposure
        assert seen[k][0] == "frame" and seen[k + 1][0] == "point"
        assert seen[k][1:] == seen[k + 1][1:]


def test_a_broken_frame_subscriber_is_dropped_and_the_run_goes_on(tmp_path, capsys):
    bench = ideal_bench()
    plan = build_plan(parse_plan(inplane_plan(step=30.0)), bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False)
    calls = []

    def broken(index, frame):
        calls.append(index)
        raise RuntimeError("view closed")

    engine.subscribe_frames(broken)
    assert engine.run() is EngineState.FINISHED
    assert len(calls) == 1 and "frame subscriber" in capsys.readouterr().err
