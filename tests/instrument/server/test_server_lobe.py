"""A two-pass lobe plan as one queue item of a real server process: the first pass, its
fit, the second pass placed by Fisher information (as ``scatterlab run`` does), with
events; and kill -9 during the second pass, then a restart and resume, losing nothing."""

from __future__ import annotations

from pathlib import Path

import h5py
import pytest

from instrument.client import BenchClient
from instrument.pipelines.brdf.second_pass import is_second_pass
from instrument.run.runfile import read_run
from tests.instrument.plans.test_lobe import LOBE_PLAN
from tests.instrument.server.test_server_e2e import Watcher, wait_idle
from tests.instrument.sim_scan import Sample, ScanSetup, profile_text
from tests.waiting import wait_for

N_SECOND = 8


@pytest.fixture
def lobe_bench(tmp_path) -> Path:
    """The sim bench rendering a sharp GGX lobe (α = 0.05) on its camera, stages fast."""
    setup = ScanSetup(theta_i_deg=(20.0, 60.0), power_w=2e-8, sensor_px=48)
    sample = Sample("sharp", "lambert+ggx", (0.3, 0.5, 0.05))
    bench = tmp_path / "bench.toml"
    bench.write_text(profile_text(setup, sample).replace("speed=20", "speed=400").replace(
        "stage=MTS25-Z8&speed=400", "stage=MTS25-Z8&speed=400&start=0"), encoding="utf-8")
    return bench


PLAN = LOBE_PLAN.replace("points = 10,", f'points = {N_SECOND}, prior = "lambert+ggx",')


def points_of(path: str) -> list[int]:
    with h5py.File(path) as f:
        return sorted(f["entry/points/index"][:].tolist())


def check_two_passes(second: str, n_total: int) -> str:
    """The second pass's run file is complete (each planned point once) and names the
    first, which is complete too; returns the first's path."""
    assert is_second_pass(second)
    assert points_of(second) == list(range(n_total))
    first_name = read_run(second).plan().scan["first_pass"]
    first = str(Path(second).parent / first_name)
    assert not is_second_pass(first)
    n_first = len(read_run(first).plan().scan["theta_i"])
    assert n_first == 2 and len(points_of(first)) > N_SECOND
    return first


@pytest.mark.slow  # two camera scans and a fit (ADR 0021)
@pytest.mark.timeout(900)
def test_a_two_pass_lobe_plan_runs_as_one_queue_item(lobe_bench, start_server):
    server = start_server(lobe_bench)
    w = Watcher(server.url)
    assert w.hello.wait(60)
    with BenchClient(server.url) as c:
        item = c.add_plan(PLAN)
        c.start_queue()
        status = wait_idle(c, "the two passes to end")
        assert status["queue"] == []
        hist = c.history()
    assert [(h["item_id"], h["outcome"]) for h in hist] == [(item["id"], "finished")]
    wait_for(lambda: w.of("item_finished"), what="the item's end on the event stream")
    started = [m.data for m in w.of("run_started")]
    finished = [m.data for m in w.of("run_finished")]
    assert len(started) == 2 and [f["status"] for f in finished] == ["finished"] * 2
    assert [s["item_id"] for s in started] == [item["id"]] * 2
    second = started[1]["path"]
    assert hist[0]["run_file"] == second and started[1]["n_total"] == N_SECOND
    assert check_two_passes(second, N_SECOND) == started[0]["path"]
    steps = [(m.data["state"], m.data["n_points"]) for m in w.of("second_pass")]
    assert steps == [("planning", None), ("planned", N_SECOND)]
    assert "placed by Fisher information" in w.of("second_pass")[1].data["message"]
    # the progress of both runs reached the clients
    assert {m.data["n_total"] for m in w.of("progress")} >= {N_SECOND}
    w.close()


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_kill_9_during_the_second_pass_then_resume_loses_nothing(lobe_bench, start_server):
    # the server kills itself once point 2 of its second run (the second pass) is stored
    server = start_server(lobe_bench, env={"SCATTERLAB_TEST_KILL": "2:2"})
    w = Watcher(server.url)
    assert w.hello.wait(60)
    with BenchClient(server.url) as c:
        item = c.add_plan(PLAN)
        c.start_queue()
    assert server.proc.wait(600) == -9
    w.close()
    started = [m.data for m in w.of("run_started")]
    assert len(started) == 2 and len(w.of("run_finished")) == 1
    second = started[1]["path"]
    server = start_server(lobe_bench)  # restarted on the same runs folder
    with BenchClient(server.url) as c:
        head = c.queue()["items"][0]
        assert head["id"] == item["id"] and head["state"] == "interrupted"
        assert head["resumable"] and head["run_file"] == second
        c.resume()  # continues the second pass's file; no new planning
        status = wait_idle(c, "the resumed second pass to end")
        assert status["queue"] == []
        hist = c.history()
    assert [h["outcome"] for h in hist] == ["interrupted", "finished"]
    assert hist[-1]["run_file"] == second
    check_two_passes(second, N_SECOND)  # 0 lost, 0 duplicated
    runs = sorted(Path(second).parent.glob("*.h5"))
    assert len(runs) == 2  # no third run was planned
