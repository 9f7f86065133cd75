"""End to end: a real server process on a random loopback port, the emulated sim bench,
clients in this process. Every wait is on an event with a generous limit (ADR 0020)."""

from __future__ import annotations

import threading
import time

import h5py
import numpy as np
import pytest

from instrument.client import BenchClient, ClientError
from instrument.run.runfile import read_events
from tests.instrument.server.helpers import plan_text
from tests.waiting import wait_for

THETA_R = [-60.0, -40.0, 10.0, 40.0, 60.0]  # theta_i = 20: -20 is the beam


class Watcher:
    """A client reading the event stream on a thread of its own, keeping every message."""

    def __init__(self, url: str) -> None:
        self.messages = []
        self.error: ClientError | None = None
        self.client = BenchClient(url)
        self._gen = self.client.events()
        self.hello = threading.Event()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        try:
            for msg in self._gen:
                self.messages.append(msg)
                if msg.type == "hello":
                    self.hello.set()
        except ClientError as err:  # the server was killed: the test looks at what came
            self.error = err

    def of(self, kind: str) -> list:
        return [m for m in list(self.messages) if m.type == kind]

    def close(self) -> None:
        self.client.close()


def wait_idle(client: BenchClient, what: str) -> dict:
    """Wait until no run goes on and the queue has stopped (asking ten times a second)."""
    def idle():
        s = client.status()
        if s["run"] is None and not s["queue_running"]:
            return s
        time.sleep(0.1)
        return None
    wait_for(idle, what=what, timeout=300)
    return client.status()


@pytest.mark.timeout(900)
def test_a_queue_of_three_plans_runs_in_order_and_two_clients_watch_it(
        bench_file, start_server):
    server = start_server(bench_file())
    watchers = [Watcher(server.url), Watcher(server.url)]
    for w in watchers:
        assert w.hello.wait(60)
    with BenchClient(server.url) as c:
        names = ["first", "second", "third"]
        ids = [c.add_plan(plan_text(n, THETA_R))["id"] for n in names]
        c.start_queue()
        status = wait_idle(c, "the queue to run out")
        assert status["queue"] == []
        hist = c.history()
    assert [h["name"] for h in hist] == names
    assert [h["item_id"] for h in hist] == ids
    assert all(h["outcome"] == "finished" for h in hist)
    files = [h["run_file"] for h in hist]
    for f in files:
        with h5py.File(f) as h:
            assert h["entry/points/index"].shape[0] == len(THETA_R)
    # both clients saw every lifecycle event of the three runs, in order
    for w in watchers:
        wait_for(lambda w=w: len(w.of("item_finished")) == 3, what="three items finished")
        started = [m.data["path"] for m in w.of("run_started")]
        finished = [(m.data["status"], m.data["path"]) for m in w.of("run_finished")]
        assert started == files
        assert finished == [("finished", f) for f in files]
        seqs = [m.seq for m in w.messages if m.type not in ("hello", "missed")]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert [m.seq for m in watchers[0].of("run_finished")] == \
        [m.seq for m in watchers[1].of("run_finished")]
    for w in watchers:
        w.close()


@pytest.mark.slow  # run by CI after the default run (ADR 0021)
@pytest.mark.timeout(900)
def test_kill_9_of_the_server_mid_run_then_restart_and_resume_loses_nothing(
        bench_file, start_server, tmp_path):
    # Stages at real speed: the 16 points left after the third take seconds of emulated
    # motion however fast the machine, so the kill lands mid-run.
    bench = bench_file(speed=1)
    theta_r = [float(x) for x in np.arange(-70.0, 71.0, 7.0) if abs(x + 20.0) > 7.0]
    server = start_server(bench)
    w = Watcher(server.url)
    assert w.hello.wait(60)
    with BenchClient(server.url) as c:
        item = c.add_plan(plan_text("long", theta_r))
        c.start_queue()
        wait_for(lambda: sum(len(m.data["items"]) for m in w.of("points")) >= 3,
                 what="three points stored")
    server.kill()
    w.close()
    assert not w.of("run_finished")  # killed mid-run
    path = w.of("run_started")[0].data["path"]
    n_total = w.of("run_started")[0].data["n_total"]
    # restarted on the same runs folder: the item is there, shown resumable
    server = start_server(bench)
    assert any("was interrupted" in line for line in server.lines)
    with BenchClient(server.url) as c:
        q = c.queue()
        assert [i["id"] for i in q["items"]] == [item["id"]] and not q["running"]
        head = q["items"][0]
        assert head["state"] == "interrupted" and head["resumable"]
        assert head["run_file"] == path
        print(c.resume())  # as `scatterlab resume` does: recover, continue the same file
        status = wait_idle(c, "the resumed run to end")
        assert status["queue"] == []
        outcomes = [h["outcome"] for h in c.history()]
    assert outcomes == ["interrupted", "finished"]
    with h5py.File(path) as f:
        idx = sorted(f["entry/points/index"][:].tolist())
        status_flags = f["entry/points/status"][:]
    assert idx == list(range(n_total))  # 0 lost, 0 duplicated
    assert (status_flags == 0).all()
    kinds = [e["kind"] for e in read_events(path)]
    assert "resumed" in kinds


@pytest.mark.timeout(900)
@pytest.mark.parametrize("answer", ["retry", "skip", "abort"])
def test_a_fault_on_the_emulated_bench_reaches_every_client_and_an_operator_answers(
        bench_file, start_server, answer):
    bench = bench_file(pause_on_detector_fault=True)
    server = start_server(bench, env={"SCATTERLAB_TEST_FAULT": "simsmc:detector_theta:1"})
    watchers = [Watcher(server.url), Watcher(server.url)]
    for w in watchers:
        assert w.hello.wait(60)
    with BenchClient(server.url) as c:
        c.add_plan(plan_text("faulty", THETA_R))
        c.start_queue()
        for w in watchers:
            wait_for(lambda w=w: w.of("paused"), what="the run paused for the fault")
            faults = w.of("fault")
            assert faults and faults[-1].data["device"] == "detector_theta"
            assert faults[-1].data["action"] == "pause"
            assert w.of("paused")[0].data["answers"] == ["retry", "skip", "abort"]
        status = c.status()
        assert status["run"]["state"] == "paused"
        assert status["run"]["answers"] == ["retry", "skip", "abort"]
        failed = watchers[0].of("paused")[0].data["index"]
        if answer == "abort":
            c.abort()
        else:
            c.resume(answer)
        wait_for(lambda: all(w.of("run_finished") for w in watchers), what="the run's end")
        end = watchers[0].of("run_finished")[0].data
        path = end["path"]
        if answer == "abort":
            assert end["status"] == "aborted"
            q = c.queue()
            assert q["items"][0]["state"] == "aborted" and q["items"][0]["resumable"]
            return
        assert end["status"] == "finished" and end["n_done"] == end["n_total"]
    with h5py.File(path) as f:
        idx = f["entry/points/index"][:].tolist()
        flags = f["entry/points/status"][:]
    row = idx.index(failed)
    if answer == "retry":
        assert (flags == 0).all()
    else:
        assert flags[row] == 1 and (flags == 1).sum() == 1


@pytest.mark.slow  # run by CI after the default run (ADR 0021)
@pytest.mark.timeout(900)
def test_clients_that_stall_or_disconnect_change_nothing_for_the_run(bench_file,
                                                                      start_server):
    from websockets.sync.client import connect

    server = start_server(bench_file())
    ws_url = "ws" + server.url[4:] + "/api/v1/events"
    with connect(ws_url) as stalled, connect(ws_url) as leaver:  # stalled never reads
        leaver.recv(60)  # its hello; it goes away once the run has started
        w = Watcher(server.url)
        assert w.hello.wait(60)
        with BenchClient(server.url) as c:
            c.add_plan(plan_text("crowded", THETA_R))
            c.start_queue()
            wait_for(lambda: w.of("run_started"), what="the run's start")
            leaver.close()
            wait_idle(c, "the run's end")
            (h,) = c.history()
        assert stalled.protocol is not None
    assert h["outcome"] == "finished"
    with h5py.File(h["run_file"]) as f:
        assert sorted(f["entry/points/index"][:].tolist()) == list(range(len(THETA_R)))
    w.close()


@pytest.mark.slow  # run by CI after the default run (ADR 0021)
@pytest.mark.timeout(900)
def test_pause_now_stops_at_once_and_resume_continues_the_same_file(bench_file,
                                                                     start_server):
    bench = bench_file(speed=1)  # the run cannot end before the pause, however fast
    theta_r = [-70.0, -60.0, -45.0, 0.0, 10.0, 30.0, 50.0, 70.0]
    server = start_server(bench)
    w = Watcher(server.url)
    assert w.hello.wait(60)
    with BenchClient(server.url) as c:
        item = c.add_plan(plan_text("paused now", theta_r))
        c.start_queue()
        wait_for(lambda: w.of("points"), what="a point stored")
        c.pause(now=True)
        wait_for(lambda: w.of("run_finished"), what="the stop")
        assert w.of("run_finished")[0].data["status"] == "aborted"
        head = c.queue()["items"][0]
        assert head["id"] == item["id"] and head["state"] == "paused" and head["resumable"]
        c.resume()
        wait_idle(c, "the resumed run's end")
        assert [h["outcome"] for h in c.history()] == ["paused", "finished"]
    path = w.of("run_started")[0].data["path"]
    assert [m.data["path"] for m in w.of("run_started")] == [path, path]
    with h5py.File(path) as f:
        assert sorted(f["entry/points/index"][:].tolist()) == list(range(len(theta_r)))
    w.close()
