"""The bench session without Qt: the device worker owns the simulated bench; manual moves
go through the guard; runs take the bench and give it back."""

from __future__ import annotations

import threading

import h5py
import pytest

from gui.model.session import (
    BenchSession,
    Connect,
    Disconnect,
    Home,
    Jog,
    MoveTo,
    SetLight,
    SetSetting,
    StartRun,
    StopAll,
)
from hw_mocks import registry
from instrument.bench.devices import Bench
from instrument.plans import build_plan, parse_plan
from instrument.run.catalog import Catalog
from tests.gui.helpers import Recorder, fast_profile
from tests.instrument.helpers import ideal_bench, inplane_plan
from tests.waiting import wait_for


@pytest.fixture
def session():
    rec = Recorder()
    s = BenchSession(rec, fsync=False)
    yield s, rec
    assert s.close(20)


def _connect(s, rec, profile):
    s.submit(Connect(profile))
    wait_for(lambda: s.connected and rec.state_updates > 0, 60, "connection")


def _emulator_position(scheme, role):
    return registry.get(scheme, role).stage.physical_position()


def test_connect_home_jog_reads_the_emulators_positions(session):
    s, rec = session
    _connect(s, rec, fast_profile())
    states = s.states()
    assert {"sample_theta", "detector_theta", "camera_z", "camera", "power_meter",
            "source"} <= set(states)
    assert states["sample_theta"].info["identity"]["model"].startswith("K10CR1")
    assert states["detector_theta"].info["velocity"] == pytest.approx(20.0)
    s.submit(Home("detector_theta"))
    wait_for(lambda: s.states()["detector_theta"].value("homed")
             and not s.states()["detector_theta"].value("moving"), 60, "homed")
    s.submit(Jog("detector_theta", 30.0))
    wait_for(lambda: abs(s.states()["detector_theta"].value("position") - 30.0) < 0.01
             and not s.states()["detector_theta"].value("moving"), 60, "jog done")
    ok = rec.results_of(Jog)[-1]
    assert ok.ok and "detector_theta=30" in ok.message
    assert _emulator_position("simsmc", "detector_theta") == pytest.approx(30.0, abs=0.01)


def test_a_refused_move_says_why_and_nothing_moves(session):
    s, rec = session
    _connect(s, rec, fast_profile())
    for role in ("sample_theta", "detector_theta"):
        s.submit(Home(role))
    wait_for(lambda: all(s.states()[r].value("homed") and not s.states()[r].value("moving")
                         for r in ("sample_theta", "detector_theta")), 60, "homed")
    s.submit(MoveTo("detector_theta", 40.0))
    wait_for(lambda: not s.states()["detector_theta"].value("moving")
             and abs(s.states()["detector_theta"].value("position") - 40) < 0.01, 60)
    s.submit(SetLight(True))
    s.submit(MoveTo("sample_theta", 120.0))    # outside [-85, 85]
    s.submit(MoveTo("detector_theta", 3.0))    # into the lit beam (< 6° bistatic)
    assert s.wait_idle(60)
    refused = [r for r in rec.results_of(MoveTo) if r.refused]
    assert len(refused) == 2
    assert "outside the soft limits" in refused[0].message
    assert "incident beam" in refused[1].message
    assert _emulator_position("simapt", "sample_theta") == pytest.approx(0.0, abs=0.01)
    assert _emulator_position("simsmc", "detector_theta") == pytest.approx(40.0, abs=0.01)


def test_light_on_is_refused_with_the_arm_in_the_beam(session):
    s, rec = session
    _connect(s, rec, fast_profile())
    s.submit(Home("detector_theta"))
    s.submit(Home("sample_theta"))
    wait_for(lambda: s.states()["detector_theta"].value("homed"), 60)
    assert s.wait_idle(60)
    s.submit(SetLight(True))
    assert s.wait_idle(60)
    r = rec.results_of(SetLight)[-1]
    assert r.refused and "beam" in r.message
    assert s.states()["source"].value("on") is False


def test_stop_all_stops_a_move_short_of_its_target(session):
    s, rec = session
    _connect(s, rec, fast_profile(speed=20))
    s.submit(Home("detector_theta"))
    wait_for(lambda: s.states()["detector_theta"].value("homed")
             and not s.states()["detector_theta"].value("moving"), 60)
    s.submit(SetSetting("detector_theta", "velocity", 1.0))  # 150° take 150 emulated s
    assert s.wait_idle(60)
    emulator = registry.get("simsmc", "detector_theta")
    # Emulated time stands still from the move to the stop reaching the controller, but for
    # 20 s let pass by hand: the stop lands under way however slowly the machine runs.
    with emulator.clock.held():
        s.submit(MoveTo("detector_theta", 150.0))
        wait_for(lambda: s.states()["detector_theta"].value("moving"), what="moving")
        emulator.clock.advance(20.0)
        sent = len(emulator.received_log)
        s.stop_all()
        wait_for(lambda: b"ST" in bytes(emulator.received_log[sent:]), what="the stop")
    wait_for(lambda: not s.states()["detector_theta"].value("moving"), what="stopped")
    assert rec.results_of(StopAll)[-1].ok
    pos = _emulator_position("simsmc", "detector_theta")
    assert 0 < pos < 149
    assert s.states()["detector_theta"].value("position") == pytest.approx(pos, abs=0.01)


def test_a_settings_new_value_is_reported_before_its_result():
    """The GUI shows a set-point field's device value again when the Set's result arrives:
    the state carrying the new setting must reach the listener first, whatever the poll
    timing (states and results are delivered in the order they are reported)."""

    class OrderRecorder(Recorder):
        def __init__(self) -> None:
            super().__init__()
            self.velocity_at_result: list = []

        def result(self, result) -> None:
            if isinstance(result.command, SetSetting):
                state = self.last_states.get("detector_theta")
                self.velocity_at_result.append(None if state is None
                                               else state.info.get("velocity"))
            super().result(result)

    rec = OrderRecorder()
    s = BenchSession(rec, fsync=False)
    try:
        _connect(s, rec, fast_profile())
        for velocity in (7.0, 3.5):
            s.submit(SetSetting("detector_theta", "velocity", velocity))
        assert s.wait_idle(60)
        assert rec.velocity_at_result == [7.0, 3.5]
    finally:
        assert s.close(20)


def test_a_rejected_setting_reports_the_drivers_error(session):
    s, rec = session
    _connect(s, rec, fast_profile())
    s.submit(SetSetting("camera", "exposure_us", 1.0))  # the camera's minimum is 10 µs
    s.submit(SetSetting("camera", "exposure_us", 5000.0))
    assert s.wait_idle(60)
    bad, good = rec.results_of(SetSetting)[-2:]
    assert not bad.ok and "exposure 1 µs outside [10 µs, 10 s]" in bad.message
    assert good.ok
    wait_for(lambda: s.states()["camera"].value("exposure_us") == 5000.0, 60)


def test_a_run_takes_the_bench_refuses_manual_moves_and_gives_it_back(tmp_path):
    rec = Recorder()
    bench: list[Bench] = []
    gate = threading.Event()  # the camera's first exposure waits for it

    def opener(profile):
        bench.append(ideal_bench())
        camera = bench[-1].devices["camera"]
        expose = camera._do_acquire_one

        def gated(timeout: float):
            # Holds the run at its first point, so that it still owns the bench when the
            # manual move arrives, however fast the run or slow the test.
            assert gate.wait(60), "the test never opened the gate"
            return expose(timeout)

        camera._do_acquire_one = gated
        return bench[-1]

    s = BenchSession(rec, opener=opener, fsync=False)
    try:
        _connect(s, rec, bench_profile := ideal_bench().profile)
        plan = build_plan(parse_plan(inplane_plan(step=15.0)), bench_profile)
        s.submit(StartRun(plan, tmp_path))
        wait_for(lambda: s.run is not None, 60, "run")
        run = s.run
        s.submit(MoveTo("sample_theta", 10.0))
        assert s.wait_idle(60)
        gate.set()
        refused = rec.results_of(MoveTo)[-1]
        assert refused.refused and "a run owns the bench" in refused.message
        wait_for(lambda: s.run is None, 60, "run end")
        assert run.finished.status == "finished"
        assert run.live.n_received == len(plan.points)
        with h5py.File(run.path) as f:
            assert f["entry"].attrs["status"] == "finished"
            assert f["entry/points/index"].shape[0] == len(plan.points)
        with Catalog(tmp_path) as cat:
            row = cat.get(run.engine.store.header.run_id)
        assert row.status == "finished" and row.n_points == len(plan.points)
        s.submit(MoveTo("sample_theta", 10.0))   # the bench is back
        assert s.wait_idle(60)
        assert rec.results_of(MoveTo)[-1].ok
        s.submit(Disconnect())
        assert s.wait_idle(60) and not s.connected
    finally:
        assert s.close(20)
