"""Run control on the simulated bench: pause, resume, abort; faults and the operator's
choice; closing the window during a run."""

from __future__ import annotations

import time

import h5py
import numpy as np
import pytest

from gui.model.faults import PauseKind
from hw_mocks import registry
from hw_mocks.faults import FaultKind
from hw_mocks.sim.world import get_world
from instrument.run.catalog import Catalog
from instrument.run.engine import EngineState
from instrument.run.runfile import read_events, read_run
from tests.gui.conftest import connect

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "gui test"
[sample]
name = "gui-sample"
[scan]
theta_i = [20.0]
theta_r = {{ start = -60.0, stop = 70.0, step = {step} }}
skip_beam_points = true
[acquisition]
mode = "fixed"
exposure_us = 1000
detectors = ["camera", "power_meter"]
"""


def start(qtbot, w, tmp_path, step=10.0):
    path = tmp_path / "plan.toml"
    path.write_text(PLAN.format(step=step))
    editor = w.plan_editor
    assert editor.open_plan(path)
    qtbot.waitUntil(editor.start.isEnabled, timeout=60000)
    editor.start.click()
    qtbot.waitUntil(lambda: w.current_run is not None, timeout=60000)
    return w.current_run


def held_detector():
    """The detector arm's emulated clock, to hold: while it is held a run moves on only as
    far as :func:`drive` lets it, so it cannot end before the test has looked."""
    return registry.get("simsmc", "detector_theta").clock


def drive(qtbot, clock, until, what: str) -> None:
    """Let emulated time pass on the held ``clock`` until ``until()``.

    Each step is longer than any move of these plans, and a move that starts after it
    starts at the held time: a step finishes at most the move under way.
    """
    deadline = time.monotonic() + 60.0
    while not until():
        assert time.monotonic() < deadline, f"the run never got to {what}"
        clock.advance(5.0)
        qtbot.wait(5)  # the engine's thread and the GUI's events go on meanwhile


def wait_points(qtbot, run, n, timeout=60000):
    """Wait until the window has received ``n`` points of ``run`` (an event, not a time)."""
    qtbot.waitUntil(lambda: run.live.n_received >= n, timeout=timeout)


def wait_end(qtbot, w, timeout=60000):
    # the window has taken the run's end too (the session's flag is set first, on its
    # worker thread)
    qtbot.waitUntil(lambda: w.session.run is None and w.bridge.run is None
                    and w.run_control.last_finished is not None, timeout=timeout)
    return w.run_control.last_finished


def test_pause_resume_and_abort(qtbot, make_window, fast_bench_file, tmp_path):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    with (clock := held_detector()).held():
        run = start(qtbot, w, tmp_path)
        drive(qtbot, clock, lambda: run.live.n_received >= 2, "2 points")
        w.run_control.pause.click()
        drive(qtbot, clock, lambda: w.run_control.pause_state is not None, "the pause")
        assert w.run_control.pause_state.kind is PauseKind.OPERATOR
        assert run.engine.state is EngineState.PAUSED
        assert not w.run_control.recovery.isVisible()  # no fault: resume or abort
        assert get_world("sim").snapshot().source.on is False  # the bench is safe
        n_paused = run.live.n_received
        w.run_control.resume.click()
        drive(qtbot, clock, lambda: run.live.n_received >= n_paused + 1, "a point more")
        w.questions.answer("abort", True)  # Abort asks first
        w.run_control.abort.click()
        ev = wait_end(qtbot, w)
    assert ev.status == "aborted" and ev.n_done < ev.n_total
    data = read_run(run.path)
    assert data.status == "aborted" and data.n_points == ev.n_done
    with Catalog(tmp_path / "runs") as cat:
        row = cat.get(data.run_id)
    assert row.status == "aborted" and row.n_points == ev.n_done
    kinds = [e["kind"] for e in read_events(run.path)]
    assert kinds.index("paused") < kinds.index("resumed")
    assert get_world("sim").snapshot().source.on is False
    assert "aborted" in w.run_control.state.text()


@pytest.mark.parametrize("choice", ["retry", "skip", "abort"])
def test_a_device_fault_pauses_the_run_and_the_operator_chooses(
        qtbot, make_window, fast_bench_file, tmp_path, choice):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    # The clock is held until the cable is pulled: the run cannot end before, and with its
    # next exchange with the detector the fault strikes (recovery then needs time to run).
    with (clock := held_detector()).held():
        run = start(qtbot, w, tmp_path, step=20.0)
        drive(qtbot, clock, lambda: run.live.n_received >= 1, "a point")
        faults = registry.get("simsmc", "detector_theta").faults
        faults.schedule(FaultKind.DISCONNECT, nth=1)  # the cable is pulled
    rc = w.run_control
    qtbot.waitUntil(lambda: rc.pause_state is not None, timeout=60000)
    assert rc.pause_state.kind is PauseKind.DEVICE_FAULT
    assert rc.recovery.isVisible() and "detector_theta" in rc.question.text()
    rows = w.fault_panel.rows()
    assert rows and all(r[2] == "detector_theta" for r in rows)
    assert rows[-1][4] == "pause" and "disconnected" in rows[-1][3]
    failed = rc.pause_state.index
    # the fault's point is numbered as the progress counts: the point after those done
    assert rows[-1][1] == str(failed + 1)
    assert get_world("sim").snapshot().source.on is False
    faults.clear()  # plugged back in
    w.questions.answer("abort", True)
    {"retry": rc.retry, "skip": rc.skip, "abort": rc.abort_run}[choice].click()
    ev = wait_end(qtbot, w)
    data = read_run(run.path)
    if choice == "abort":
        assert ev.status == "aborted" and data.status == "aborted"
        assert failed not in set(data.index.tolist())
        return
    assert ev.status == "finished" and data.n_points == ev.n_total
    row = data.index.tolist().index(failed)
    if choice == "retry":
        assert set(data.point_status.tolist()) == {0}
    else:
        assert data.point_status[row] == 1 and (data.point_status == 1).sum() == 1
        with h5py.File(run.path) as f:
            assert b"skipped by the operator" in f["entry/points/note"][row]


def test_closing_during_a_run_asks_then_makes_everything_safe(qtbot, make_window,
                                                              fast_bench_file, tmp_path):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    with (clock := held_detector()).held():  # the run cannot end before the window closes
        run = start(qtbot, w, tmp_path, step=5.0)
        drive(qtbot, clock, lambda: run.live.n_received >= 2, "2 points")
        w.confirm_close_during_run(True)  # the operator answers "Yes" to the question
        w.close()
        qtbot.waitUntil(lambda: not w.isVisible(), timeout=60000)
    assert w.session.run is None and not run.engine.alive
    data = read_run(run.path)  # a valid, finalised file
    assert data.status == "aborted" and 2 <= data.n_points < len(run.plan.points)
    assert get_world("sim").snapshot().source.on is False
    for role in ("sample_theta",):
        assert not registry.get("simapt", role).stage.is_moving()
    assert not registry.get("simsmc", "detector_theta").stage.is_moving()


def test_a_small_scan_to_completion_file_catalog_and_live_plot(qtbot, make_window,
                                                               fast_bench_file, tmp_path):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    run = start(qtbot, w, tmp_path, step=20.0)
    ev = wait_end(qtbot, w)
    assert ev.status == "finished" and ev.n_done == len(run.plan.points)
    data = read_run(run.path)
    assert data.status == "finished" and data.n_points == ev.n_done
    assert data.frame_shape == (1024, 1024) and (data.point_status == 0).all()
    with Catalog(tmp_path / "runs") as cat:
        row = cat.get(data.run_id)
    assert (row.status, row.n_points, row.n_planned) == ("finished", ev.n_done, ev.n_done)
    assert row.sample == "gui-sample" and row.path == str(run.path)
    # the live plot shows every point done, one curve for the one θi
    qtbot.waitUntil(lambda: w.live_plot.n_plotted == ev.n_done, timeout=60000)
    assert w.live_plot.kind == "in_plane" and list(w.live_plot._curves) == [20.0]
    x, y = w.live_plot._curves[20.0].getData()
    assert len(x) == ev.n_done and np.all(np.diff(x) > 0)
    assert np.allclose(np.sort(10 ** y), np.sort(data.signal))  # log-y axis
    assert "points received" in w.live_plot.caption.text()
    assert w.run_control.progress.value() == ev.n_done
    # the bench is the operator's again
    assert w.bench_panel.panels["sample_theta"].home.isEnabled()


def test_space_pauses_and_resumes_but_not_while_typing(qtbot, make_window, fast_bench_file,
                                                       tmp_path):
    from PySide6.QtCore import Qt

    w = make_window(fast_bench_file())
    connect(qtbot, w)
    with (clock := held_detector()).held():  # the run cannot end while the test types
        run = start(qtbot, w, tmp_path, step=5.0)
        drive(qtbot, clock, lambda: run.live.n_received >= 1, "a point")
        w.activateWindow()
        qtbot.waitUntil(w.isActiveWindow, timeout=60000)
        field = w.plan_editor.field("plan.name")  # a text field: Space is typed, not a pause
        field.setFocus()
        qtbot.keyClick(field, Qt.Key_Space)
        assert run.engine.state is EngineState.RUNNING
        w.run_control.state.setFocus()
        w.run_control.pause.setFocus()
        qtbot.keyClick(w.run_control.progress, Qt.Key_Space)
        drive(qtbot, clock, lambda: run.engine.state is EngineState.PAUSED, "the pause")
        qtbot.keyClick(w.run_control.progress, Qt.Key_Space)
        qtbot.waitUntil(lambda: run.engine.state is EngineState.RUNNING, timeout=60000)
        w.questions.answer("abort", True)  # Abort asks first
        w.run_control.abort.click()
        assert wait_end(qtbot, w).status == "aborted"
