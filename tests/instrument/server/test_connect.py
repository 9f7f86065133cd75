"""``connect(url)``: the scripting surface (dry_run, run, open_run) against a real server
process on a random loopback port (ADR 0091's companion to 0083). Every wait is on an
event or a message, with a generous limit."""

from __future__ import annotations

import numpy as np
import pytest

from instrument import connect, plans
from instrument.bench.guard import GuardError
from tests.instrument.server.helpers import plan_text

THETA_R = [-60.0, -40.0, 10.0, 40.0, 60.0]  # theta_i = 20: -20 is the beam


def _plan(name: str, theta_r) -> plans.PlanSpec:
    return plans.parse_plan(plan_text(name, list(theta_r)))


@pytest.mark.timeout(900)
def test_connect_dry_runs_runs_and_opens_a_run_on_the_server(bench_file, start_server,
                                                              tmp_path):
    server = start_server(bench_file())
    with connect(server.url, runs_dir=tmp_path / "here") as bench:
        dry = bench.dry_run(_plan("remote", THETA_R))
        assert dry.n_points == len(THETA_R) and dry.estimate.total_s > 0
        # the guard refuses locally, in the same words, before anything is sent
        with pytest.raises(GuardError, match="beam"):
            bench.run(_plan("into the beam", [-20.0]))
        handle = bench.run(_plan("remote", THETA_R), block=False)
        kinds = [m.type for m in handle.events(timeout=300)]
        assert handle.wait(60) == "finished" and handle.outcome == "finished"
        assert kinds[-1] == "item_finished" and "run_finished" in kinds
        assert handle.progress.n_done == handle.progress.n_total == len(THETA_R)
        run = bench.open_run(handle.path)
        assert run.path.parent == tmp_path / "here"
        table = run.to_pandas(reduced=False)
        assert len(table) == len(THETA_R)
        assert np.all(np.isfinite(table["power_w"]))
        # blocking, as on the bench PC
        again = bench.run(_plan("blocking", THETA_R[:2]), progress=False, timeout=300)
        assert again.status == "finished"
        with pytest.raises(TypeError, match="adaptive"):
            bench.run(plans.sharp_lobe(30))


@pytest.mark.timeout(900)
def test_a_remote_run_pauses_resumes_and_aborts(bench_file, start_server):
    # Stages at real speed: each point takes seconds of emulated motion however fast the
    # machine is, so the run is still going when the pause arrives.
    server = start_server(bench_file(speed=1))
    theta_r = [float(x) for x in np.arange(-70.0, 71.0, 7.0) if abs(x + 20.0) > 7.0]
    with connect(server.url) as bench:
        handle = bench.run(_plan("long", theta_r), block=False)
        events = handle.events(timeout=300)
        for msg in events:
            if msg.type == "points":
                handle.pause()
                break
        assert next(m for m in events if m.type == "paused").type == "paused"
        assert handle.status == "paused"
        handle.resume()
        assert next(m for m in events if m.type == "resumed")
        handle.abort()
        end = next(m for m in events if m.type == "run_finished")
        assert end.data["status"] == "aborted"
        assert handle.wait(120) in ("aborted", "interrupted", "paused", "failed")
        assert 0 < handle.progress.n_done < len(theta_r)
