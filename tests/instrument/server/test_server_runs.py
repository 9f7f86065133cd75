"""Runs through a real server process: a resumed run is shown whole after a restart
(backfill), a run's data do not depend on how long the server polled the emulated
devices before it, and who may act without a key on loopback. Every wait is on an event
or a printed line, with a generous limit (ADR 0020)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from gui.model.remote import RemoteState
from instrument.client import BenchClient, ClientError
from instrument.server.db import ServerDB
from instrument.server.keys import KeyStore
from tests.instrument.server.helpers import plan_text
from tests.instrument.server.test_server_e2e import Watcher, wait_idle
from tests.waiting import wait_for

THETA_R = [-60.0, -40.0, 10.0, 40.0, 60.0]  # theta_i = 20: -20 is the beam


@pytest.mark.slow  # real server processes, a restart: 30-40 s
@pytest.mark.timeout(900)
def test_a_run_resumed_after_a_restart_is_shown_whole(bench_file, start_server):
    bench = bench_file()
    # killed (SIGKILL, on the engine's thread) once point 2 of the first run is stored
    server = start_server(bench, env={"SCATTERLAB_TEST_KILL": "1:2"})
    with BenchClient(server.url) as c:
        item = c.add_plan(plan_text("resumed", THETA_R))
        c.start_queue()
    assert server.proc.wait(300) != 0  # it killed itself mid-run

    server = start_server(bench)
    w = Watcher(server.url)
    assert w.hello.wait(60)
    with BenchClient(server.url) as c:
        assert c.queue()["items"][0]["id"] == item["id"]
        c.resume()
        wait_idle(c, "the resumed run to end")
        wait_for(lambda: w.of("run_finished"), what="the run's end on the stream")
        # a client that connects after the resumption reads the backfill with the rest
        run, items = c.all_run_points()
    started = w.of("run_started")[0].data
    # the points stored before the kill (the journal's, as the resumption recovered them)
    assert 3 <= started["n_done"] < len(THETA_R)
    backfill = w.of("backfill")
    assert [(m.data["part"], m.data["parts"]) for m in backfill] == [(1, 1)]
    assert backfill[0].data["path"] == started["path"]
    assert backfill[0].data["n_points"] == started["n_done"]
    stored = sorted(i["index"] for i in backfill[0].data["items"])
    assert len(set(stored)) == len(stored) == started["n_done"]
    # the backfill comes right after run_started, before any new point
    order = [m.type for m in w.messages if m.type in ("run_started", "backfill", "points")]
    assert order[:2] == ["run_started", "backfill"]
    after = sorted(i["index"] for m in w.of("points") for i in m.data["items"])
    assert sorted(stored + after) == list(range(len(THETA_R)))  # whole, once each
    assert run["run_id"] == started["run_id"]
    assert sorted(i["index"] for i in items) == list(range(len(THETA_R)))
    # the GUI's model of the server draws every point of the run
    state = RemoteState(server.url)
    for m in w.messages:
        state.apply(m)
    assert state.run is not None and sorted(state.run.seen) == list(range(len(THETA_R)))
    with h5py.File(started["path"]) as f:
        power = dict(zip(f["entry/points/index"][:].tolist(),
                         f["entry/points/power_w"][:].tolist(), strict=True))
    drawn = {i["index"]: i["power_w"] for i in backfill[0].data["items"]}
    assert drawn == {k: power[k] for k in stored}  # the values in the file, as stored
    w.close()


def _run_data(server, name: str, *, idle_polls: int) -> dict[str, np.ndarray]:
    """Run one plan (power meter, a dark reading at every point) on ``server`` after at
    least ``idle_polls`` power-meter readings of the sampler (each a ``devices`` message
    with a new read_at); the run's arrays."""
    w = Watcher(server.url)
    assert w.hello.wait(60)

    def polls() -> int:
        return len({m.data["states"]["power_meter"]["read_at"] for m in w.of("devices")
                    if "power_meter" in (m.data.get("states") or {})})
    wait_for(lambda: polls() >= idle_polls, 300, f"{idle_polls} idle readings")
    with BenchClient(server.url) as c:
        c.add_plan(plan_text(name, THETA_R) + 'dark = "per_point"\n')
        c.start_queue()
        wait_idle(c, "the run to end")
        path = c.history()[-1]["run_file"]
    w.close()
    with h5py.File(path) as f:
        p = f["entry/points"]
        order = np.argsort(p["index"][:])
        return {k: p[k][:][order] for k in ("index", "power_w", "power_dark_w", "signal",
                                           "positions")}


@pytest.mark.slow  # two real server processes: 30-40 s
@pytest.mark.timeout(900)
def test_a_runs_data_do_not_depend_on_the_idle_polls_before_it(bench_file, start_server,
                                                               tmp_path):
    bench = bench_file()
    quick = _run_data(start_server(bench, tmp_path / "a"), "same", idle_polls=0)
    late = _run_data(start_server(bench, tmp_path / "b"), "same", idle_polls=12)
    for key in quick:
        np.testing.assert_array_equal(quick[key], late[key], err_msg=key)  # bit for bit
    assert np.isfinite(quick["power_w"]).all() and np.isfinite(quick["power_dark_w"]).all()


@pytest.mark.timeout(300)
def test_loopback_without_keys_is_unauthenticated_admin_and_says_so(bench_file,
                                                                     start_server):
    server = start_server(bench_file())
    # printed right after the address (read on the helper's own thread)
    wait_for(lambda: any("--require-keys" in line for line in server.lines), 60,
             "the access lines")
    assert any("UNAUTHENTICATED" in line for line in server.lines)
    with BenchClient(server.url) as c:
        assert c.status()["you"] == {"name": "local", "role": "admin"}


@pytest.mark.timeout(300)
def test_require_keys_refuses_loopback_clients_without_a_key(bench_file, start_server,
                                                              tmp_path):
    runs = tmp_path / "runs"
    server = start_server(bench_file(), runs, args=("--require-keys",))
    wait_for(lambda: any("needs an API key and none exists" in line
                         for line in server.lines), 60, "the access line")
    assert not any("UNAUTHENTICATED" in line for line in server.lines)
    with BenchClient(server.url) as c, pytest.raises(ClientError) as err:
        c.status()
    assert err.value.status == 401
    with ServerDB(runs) as db:  # `scatterlab serve keys add` on the bench PC
        _, token = KeyStore(db).add("ann", "operator")
    with BenchClient(server.url, token) as c:
        assert c.status()["you"] == {"name": "ann", "role": "operator"}
