"""Device faults mid-scan, injected by the firmware emulators' fault injectors, with the
real drivers: recovery per the profile's policy, or a paused run with the fault reported
and the hardware left safe."""

from __future__ import annotations

import json
import threading

import h5py
import pytest

from hw_mocks import registry
from hw_mocks.faults import FaultKind
from hw_mocks.sim.ideal import IdealCamera, IdealPowerMeter, IdealSource
from instrument.bench.devices import Bench, open_device
from instrument.bench.profile import parse_profile
from instrument.plans import build_plan, parse_plan
from instrument.run.engine import EngineState
from instrument.run.events import EventQueue, Fault, Paused, PointCompleted
from instrument.run.runner import start_run
from tests.instrument.helpers import inplane_plan
from tests.waiting import wait_for

PROFILE = """
[bench]
name = "emulated axes"
[devices.sample_theta]
driver = "thorlabs_apt"
url = "simapt://sample_theta?model=K10CR1&speed=400"
stage = "K10CR1"
limits = [-90.0, 90.0]
velocity = 10.0
acceleration = 10.0
options = {{ timeout = 0.05, retries = 1 }}
[devices.sample_theta.retry]
attempts = 2
backoff_s = 0.0
on_failure = "{policy}"
[devices.detector_theta]
driver = "newport_smc100"
url = "simsmc://detector_theta?kind=rotary&speed=400"
limits = [-170.0, 170.0]
velocity = 20.0
acceleration = 80.0
options = {{ reply_timeout = 0.05, retries = 1 }}
[devices.detector_theta.retry]
attempts = 2
backoff_s = 0.0
on_failure = "{policy}"
[devices.camera]
driver = "sim_camera"
url = "ideal://camera"
[devices.power_meter]
driver = "pm100usb"
url = "ideal://power_meter"
[devices.source]
driver = "sim_source"
url = "ideal://source"
[geometry]
kind = "in_plane"
min_bistatic_deg = 5.0
"""


@pytest.fixture
def make_bench():
    benches = []

    def make(policy: str) -> Bench:
        profile = parse_profile(PROFILE.format(policy=policy))
        source = IdealSource("source")
        devices = {r: open_device(profile.devices[r])
                   for r in ("sample_theta", "detector_theta")}
        devices.update(camera=IdealCamera("camera", source=source),
                       power_meter=IdealPowerMeter("power_meter"), source=source)
        bench = Bench(profile, devices)
        benches.append(bench)
        return bench

    yield make
    for b in benches:
        b.close()


def _start(tmp_path, bench):
    plan = build_plan(parse_plan(inplane_plan(step=30.0)), bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False)
    q = EventQueue()
    engine.subscribe(q)
    return engine, q, plan


def _file(engine):
    with h5py.File(engine.store.path) as f:
        return (list(f["entry/points/index"][:]), list(f["entry/points/status"][:]),
                list(f["entry/points/retries"][:]),
                [json.loads(s) for s in f["entry/events/log"][:]])


def test_transient_disconnect_is_retried(tmp_path, make_bench):
    bench = make_bench("pause")
    engine, q, plan = _start(tmp_path, bench)
    faults = registry.get("simsmc", "detector_theta").faults

    def on(ev):
        if isinstance(ev, PointCompleted) and ev.index == 1:
            faults.schedule(FaultKind.DISCONNECT, nth=1)
        if isinstance(ev, Fault) and ev.action.startswith("retry"):
            faults.clear()  # the cable is plugged back in

    engine.subscribe(on)
    assert engine.run() is EngineState.FINISHED
    fault_events = [e for e in q.drain() if isinstance(e, Fault)]
    assert fault_events and fault_events[0].device == "detector_theta"
    assert "disconnected" in fault_events[0].cause
    idx, status, retries, log = _file(engine)
    assert sorted(idx) == list(range(len(plan.points))) and set(status) == {0}
    assert sum(retries) >= 1
    assert any(e["kind"] == "fault" and e["device"] == "detector_theta" for e in log)


def _disconnect_after_point(engine, faults, index: int) -> threading.Event:
    """Pull the cable once point ``index`` is done (and leave it out); the event is set
    when the engine pauses."""
    paused = threading.Event()
    armed = []

    def on(ev):
        if isinstance(ev, PointCompleted) and ev.index == index and not armed:
            armed.append(1)
            faults.schedule(FaultKind.DISCONNECT, nth=1)
        if isinstance(ev, Paused):
            paused.set()

    engine.subscribe(on)
    return paused


def test_persistent_fault_pauses_safely_and_resumes(tmp_path, make_bench):
    bench = make_bench("pause")
    engine, q, plan = _start(tmp_path, bench)
    faults = registry.get("simapt", "sample_theta").faults
    paused = _disconnect_after_point(engine, faults, 2)
    engine.start()
    assert paused.wait(60)
    events = q.drain()
    fault = [e for e in events if isinstance(e, Fault)][-1]
    assert fault.device == "sample_theta" and fault.action == "pause"
    assert "failed 2 time(s)" in fault.cause
    # Hardware safe: light off, the other axis not moving.
    assert bench.source._on is False
    assert not bench.devices["detector_theta"].status().is_moving
    faults.clear()  # the operator fixes the link
    engine.resume()
    assert engine.wait(30) is EngineState.FINISHED
    idx, _status, _, log = _file(engine)
    assert sorted(idx) == list(range(len(plan.points))) and len(idx) == len(set(idx))
    kinds = [e["kind"] for e in log]
    assert "fault" in kinds and kinds.index("paused") < kinds.index("resumed")


def _unplug_after_point(index: int, faults, *, reconnect_on: str):
    """Subscriber: pull the cable once point ``index`` is done; plug it back in when the
    engine reports the recovery action ``reconnect_on``."""
    armed = []

    def on(ev):
        if isinstance(ev, PointCompleted) and ev.index == index and not armed:
            armed.append(1)
            faults.schedule(FaultKind.DISCONNECT, nth=1)
        if isinstance(ev, Fault) and ev.action == reconnect_on:
            faults.clear()

    return on


def test_skip_policy_marks_the_point(tmp_path, make_bench):
    bench = make_bench("skip")
    engine, _q, plan = _start(tmp_path, bench)
    faults = registry.get("simsmc", "detector_theta").faults
    engine.subscribe(_unplug_after_point(3, faults, reconnect_on="skip point"))
    assert engine.run() is EngineState.FINISHED
    idx, status, _, _ = _file(engine)
    assert sorted(idx) == list(range(len(plan.points)))
    assert status.count(1) == 1 and status[idx.index(4)] == 1  # point 4 skipped, marked


def test_rehome_policy(tmp_path, make_bench):
    bench = make_bench("rehome")
    engine, q, plan = _start(tmp_path, bench)
    faults = registry.get("simapt", "sample_theta").faults
    engine.subscribe(_unplug_after_point(2, faults, reconnect_on="rehome"))
    assert engine.run() is EngineState.FINISHED
    actions = [e.action for e in q.drain() if isinstance(e, Fault)]
    assert "rehome" in actions
    idx, status, _, _ = _file(engine)
    assert sorted(idx) == list(range(len(plan.points))) and set(status) == {0}


def test_abort_stops_a_move_in_progress(tmp_path, make_bench):
    """Abort during a long move: the axis stops where it is (not at the target), the
    light is off and the file is finalised as aborted."""
    bench = make_bench("pause")
    plan = build_plan(parse_plan(inplane_plan(step=30.0)), bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False)
    det = bench.devices["detector_theta"]
    # Slow the detector arm so that the first long move lasts seconds.
    det.enable()
    det.home()
    det.velocity = 0.05  # a 30° step takes 600 s of emulated time
    moving = threading.Event()

    def on(ev):
        if isinstance(ev, PointCompleted):
            moving.set()

    engine.subscribe(on)
    emulator = registry.get("simsmc", "detector_theta")
    engine.start()
    assert moving.wait(60)  # first point done; the next move is long
    # Emulated time stands still from the start of that move until the stop reached the
    # controller, but for 100 s let pass by hand (5° of the 30°): the abort surely lands
    # mid-move however slowly the machine runs.
    with emulator.clock.held():
        wait_for(lambda: emulator.stage.is_moving(), what="the next move to start")
        emulator.clock.advance(100.0)
        sent = len(emulator.received_log)
        engine.abort()
        wait_for(lambda: b"ST" in bytes(emulator.received_log[sent:]), what="the stop")
    assert engine.wait(60) is EngineState.ABORTED
    s = det.status()
    assert not s.is_moving
    assert bench.source._on is False
    with h5py.File(engine.store.path) as f:
        assert f["entry"].attrs["status"] == "aborted"
        n = f["entry/points/index"].shape[0]
    assert n < len(plan.points)
    targets = {p.target_dict()["detector_theta"] for p in plan.points}
    assert all(abs(s.position - t) > 0.01 for t in targets)  # stopped between targets


def test_after_a_fault_pause_the_operator_skips_the_point(tmp_path, make_bench):
    """resume(skip_point=True): the failed point is stored as skipped, named as the
    operator's choice, and the run goes on with the next point."""
    bench = make_bench("pause")
    engine, q, plan = _start(tmp_path, bench)
    faults = registry.get("simsmc", "detector_theta").faults
    paused = _disconnect_after_point(engine, faults, 2)
    engine.start()
    assert paused.wait(60)
    pause = [e for e in q.drain() if isinstance(e, Paused)][-1]
    faults.clear()
    engine.resume(skip_point=True)
    assert engine.wait(30) is EngineState.FINISHED
    idx, status, _, log = _file(engine)
    assert sorted(idx) == list(range(len(plan.points)))
    assert status[idx.index(pause.index)] == 1 and status.count(1) == 1
    skipped = [e for e in log if e["kind"] == "skipped"]
    assert len(skipped) == 1 and skipped[0]["index"] == pause.index
    assert "skipped by the operator" in skipped[0]["reason"]
    with h5py.File(engine.store.path) as f:
        note = f["entry/points/note"][idx.index(pause.index)]
    assert b"skipped by the operator" in note


def test_skip_point_after_an_operator_pause_skips_nothing(tmp_path, make_bench):
    bench = make_bench("pause")
    engine, _q, _plan = _start(tmp_path, bench)
    paused = threading.Event()

    def on(ev):
        if isinstance(ev, PointCompleted) and ev.index == 1:
            engine.pause()
        if isinstance(ev, Paused):
            paused.set()

    engine.subscribe(on)
    engine.start()
    assert paused.wait(60)
    engine.resume(skip_point=True)
    assert engine.wait(30) is EngineState.FINISHED
    _, status, _, _ = _file(engine)
    assert set(status) == {0}


def test_the_reader_gives_the_event_log_and_provenance(tmp_path, make_bench):
    from instrument.run.runfile import read_attributes, read_events

    bench = make_bench("pause")
    engine, _q, _plan = _start(tmp_path, bench)
    faults = registry.get("simsmc", "detector_theta").faults
    engine.subscribe(_unplug_after_point(1, faults, reconnect_on="retry 1/1"))
    assert engine.run() is EngineState.FINISHED
    events = read_events(engine.store.path)
    assert events == _file(engine)[3]
    fault = next(e for e in events if e["kind"] == "fault")
    assert fault["device"] == "detector_theta" and "disconnected" in fault["cause"]
    attrs = read_attributes(engine.store.path)
    assert attrs["status"] == "finished" and attrs["run_id"] == engine.store.header.run_id
    assert attrs["software_version"] and attrs["durability"] == "process"
