"""The GUI as a client of a real bench server process on a random loopback port.

The operator's actions go through the window's buttons and methods to the server; what is
checked is what the window shows and what the server did (its queue history, its run
files). Every wait is on a condition with a generous limit (ADR 0020); no timing asserts.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import pytest

from gui.model import filters, readouts
from gui.model import format as fmt
from instrument.bench.device_state import state_from_message
from instrument.bench.profile import load_profile
from instrument.client import BenchClient
from instrument.server.db import ServerDB
from instrument.server.keys import KeyStore
from tests.instrument.server.helpers import (
    ROOT,
    ServerProcess,
    fast_profile_text,
    plan_text,
)

WAIT_MS = 120_000
THETA_R = [-60.0, -40.0, 10.0, 40.0, 60.0]  # theta_i = 20: -20 is the beam


@pytest.fixture
def server(tmp_path):
    started: list[ServerProcess] = []

    def start(*, fault: str | None = None, pause_on_fault: bool = False,
              profile: str | None = None) -> ServerProcess:
        """``profile``: a built-in bench as it is (else the fast sim bench)."""
        bench = tmp_path / f"{profile or 'sim-fast'}.toml"
        bench.write_text(load_profile(profile).source_text if profile else
                         fast_profile_text(pause_on_detector_fault=pause_on_fault),
                         encoding="utf-8")
        env = {"SCATTERLAB_TEST_FAULT": fault} if fault else None
        s = ServerProcess(bench, tmp_path / "runs", env=env)
        started.append(s)
        return s

    yield start
    for s in started:
        s.kill()


@pytest.fixture
def open_window(qtbot):
    from gui.qt.client_window import ClientWindow

    windows: list[ClientWindow] = []

    def make(url: str, key: str | None = None) -> ClientWindow:
        w = ClientWindow(url, key)
        qtbot.addWidget(w)
        w.show()
        windows.append(w)
        qtbot.waitUntil(lambda: w.state.stream_up, timeout=WAIT_MS)
        # the widgets follow the state on the window's redraw timer: wait until they show
        # who this key is (the controls are enabled or greyed for it by then)
        qtbot.waitUntil(lambda: bool(w.state.you.get("role")) and
                        f"({w.state.you['role']})" in w.banner.text(), timeout=WAIT_MS)
        return w

    yield make
    for w in windows:
        w.close()


def _result(window, what: str):
    return next((r for r in window.results if r[0] == what), None)


@pytest.mark.timeout(900)
def test_three_plans_queued_from_the_gui_survive_its_closing_and_reopening_shows_the_plot(
        server, open_window, qtbot):
    srv = server()
    w = open_window(srv.url)
    assert w.add_button.isEnabled() and w.stop_all_button.isEnabled()
    qtbot.waitUntil(lambda: w.browser is not None, timeout=WAIT_MS)  # runs folder is local
    long_scan = [float(t) for t in (*range(-85, -44), *range(10, 86))]  # 117 points
    w.add_plan_text(plan_text("first", long_scan))
    w.add_plan_text(plan_text("second", THETA_R))
    w.add_plan_text(plan_text("third", THETA_R, theta_i=30.0))
    qtbot.waitUntil(lambda: len(w.state.queue_items) == 3, timeout=WAIT_MS)
    assert [i["name"] for i in w.state.queue_items] == ["first", "second", "third"]
    w.start_queue_button.click()
    qtbot.waitUntil(lambda: w.state.run is not None and w.state.run.live is not None
                    and w.state.run.live.n_received >= 3, timeout=WAIT_MS)
    w.pause_button.click()  # at the end of the point: the run stays live for the reopening
    qtbot.waitUntil(lambda: w.state.run.state == "paused", timeout=WAIT_MS)
    n_before = w.state.run.n_done
    w.close()

    with BenchClient(srv.url) as c:  # the server still has the run
        st = c.status()
        assert st["run"] is not None and st["run"]["state"] == "paused"

    again = open_window(srv.url)
    qtbot.waitUntil(lambda: again.state.run is not None and again.state.run.live is not None
                    and again.state.run.live.n_received >= n_before, timeout=WAIT_MS)
    snap = again.state.run.live.snapshot()
    assert 0 in snap.index.tolist()  # the plot holds the run from its first point
    assert sorted(snap.index.tolist()) == list(range(snap.n_received))
    qtbot.waitUntil(lambda: again.plot.n_plotted > 0, timeout=WAIT_MS)
    assert again.fault_box.isVisible() and again.resume_button.isEnabled()
    again.resume_button.click()
    qtbot.waitUntil(lambda: not again.state.queue_items and not again.state.queue_running,
                    timeout=WAIT_MS * 3)
    with BenchClient(srv.url) as c:
        history = c.history()
    done = [h for h in history if h["outcome"] == "finished"]
    assert [h["name"] for h in sorted(done, key=lambda h: h["item_id"])] == \
        ["first", "second", "third"]


def _keys(runs) -> dict[str, str]:
    runs.mkdir(parents=True, exist_ok=True)
    with ServerDB(runs) as db:
        store = KeyStore(db)
        return {role: store.add(f"{role}-user", role)[1] for role in ("observer", "operator")}


@pytest.mark.timeout(600)
def test_an_observer_key_sees_the_controls_greyed_with_the_reason(server, open_window,
                                                                   qtbot, tmp_path):
    tokens = _keys(tmp_path / "runs")
    srv = server()
    obs = open_window(srv.url, tokens["observer"])
    assert obs.state.you == {"name": "observer-user", "role": "observer"}
    for b in (obs.add_button, obs.start_queue_button, obs.pause_button, obs.abort_button,
              obs.light_button, obs.take_button, obs.stop_all_button):
        assert not b.isEnabled()
    qtbot.waitUntil(lambda: "observer" in obs.add_button.toolTip(), timeout=WAIT_MS)
    assert "View only" in obs.banner.text()
    qtbot.waitUntil(lambda: bool(obs.axis_rows), timeout=WAIT_MS)  # device states arrive

    op = open_window(srv.url, tokens["operator"])
    assert op.add_button.isEnabled()
    op.take_button.click()
    qtbot.waitUntil(lambda: obs.state.lease_holder() == "operator-user", timeout=WAIT_MS)
    # the labels and buttons follow the state on the window's redraw timer
    qtbot.waitUntil(lambda: "operator-user" in obs.control_label.text(), timeout=WAIT_MS)
    qtbot.waitUntil(lambda: op.release_button.isEnabled() and not op.take_button.isEnabled(),
                    timeout=WAIT_MS)


# slow: 4.0 s CPU (a server process and a run); the cheaper
# test_a_fault_on_the_emulated_bench_reaches_every_client_and_an_operator_answers ([retry],
# test_server_e2e.py) checks the same retry answered through the server, and
# test_run_control.py::test_a_device_fault_pauses_the_run_and_the_operator_chooses[retry] the
# GUI's fault box and retry button, in the default run
@pytest.mark.slow
@pytest.mark.timeout(900)
def test_a_fault_is_shown_and_answered_retry_from_the_gui(server, open_window, qtbot):
    srv = server(fault="simsmc:detector_theta:1", pause_on_fault=True)
    w = open_window(srv.url)
    w.add_plan_text(plan_text("faulty", THETA_R), "faulty")
    w.start_queue_button.click()
    qtbot.waitUntil(lambda: w.fault_box.isVisible() and w.retry_button.isVisible(),
                    timeout=WAIT_MS)
    assert w.state.run.answers == ["retry", "skip", "abort"]
    assert "FAULT detector_theta" in w.log_view.toPlainText()
    w.retry_button.click()
    qtbot.waitUntil(lambda: w.state.run.state == "finished", timeout=WAIT_MS)
    assert w.state.run.n_done == w.state.run.n_total == len(THETA_R)
    assert _result(w, "retry")[1]
    assert not w.fault_box.isVisible()


def test_closing_the_gui_leaves_a_local_server_with_a_run_going_and_stops_an_idle_one(
        tmp_path):
    import subprocess
    import sys
    from types import SimpleNamespace

    from gui.app import _after_close
    from gui.model.remote import RemoteRun, RemoteState
    from instrument.client.local import LocalServer

    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
    try:
        local = LocalServer("http://127.0.0.1:1", child.pid, "sim", tmp_path, True)
        state = RemoteState(local.url)
        state.stream_up = True
        state.run = RemoteRun(state="running")
        said = _after_close(SimpleNamespace(state=state), local)
        assert "keeps running" in said and "--stop-server" in said and local.alive()
        state.run.state = "finished"
        said = _after_close(SimpleNamespace(state=state), local)
        assert said.startswith("stopped the local server") and not local.alive()
    finally:
        child.kill()
        child.wait(60)


def _arm_deg(view) -> float | None:
    """The detector arm's azimuth in the drawing (None: no arm drawn)."""
    import math

    arms = view.scene.by_role("arm") if view.scene is not None else []
    if not arms:
        return None
    x, y = arms[0].xy[1]
    return math.degrees(math.atan2(y, x))


@pytest.mark.timeout(600)
def test_the_goniometer_drawing_follows_the_servers_read_back_positions(
        server, open_window, qtbot):
    srv = server()
    w = open_window(srv.url)
    view = w.goniometer
    qtbot.waitUntil(lambda: view.profile is not None, timeout=WAIT_MS)  # the server's bench
    w.tabs.setCurrentWidget(view)  # the drawing redraws only while it is shown
    qtbot.waitUntil(lambda: view.scene is not None and "detector_theta" in w.axis_rows,
                    timeout=WAIT_MS)
    assert _arm_deg(view) is None  # not homed: the arm's position is unknown
    w.home("detector_theta")
    qtbot.waitUntil(lambda: _result(w, "home detector_theta") is not None, timeout=WAIT_MS)
    assert _result(w, "home detector_theta")[1]
    w.move_to("detector_theta", 40.0)
    qtbot.waitUntil(lambda: _result(w, "move detector_theta") is not None, timeout=WAIT_MS)
    assert _result(w, "move detector_theta")[1]
    # the drawing settles where the server's read-back says the stage is (steps of 1e-3°)
    qtbot.waitUntil(lambda: not w.state.axes["detector_theta"].get("moving")
                    and _arm_deg(view) is not None
                    and abs(_arm_deg(view) - 40.0) < 0.01, timeout=WAIT_MS)
    assert abs(w.state.homed_positions()["detector_theta"] - 40.0) < 0.01
    assert "detector_theta 40.0" in view.caption.text()


@pytest.mark.timeout(600)
def test_an_operator_approves_and_denies_an_observers_proposals_from_the_gui(
        server, open_window, qtbot, tmp_path):
    tokens = _keys(tmp_path / "runs")
    srv = server()
    with BenchClient(srv.url, tokens["observer"]) as c:
        keep = c.propose(plan_text("keep-me", THETA_R), "keep-me")["id"]
        drop = c.propose(plan_text("drop-me", THETA_R), "drop-me")["id"]
    obs = open_window(srv.url, tokens["observer"])
    assert not obs.approve_button.isEnabled() and not obs.deny_button.isEnabled()
    op = open_window(srv.url, tokens["operator"])
    # the list is redrawn by the window's timer, after the state changed
    qtbot.waitUntil(lambda: "2 proposed" in op.queue_label.text(), timeout=WAIT_MS)
    assert "proposed by observer-user" in op.queue_list.item(0).text()
    assert op.approve_button.isEnabled() and op.deny_button.isEnabled()

    assert op.select_item(drop)
    op.deny_button.click()
    qtbot.waitUntil(lambda: _result(op, f"deny item {drop}") is not None, timeout=WAIT_MS)
    assert op.select_item(keep)
    op.approve_button.click()
    qtbot.waitUntil(lambda: _result(op, f"approve item {keep}") is not None, timeout=WAIT_MS)
    assert _result(op, f"deny item {drop}")[1] and _result(op, f"approve item {keep}")[1]
    # every window shows the server's queue: the kept one queued, the other gone
    for w in (op, obs):
        qtbot.waitUntil(lambda w=w: [(i["id"], i["state"]) for i in w.state.queue_items]
                        == [(keep, "queued")], timeout=WAIT_MS)
    qtbot.waitUntil(lambda: "proposed" not in op.queue_label.text(), timeout=WAIT_MS)

    # approving what is not a proposal is refused by the server, with its reason
    op.approve_button.click()
    qtbot.waitUntil(lambda: len([r for r in op.results if r[0] == f"approve item {keep}"])
                    == 2, timeout=WAIT_MS)
    refused = [r for r in op.results if r[0] == f"approve item {keep}"][1]
    assert not refused[1] and "not a proposal" in refused[2]
    with BenchClient(srv.url, tokens["operator"]) as c:
        history = c.history()
    assert [(h["item_id"], h["outcome"]) for h in history] == [(drop, "denied")]


@pytest.mark.timeout(900)
def test_the_camera_settings_are_set_through_the_server_between_runs_only(
        server, open_window, qtbot):
    srv = server()
    w = open_window(srv.url)
    qtbot.waitUntil(lambda: w.state.camera is not None and w.set_gain_button.isEnabled(),
                    timeout=WAIT_MS)
    w.exposure_box.setValue(2500.0)  # an edit: pending until the server answers
    w.set_exposure_button.click()
    qtbot.waitUntil(lambda: _result(w, "camera exposure_us") is not None, timeout=WAIT_MS)
    assert _result(w, "camera exposure_us")[1]
    qtbot.waitUntil(lambda: w.state.camera["exposure_us"] == 2500.0, timeout=WAIT_MS)
    qtbot.waitUntil(lambda: w.exposure_box.value() == 2500.0, timeout=WAIT_MS)

    # a gain outside the camera's range: refused with the range; the field shows the
    # camera's gain again
    gain = w.state.camera["gain"]
    w.gain_box.setValue(99.0)
    w.set_gain_button.click()
    qtbot.waitUntil(lambda: _result(w, "camera gain") is not None, timeout=WAIT_MS)
    _, ok, message, _ = _result(w, "camera gain")
    assert not ok and "outside [0, 24]" in message
    assert w.gain_box.value() == gain and not w.camera_fields["gain"].pending

    # while a run owns the bench the fields are greyed, and the server refuses anyway
    long_scan = [float(t) for t in (*range(-85, -44), *range(10, 86))]
    w.add_plan_text(plan_text("long", long_scan))
    qtbot.waitUntil(lambda: len(w.state.queue_items) == 1, timeout=WAIT_MS)
    w.start_queue_button.click()
    qtbot.waitUntil(lambda: w.state.owner == "run" and not w.set_gain_button.isEnabled(),
                    timeout=WAIT_MS)
    assert "between runs" in w.set_gain_button.toolTip()
    w.pause_button.click()  # a paused run keeps the bench: the refusal does not race it
    # the sampler may say "owner: run" before the run_started message arrives
    qtbot.waitUntil(lambda: w.state.run is not None and w.state.run.state == "paused",
                    timeout=WAIT_MS)
    w.set_camera("gain", 3.0)
    qtbot.waitUntil(lambda: len([r for r in w.results if r[0] == "camera gain"]) == 2,
                    timeout=WAIT_MS)
    refused = [r for r in w.results if r[0] == "camera gain"][1]
    assert not refused[1] and "a run owns the bench" in refused[2]
    w.abort_button.click()
    qtbot.waitUntil(lambda: w.state.run is not None and not w.state.run.alive,
                    timeout=WAIT_MS)
    with BenchClient(srv.url) as c:
        rows = [(r["what"], r["status"]) for r in c.request("GET", "/audit")
                if r["what"].endswith("/bench/camera")]
    assert [s for _, s in rows] == [200, 422, 409]  # every one audited


def test_a_server_bench_profile_unreadable_here_leaves_the_drawing_empty_saying_why(
        qtbot, tmp_path):
    from gui.qt.client_window import ClientWindow

    w = ClientWindow("http://127.0.0.1:1")  # no server: the state is set by hand
    qtbot.addWidget(w)
    try:
        w.state.bench = str(tmp_path / "elsewhere" / "bench.toml")  # not on this PC
        w.state.axes = {"detector_theta": {"position": 40.0, "homed": True}}
        w._refresh_goniometer_profile()
        w._refresh_devices()
        assert w.goniometer.profile is None and w.goniometer.scene is None
        assert "not a built-in profile nor a file readable" in w.goniometer.caption.text()
        assert not w.goniometer._dirty  # no redraw pending that would say only "no bench"
        assert "detector_theta" in w.axis_rows  # the other tabs work
    finally:
        w.close()


# the device panels ---------------------------------------------------------------------
class _Observer:
    """An independent client of the event stream that keeps every ``states`` entry the
    server published, by role: what the server said, to compare the window with."""

    def __init__(self, url: str) -> None:
        self.seen: dict[str, list[dict]] = {}
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._client = BenchClient(url)
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()
        assert self._ready.wait(60)

    def _read(self) -> None:
        with self._client.open_events(open_timeout_s=60) as stream:
            self._ready.set()
            while not self._stop.is_set():
                msg = stream.recv(timeout_s=0.2)
                if msg is not None and msg.type == "devices":
                    for role, raw in (msg.data.get("states") or {}).items():
                        self.seen.setdefault(role, []).append(raw)

    def published(self, role: str, state) -> bool:
        """Whether the server published ``state`` (the window's) for ``role``."""
        return any(state_from_message(role, raw).values == state.values
                   and state_from_message(role, raw).info == state.info
                   for raw in list(self.seen.get(role, ())))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(60)
        self._client.close()


def _shown(window, qtbot, roles: tuple[str, ...], observer: _Observer) -> None:
    """Wait until the window has a panel for each role showing a state the server
    published (the observer saw it too)."""
    qtbot.waitUntil(lambda: all(
        r in window.panels and window.panels[r].state is not None
        and window.panels[r].state is window.state.device_states.get(r)
        and observer.published(r, window.panels[r].state) for r in roles),
        timeout=WAIT_MS)


@pytest.mark.timeout(600)
def test_the_lock_in_and_filter_wheel_panels_show_the_servers_state(server, open_window,
                                                                      qtbot):
    srv = server(profile="sim-spectral")
    observer = _Observer(srv.url)
    try:
        w = open_window(srv.url)
        _shown(w, qtbot, ("lockin", "filter_wheel", "power_meter"), observer)
        lockin, wheel = w.panels["lockin"], w.panels["filter_wheel"]
        v, info = lockin.state.values, lockin.state.info
        assert v["sensitivity_v"] == 1.0 and v["reference"] == "external"
        assert v["frequency_hz"] == 137.0 and info["identity"]["model"] == "SR830"
        assert lockin.reading.text() == readouts.lockin_reading(v)
        assert lockin.detail.text() == readouts.lockin_detail(v)
        assert lockin.sensitivity.currentData() == v["sensitivity_v"]
        assert lockin.time_constant.currentData() == v["time_constant_s"]
        assert lockin.reference.currentData() == "external"
        assert lockin.sensitivity.count() == len(info["sensitivities_v"]) == 27
        wv = wheel.state.values
        assert wv == {"position": 1, "speed": "high"}
        assert wheel.position.text().startswith("slot 1: 450 nm")
        assert wheel.count.text() == "6" and wheel.speed.currentData() == "high"
        # set through the server: "applying…" from the click until the server's event
        for b in (lockin.sensitivity, lockin.auto, wheel.go, wheel.speed):
            assert b.isEnabled()
        wheel.slot.setCurrentIndex(wheel.slot.findData(3))
        wheel.go.click()
        assert not wheel.pending.isHidden() and wheel.pending.text().startswith("applying")
        qtbot.waitUntil(lambda: wheel.state.values["position"] == 3
                        and wheel.pending.isHidden() and wheel.go.isEnabled(),
                        timeout=WAIT_MS)
        assert wheel.position.text().startswith("slot 3")
        k = lockin.sensitivity.findData(1e-3)
        assert k >= 0
        lockin.sensitivity.activated.emit(k)
        assert not lockin.pending.isHidden()
        qtbot.waitUntil(lambda: lockin.state.values["sensitivity_v"] == 1e-3
                        and lockin.pending.isHidden(), timeout=WAIT_MS)
        assert lockin.sensitivity.currentData() == 1e-3
        assert lockin.outcome.isHidden()  # done: no refusal shown
        # refused by the server before anything was sent: the panel says why
        w.set_device("filter_wheel", {"position": 9})
        qtbot.waitUntil(lambda: not wheel.outcome.isHidden(), timeout=WAIT_MS)
        assert "filter_wheel.position" in wheel.outcome.text()
        assert wheel.pending.isHidden() and wheel.state.values["position"] == 3
    finally:
        observer.close()


# slow: 2.4 s CPU (a server process); the cheaper
# test_bench_panel.py::test_launch_connect_home_jog checks the same power-meter panel (reading in
# W at 633 nm), and test_the_lock_in_and_filter_wheel_panels_show_the_servers_state the same
# panels showing the server's published state, in the default run
@pytest.mark.slow
@pytest.mark.timeout(600)
def test_the_power_meter_panel_shows_the_servers_reading(server, open_window, qtbot):
    srv = server(profile="sim")
    observer = _Observer(srv.url)
    try:
        w = open_window(srv.url)
        _shown(w, qtbot, ("power_meter", "filter_wheel"), observer)
        pm = w.panels["power_meter"]
        v = pm.state.values
        assert v["wavelength_nm"] == 633.0 and pm.wavelength.text() == "633 nm"
        assert pm.reading.text() == fmt.si(v["power_w"], "W") != "—"
        assert pm.state.info["identity"]["model"] == "PM100USB"
        nd = w.panels["filter_wheel"]
        assert nd.position.text() == filters.slot_label(
            nd.bands(nd.state), nd.state.values["position"])
    finally:
        observer.close()


@pytest.mark.timeout(600)
def test_the_first_redraws_import_no_scipy_stats_on_the_gui_thread(server):
    """The run browser, built on the redraw that first knows the runs folder, imports
    nothing heavy: the fit's candidate models come from the registry, not from the fit
    pipeline (which imports scipy.stats, 0.4 s of CPU on the GUI thread). A fresh process,
    so that what other tests imported does not hide an import."""
    srv = server()
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen"}
    out = subprocess.run([sys.executable, "-m", "tests.gui.first_redraw", srv.url],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    found = json.loads(out.stdout.strip().splitlines()[-1])
    assert found["browser"], "the window never built its run browser"
    assert not found["stats_before_show"]
    assert "scipy.stats" not in found["imported"]
    assert not any(m.startswith("instrument.pipelines.brdf.analyse")
                   for m in found["imported"])
