"""The dashboard in a real Chromium against a real server process on the emulated bench.

Every wait is on a page condition (or an event) with a generous limit; nothing is timed
(ADR 0020). Where Chromium or Playwright is missing these tests skip, saying why in one
line; CI installs Chromium (.ci/run), so there they always run.
"""

from __future__ import annotations

import socket
from pathlib import Path

import h5py
import numpy as np
import pytest

from instrument.client import BenchClient, ClientError
from instrument.server.dashboard.screenshots import PLAN as SCREENSHOT_PLAN
from instrument.server.db import ServerDB
from instrument.server.keys import KeyStore
from tests.instrument.server.browser import (
    chromium,
    chromium_missing,
    sign_in,
    wait_live,
    wait_run_state,
)
from tests.instrument.server.helpers import ServerProcess, plan_text
from tests.waiting import wait_for

if (_why := chromium_missing()) is not None:
    pytest.skip(_why, allow_module_level=True)  # one line for the whole file

pytestmark = pytest.mark.timeout(900)

THETA_R = [-60.0, -40.0, 10.0, 40.0, 60.0]  # theta_i = 20: -20 is the beam
#: Many points, so that a pause asked for at the run's start lands long before its end.
LONG_THETA_R = [float(t) for t in np.arange(-80.0, 81.0, 3.0) if abs(t + 20.0) > 12.0]
#: A camera scan a fit can use (two incidence angles, dark frames): for the report.
CAMERA_PLAN = SCREENSHOT_PLAN.format(step=15.0)


def add_keys(runs: Path) -> dict[str, str]:
    """An observer's and an operator's key (the server then needs a key for everything)."""
    with ServerDB(runs) as db:
        store = KeyStore(db)
        return {"observer": store.add("olga", "observer")[1],
                "operator": store.add("oscar", "operator")[1]}


def page_int(page, selector: str, attr: str) -> int:
    return int(page.eval_on_selector(selector, f"e => e.dataset.{attr} || '0'"))


def wait_idle(client: BenchClient) -> None:
    def idle():
        s = client.status()
        return s["run"] is None and not s["queue_running"]
    wait_for(idle, what="the queue to run out", timeout=600)


def test_an_observer_watches_a_run_to_its_end_and_cannot_pause_it(bench_file, start_server,
                                                                    tmp_path):
    runs = tmp_path / "runs"
    keys = add_keys(runs)
    server = start_server(bench_file(), runs)
    with chromium(tmp_path / "profile") as page:
        sign_in(page, server.url, keys["observer"])
        assert page.inner_text("#who") == "signed in as olga (observer)"
        # the operator's buttons are greyed, with the reason
        for button in ("pause", "resume", "abort", "stop-all", "queue-add", "answer-skip"):
            assert page.is_disabled(f"#{button}"), button
            assert "observer key" in page.get_attribute(f"#{button}", "title")
        assert "only operators may pause" in page.inner_text("#role-reason")
        with BenchClient(server.url, keys["operator"]) as op:
            op.add_plan(plan_text("watched", THETA_R))
            op.start_queue()
            wait_run_state(page, "finished")
            # ... and the API refuses the observer's pause, from the page itself
            status = page.evaluate("api('POST', '/run/pause', {now: false}).then(r => r.status)")
            assert status == 403
            with BenchClient(server.url, keys["observer"]) as obs, \
                    pytest.raises(ClientError) as err:
                obs.pause()
            assert err.value.status == 403
            # the page sees "finished" from the event stream; the history row may land a
            # moment later on a loaded host
            wait_for(op.history, what="the finished run in the history", timeout=60)
            (h,) = op.history()
        assert h["outcome"] == "finished"
        n = len(THETA_R)
        page.wait_for_function(f"() => document.getElementById('run-numbers').dataset.done == {n}")
        assert page.inner_text("#run-numbers").startswith(f"{n} of {n} points")
        # every point plotted (the page watched from the start), axes labelled with units
        assert page_int(page, "#plot", "plotted") == n
        labels = page.evaluate("[Plot.fig.below[0].axis_label, Plot.fig.left[0].axis_label]")
        assert labels == ["θr (signed: > 0 specular side) (deg)", "power (W)"]
        log = page.inner_text("#log")
        assert "run started" in log and "run finished" in log
        assert "watched" in page.inner_text("#runs")
        assert page.errors == []


def plotted_indices(page) -> list[int]:
    return sorted(page.evaluate("Plot.kept.map((k) => k.i)"))


@pytest.mark.slow  # a 45-point run, paused after a few points: about a minute
def test_a_page_opened_mid_run_plots_the_run_from_its_first_point(bench_file, start_server,
                                                                   tmp_path):
    runs = tmp_path / "runs"
    keys = add_keys(runs)
    server = start_server(bench_file(speed=20), runs)
    n = len(LONG_THETA_R)
    with BenchClient(server.url, keys["operator"]) as op:
        op.add_plan(plan_text("joined late", LONG_THETA_R))
        op.start_queue()
        # held at a point boundary, so what "so far" means cannot move under the test
        wait_for(lambda: (op.status()["run"] or {}).get("n_done", 0) >= 3,
                 what="three points done", timeout=300)
        op.pause()
        wait_for(lambda: (op.status()["run"] or {}).get("state") == "paused",
                 what="the run to pause", timeout=300)
        done = op.status()["run"]["n_done"]
        assert 3 <= done < n
        with chromium(tmp_path / "profile") as page:
            page.goto(server.url.rstrip("/") + "/")
            page.evaluate("Backfill.pageSize = 2")  # several pages, as a long run has
            page.wait_for_selector("#signin:not([hidden])")
            page.fill("#key", keys["observer"])
            page.click("#signin-button")
            wait_live(page)
            page.wait_for_function(f"() => Plot.kept.length === {done}")
            assert plotted_indices(page) == list(range(done))  # from index 0, each once
            # the log is drawn at the page's next redraw tick
            page.wait_for_function("() => document.getElementById('log').innerText"
                                   ".includes(\"plotted the run's points so far\")")
            op.resume()
            wait_run_state(page, "finished")
            page.wait_for_function(f"() => Plot.kept.length === {n}")
            # the stream's points joined the ones read before them, none twice
            assert plotted_indices(page) == list(range(n))
            page.wait_for_function(
                f"() => document.getElementById('plot').dataset.plotted == {n}")
            assert page.evaluate("Plot.kind") == "in_plane"
            assert page.errors == []


@pytest.mark.slow  # a 45-point run, so that the pause lands early: about a minute
def test_an_operator_pauses_and_resumes_a_run_and_adds_a_plan_file(bench_file, start_server,
                                                                    tmp_path):
    runs = tmp_path / "runs"
    keys = add_keys(runs)
    server = start_server(bench_file(speed=20), runs)
    plan = tmp_path / "long.toml"
    plan.write_text(plan_text("paused and resumed", LONG_THETA_R), encoding="utf-8")
    with chromium(tmp_path / "profile") as page:
        sign_in(page, server.url, keys["operator"])
        assert page.inner_text("#role-reason") == ""
        page.set_input_files("#plan-file", str(plan))
        page.click("#queue-add")
        page.wait_for_function("() => document.querySelector('#queue tbody').innerText"
                               ".includes('paused and resumed')")
        assert "oscar" in page.inner_text("#queue")  # who added it
        page.click("#queue-start")
        wait_run_state(page, "running")
        page.click("#pause")
        wait_run_state(page, "paused")
        with BenchClient(server.url, keys["observer"]) as obs:
            assert obs.status()["run"]["state"] == "paused"
        assert page.is_enabled("#resume") and page.is_disabled("#pause")
        assert "paused by oscar" in page.inner_text("#log")
        page.click("#resume")
        wait_run_state(page, "finished")
        assert "resumed" in page.inner_text("#log")
        with BenchClient(server.url, keys["observer"]) as obs:
            wait_for(obs.history, what="the finished run in the history", timeout=60)
            (h,) = obs.history()
        assert h["outcome"] == "finished"
        with h5py.File(h["run_file"]) as f:
            assert sorted(f["entry/points/index"][:].tolist()) == \
                list(range(len(LONG_THETA_R)))
        assert page.errors == []


def test_an_operator_answers_an_injected_fault_with_skip(bench_file, start_server, tmp_path):
    runs = tmp_path / "runs"
    keys = add_keys(runs)
    server = start_server(bench_file(pause_on_detector_fault=True), runs,
                          env={"SCATTERLAB_TEST_FAULT": "simsmc:detector_theta:1"})
    with chromium(tmp_path / "profile") as page:
        sign_in(page, server.url, keys["operator"])
        with BenchClient(server.url, keys["operator"]) as op:
            op.add_plan(plan_text("faulty", THETA_R))
        page.click("#queue-start")
        page.wait_for_selector("#fault-box:not([hidden])")
        assert "detector_theta" in page.inner_text("#fault-box")
        for answer in ("retry", "skip", "abort"):
            assert page.is_enabled(f"#answer-{answer}")
        assert "fault: detector_theta" in page.inner_text("#log")
        page.click("#answer-skip")
        wait_run_state(page, "finished")
        assert page.is_hidden("#fault-box")
        assert "(1 skipped)" in page.inner_text("#run-numbers")
        with BenchClient(server.url, keys["observer"]) as obs:
            wait_for(obs.history, what="the finished run in the history", timeout=60)
            (h,) = obs.history()
        with h5py.File(h["run_file"]) as f:
            assert (f["entry/points/status"][:] == 1).sum() == 1  # one point skipped
        assert page.errors == []


@pytest.mark.slow  # a camera run and its fit: about a minute (run by CI: ADR 0021)
def test_an_observer_sees_the_camera_opens_a_finished_runs_report_and_downloads_it(
        bench_file, start_server, tmp_path):
    from instrument.pipelines.brdf.pipeline import fit_run

    runs = tmp_path / "runs"
    keys = add_keys(runs)
    server = start_server(bench_file(), runs)
    with chromium(tmp_path / "profile") as page:
        sign_in(page, server.url, keys["observer"])
        with BenchClient(server.url, keys["operator"]) as op:
            op.add_plan(CAMERA_PLAN)
            op.start_queue()
            wait_run_state(page, "finished")
            wait_idle(op)
            (h,) = op.history()
        caption = page.inner_text("#frame-caption")
        assert "exposure" in caption and "saturated" in caption
        assert page.is_visible("#frame")
        fit_run(h["run_file"])  # what `scatterlab fit RUN.h5` does: DIR/RUN/fit/index.html
        page.click("#runs-refresh")
        name = Path(h["run_file"]).name
        row = page.locator("#runs tbody tr", has_text=name)
        row.locator(".open-report").click()
        page.wait_for_selector("#report:not([hidden])")
        report = page.frame_locator("#report")
        assert report.locator("h1").first.inner_text().startswith("BRDF of sim-grey")
        sources = report.locator("img").evaluate_all("imgs => imgs.map(i => i.src)")
        assert sources and all(s.startswith("data:image/png;base64,") for s in sources)
        assert page.inner_text("#report-title") == f"fit report of {name}"
        with page.expect_download() as dl:
            row.locator(".download").click()
        assert dl.value.suggested_filename == name
        assert Path(dl.value.path()).read_bytes() == Path(h["run_file"]).read_bytes()
        assert page.errors == []


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# slow: 6.5 s CPU (two server starts and Chromium); the page's event stream is followed to a
# run's end in the default run by test_an_observer_watches_a_run_to_its_end_and_cannot_pause_it
@pytest.mark.slow
def test_the_page_reconnects_by_itself_after_the_server_restarts(bench_file, tmp_path):
    bench, runs = bench_file(), tmp_path / "runs"
    listen = f"127.0.0.1:{_free_port()}"
    servers = [ServerProcess(bench, runs, listen=listen)]
    try:
        with chromium(tmp_path / "profile") as page:
            sign_in(page, servers[0].url, None)  # no keys: loopback acts as admin
            servers[0].kill()  # kill -9: no goodbye to the page
            page.wait_for_function(
                "() => document.getElementById('conn').textContent === 'reconnecting…'")
            servers.append(ServerProcess(bench, runs, listen=listen))
            wait_live(page)
            assert page.inner_text("#log").count("connected to bench sim") == 2
            assert "lost the server" in page.inner_text("#log")
            # and the events flow again: a run after the restart is seen to its end
            with BenchClient(servers[1].url) as c:
                c.add_plan(plan_text("after the restart", THETA_R))
                c.start_queue()
            wait_run_state(page, "finished")
            assert page.errors == []
    finally:
        for s in servers:
            s.kill()


#: The page's memory bound (dashboard.js MAX_PLOT_POINTS, MAX_LOG).
MAX_PLOT_POINTS, MAX_LOG = 4000, 300


# slow: 3.6 s CPU (a server and Chromium); the page's plot and log in a browser are checked in
# the default run by test_an_observer_watches_a_run_to_its_end_and_cannot_pause_it (every point
# plotted)
@pytest.mark.slow
def test_the_plot_and_the_log_stay_bounded_over_a_long_run(bench_file, start_server,
                                                           tmp_path):
    """An 8-hour run's worth of points (100,000, in the server's batches) and 1,000 log
    lines through the page's own message handler: the plot keeps ≤ 4,000 points spread
    over the whole run, the log 300 lines."""
    server = start_server(bench_file())
    with chromium(tmp_path / "profile") as page:
        sign_in(page, server.url, None)
        kept = page.evaluate("""() => {
            const n = 100000;
            handle({type: 'run_started', data: {n_total: n, n_done: 0, estimated_s: 28800,
                    path: '/runs/long.h5', item_id: 1, plan_kind: 'brdf_in_plane'}});
            for (let start = 0; start < n; start += 250) {
                const items = [];
                for (let i = start; i < start + 250; i++) {
                    const tr = -80 + 160 * ((i * 7919) % n) / n;
                    items.push({index: i, status: 'ok', angles: [20 + 5 * (i % 3), 0, tr, 180],
                                signal: 1 + Math.cos(tr / 60), power_w: null});
                }
                handle({type: 'points', data: {items}});
            }
            for (let i = 0; i < 1000; i++) addLog('info', 'line ' + i);
            Plot.draw();
            const idx = Plot.kept.map(k => k.i);
            return {n: idx.length, first: Math.min(...idx), last: Math.max(...idx),
                    stride: Plot.stride, log: S.log.length,
                    curves: Plot.sources.size, seen: Plot.seen.size, seenMax: SEEN_MAX};
        }""")
    assert MAX_PLOT_POINTS // 2 <= kept["n"] <= MAX_PLOT_POINTS
    assert kept["first"] == 0 and kept["last"] >= 100_000 - 2 * kept["stride"]
    assert kept["stride"] == 32  # 100,000 / 32 = 3,125 points kept
    assert kept["curves"] == 3  # one per θi
    assert kept["log"] == MAX_LOG
    assert kept["seen"] == kept["seenMax"] == 10_000  # the indices remembered, bounded too


#: In-plane points ``span(a, b)`` (indices a … b-1) for the page's own handlers.
SPAN_JS = """
            const pt = (i) => ({index: i, status: 'ok', angles: [20, 180, -60 + 10 * i, 0],
                                signal: 1 + i, power_w: null});
            const span = (a, b) => Array.from({length: b - a}, (_, k) => pt(a + k));"""


# slow: 4.2 s CPU (a server and Chromium); each point plotted once over a whole run is checked in
# the default run by test_an_observer_watches_a_run_to_its_end_and_cannot_pause_it
@pytest.mark.slow
def test_points_read_so_far_and_the_streams_overlap_are_plotted_once(bench_file,
                                                                      start_server, tmp_path):
    """The prefill's order of events, driven through the page's own handlers: stream points
    that come before the first page wait for it (it names the plan), and points in both the
    pages and the stream are plotted once."""
    server = start_server(bench_file())
    with chromium(tmp_path / "profile") as page:
        sign_in(page, server.url, None)
        got = page.evaluate("""() => {""" + SPAN_JS + """
            S.run = {state: 'running', n_total: 12, n_done: 8, plan_kind: null};
            Plot.clear();
            Backfill.early = [];                                  // connected: reading pages
            handle({type: 'points', data: {items: span(8, 10)}});  // before the first page
            const held = Plot.kept.length;
            Backfill.first({plan_kind: 'brdf_in_plane', n_total: 12});
            Plot.add(span(0, 5));                                 // page 1
            Plot.add(span(5, 10));                                // page 2 overlaps the stream
            handle({type: 'points', data: {items: span(9, 12)}});  // and the stream the pages
            return {held, kind: Plot.kind, planKind: S.run.plan_kind,
                    idx: Plot.kept.map((k) => k.i).sort((a, b) => a - b)};
        }""")
        assert page.errors == []
    assert got["held"] == 0
    assert (got["kind"], got["planKind"]) == ("in_plane", "brdf_in_plane")
    assert got["idx"] == list(range(12))


@pytest.mark.slow  # a server, Chromium and a run: 25 s
def test_a_resumed_runs_backfill_is_plotted_with_the_points_that_follow(bench_file,
                                                                        start_server,
                                                                        tmp_path):
    """The server's order of events for a resumed run, through the page's own handlers:
    run_started (5 of 12 done), the backfill of those 5, then new points: the plot has the
    run whole, each point once, and the log says what came back."""
    server = start_server(bench_file())
    with chromium(tmp_path / "profile") as page:
        sign_in(page, server.url, None)
        got = page.evaluate("""() => {""" + SPAN_JS + """
            handle({type: 'run_started', data: {run_id: 'r', path: '/runs/r.h5',
                    plan_kind: 'brdf_in_plane', n_total: 12, n_done: 5, estimated_s: 1,
                    item_id: 1}});
            handle({type: 'backfill', data: {run_id: 'r', path: '/runs/r.h5', n_points: 5,
                    part: 1, parts: 1, items: span(0, 5)}});
            handle({type: 'points', data: {items: span(5, 12)}});
            return {idx: Plot.kept.map((k) => k.i).sort((a, b) => a - b),
                    log: S.log.map((e) => e.text)};
        }""")
        assert page.errors == []
    assert got["idx"] == list(range(12))
    assert any("5 points stored before it was resumed" in t for t in got["log"])


# slow: 4.6 s CPU (a server and Chromium); the same polar map's geometry (x = θr cos φr, y = θr
# sin φr) is checked in the GUI's plot in the default run by
# test_live_plots.py::test_the_hemisphere_map_fills; the page's own mapping and log colour run in
# CI's slow run
@pytest.mark.slow
def test_a_hemisphere_scan_is_a_polar_map_coloured_by_log_signal(bench_file, start_server,
                                                                  tmp_path):
    """As the GUI's: x = θr cos φr, y = θr sin φr, the colour mapping log10 of the signal
    over the range plotted."""
    server = start_server(bench_file())
    with chromium(tmp_path / "profile") as page:
        sign_in(page, server.url, None)
        drawn = page.evaluate("""() => {
            handle({type: 'run_started', data: {n_total: 3, n_done: 0, estimated_s: 10,
                    path: '/runs/h.h5', item_id: 1, plan_kind: 'brdf_hemisphere'}});
            handle({type: 'points', data: {items: [
                {index: 0, status: 'ok', angles: [30, 180, 60, 0], signal: 10, power_w: null},
                {index: 1, status: 'ok', angles: [30, 180, 30, 90], signal: 1000, power_w: null},
                {index: 2, status: 'skipped', angles: [30, 180, 45, 180], signal: null,
                 power_w: null}]}});
            Plot.draw();
            const d = Plot.sources.get(0).data;
            return {x: Array.from(d.x), y: Array.from(d.y), v: Array.from(d.v),
                    low: Plot.mapper.low, high: Plot.mapper.high,
                    labels: [Plot.fig.below[0].axis_label, Plot.fig.left[0].axis_label]};
        }""")
        assert page.errors == []
    assert drawn["x"] == pytest.approx([60.0, 0.0], abs=1e-9)
    assert drawn["y"] == pytest.approx([0.0, 30.0], abs=1e-9)
    assert drawn["v"] == pytest.approx([1.0, 3.0])
    assert (drawn["low"], drawn["high"]) == (pytest.approx(1.0), pytest.approx(3.0))
    assert drawn["labels"] == ["θr cos φr (deg)", "θr sin φr (deg)"]


@pytest.mark.slow  # two camera scans' worth of the sim bench and a fit: minutes
def test_the_screenshot_script_renders_the_dashboards_pictures_none_blank(tmp_path):
    import matplotlib.image

    from instrument.server.dashboard.screenshots import DASHBOARD_VIEWS, render_dashboard

    shots = render_dashboard(tmp_path)
    assert tuple(shots) == DASHBOARD_VIEWS
    for name, path in shots.items():
        px = matplotlib.image.imread(path)[..., :3]
        assert px.shape[0] > 400 and px.shape[1] > 800, name
        assert len(np.unique(px.reshape(-1, 3)[::7], axis=0)) > 50, f"{name} looks blank"


# slow: 4.3 s CPU (a server and Chromium); the camera settings through the server are checked in
# the default run by
# test_client_window.py::test_the_camera_settings_are_set_through_the_server_between_runs_only
@pytest.mark.slow
def test_the_device_table_has_the_cameras_settings_and_during_a_run_its_frames_exposure(
        bench_file, start_server, tmp_path):
    server = start_server(bench_file())
    with chromium(tmp_path / "profile") as page:
        sign_in(page, server.url, None)
        page.wait_for_selector("#camera-row")
        with BenchClient(server.url) as admin:  # loopback without keys: the local admin
            admin.take_control()
            admin.camera_settings(exposure_us=2500.0)
            admin.release_control()
        page.wait_for_function("() => document.getElementById('camera-row').innerText"
                               ".includes('exposure 2500 µs')")
        assert "gain" in page.inner_text("#camera-row")
        # a run owns the bench: the latest frame's exposure, and who sets it
        row = page.evaluate("""() => {
            S.frame = {drawn: true, exposure_us: 1234.5};
            handle({type: 'devices', data: {axes: {}, light: null, owner: 'run'}});
            render();
            return document.getElementById('camera-row').innerText;
        }""")
        assert "exposure 1234.5 µs" in row and "run controls it" in row
        assert page.errors == []


@pytest.mark.slow  # a server, Chromium and a run: 25 s
def test_an_operator_sets_a_device_from_the_device_table(bench_file, start_server,
                                                          tmp_path):
    server = start_server(bench_file())
    with chromium(tmp_path / "profile") as page:
        sign_in(page, server.url, None)  # loopback without keys: the local admin
        page.wait_for_selector("#device-filter_wheel")
        assert "slot 1" in page.inner_text("#device-filter_wheel")
        assert " W" in page.inner_text("#device-power_meter")  # the meter has its row
        page.select_option("#device-role", "filter_wheel")
        page.select_option("#device-field", "position")
        page.fill("#device-value", "3")
        page.wait_for_function("() => !document.getElementById('device-apply').disabled")
        page.click("#device-apply")
        page.wait_for_function("() => document.getElementById('device-filter_wheel')"
                               ".innerText.includes('slot 3')")
        page.wait_for_function("() => [...document.querySelectorAll('#log li')]"
                               ".some(li => li.innerText.includes('position=3 done'))")
        # refused before anything is sent: the field is named
        page.fill("#device-value", "9")
        page.wait_for_function("() => !document.getElementById('device-apply').disabled")
        page.click("#device-apply")
        page.wait_for_function("() => document.getElementById('command-result')"
                               ".innerText.includes('filter_wheel.position')")
        assert "slot 3" in page.inner_text("#device-filter_wheel")
        assert page.errors == []
