"""The CLI as a client of a real server process: queue, status, watch, pause, abort,
resume without a run; serve keys and audit; serve's refusal to listen beyond loopback."""

from __future__ import annotations

import io
import re
import threading

import pytest

from instrument.cli import main
from instrument.cli.watch import watch
from instrument.client import BenchClient
from tests.instrument.server.helpers import plan_text
from tests.waiting import wait_for


@pytest.fixture
def plans(tmp_path):
    paths = []
    for name in ("alpha", "beta"):
        p = tmp_path / f"{name}.toml"
        p.write_text(plan_text(name, [-60.0, 40.0]), encoding="utf-8")
        paths.append(str(p))
    return paths


@pytest.mark.timeout(900)
def test_queue_status_and_watch_through_the_server(bench_file, start_server, plans,
                                                   monkeypatch, capsys):
    server = start_server(bench_file())
    monkeypatch.setenv("SCATTERLAB_SERVER", server.url)
    monkeypatch.delenv("SCATTERLAB_KEY", raising=False)
    assert main(["queue", "add", *plans, "--stop"]) == 0
    out = capsys.readouterr().out
    assert "added item 1: alpha" in out and "added item 3: stop marker" in out
    assert main(["queue", "move", "2", "0"]) == 0
    assert main(["queue", "list"]) == 0
    out = capsys.readouterr().out
    assert out.index("beta") < out.index("alpha") < out.index("stop marker")
    assert main(["pause"]) == 2
    assert "no run is in progress" in capsys.readouterr().err
    # `scatterlab watch`'s loop, started before the queue so that it sees every run
    seen = io.StringIO()
    client = BenchClient(server.url)
    watcher = threading.Thread(target=watch, args=(client,), kwargs={"out": seen},
                               daemon=True)
    watcher.start()
    wait_for(lambda: "watching bench 'sim'" in seen.getvalue(), what="the watcher")
    assert main(["queue", "start"]) == 0
    wait_for(lambda: "stop marker: stop marker" in seen.getvalue(), what="the stop marker")
    assert main(["watch", "--until-idle"]) == 0  # the queue stopped: it returns at once
    out = seen.getvalue()
    assert out.count("run finished: 2/2 points") == 2
    assert out.index("item #2 beta: finished") < out.index("item #1 alpha: finished")
    assert main(["status"]) == 0
    out = capsys.readouterr().out
    assert "run: none" in out and "queue stopped: 0 item(s)" in out
    assert main(["queue", "history"]) == 0
    out = capsys.readouterr().out
    assert [w for w in out.split() if w in ("alpha", "beta")] == ["beta", "alpha"]
    assert main(["resume"]) == 2
    assert "nothing to resume" in capsys.readouterr().err
    server.stop()
    watcher.join(60)
    assert "the server closed the event stream" in seen.getvalue()
    client.close()


def test_keys_and_the_audit_log_from_the_command_line(bench_file, start_server, tmp_path,
                                                      monkeypatch, capsys, plans):
    runs = tmp_path / "runs"
    assert main(["serve", "keys", "add", "--role", "operator", "--name", "ann",
                 "--runs", str(runs)]) == 0
    token = re.search(r"sl_\S+", capsys.readouterr().out).group(0)
    assert token.startswith("sl_")
    assert main(["serve", "--runs", str(runs), "keys", "add", "--role", "observer",
                 "--name", "obs", "--expires", "30"]) == 0
    obs = re.search(r"sl_\S+", capsys.readouterr().out).group(0)
    server = start_server(bench_file(), runs)
    monkeypatch.setenv("SCATTERLAB_SERVER", server.url)
    monkeypatch.setenv("SCATTERLAB_KEY", obs)
    assert main(["queue", "add", plans[0]]) == 2
    assert "observer keys may not do this" in capsys.readouterr().err
    assert main(["queue", "add", "--propose", plans[0]]) == 0
    monkeypatch.setenv("SCATTERLAB_KEY", token)
    assert main(["control", "take", "--timeout", "600"]) == 0
    assert "control held by ann until" in capsys.readouterr().out
    assert main(["queue", "approve", "1"]) == 0
    monkeypatch.setenv("SCATTERLAB_KEY", obs)
    assert main(["control", "show"]) == 0
    assert "control held by ann" in capsys.readouterr().out
    monkeypatch.setenv("SCATTERLAB_KEY", token)
    assert main(["control", "release"]) == 0
    monkeypatch.setenv("SCATTERLAB_KEY", "sl_wrong")
    assert main(["status"]) == 2
    assert "HTTP 401" in capsys.readouterr().err
    assert main(["serve", "keys", "list", "--runs", str(runs)]) == 0
    out = capsys.readouterr().out
    assert "operator  valid" in out and "observer  valid" in out
    assert main(["serve", "keys", "revoke", "1", "--runs", str(runs)]) == 0
    assert main(["serve", "audit", "--runs", str(runs)]) == 0
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if "/api/v1/queue" in ln]
    assert "obs (observer)" in lines[0] and " 403 " in lines[0]
    assert "obs (observer)" in lines[1] and " 200 " in lines[1] and "proposed" in lines[1]
    assert "ann (operator)" in lines[2] and "approved item 1" in lines[2]
    assert any("/api/v1/control/take" in ln and "ann (operator)" in ln
               for ln in out.splitlines())


def test_serve_refuses_a_lab_address_without_tls_and_keys(tmp_path, capsys):
    assert main(["serve", "--listen", "0.0.0.0:0", "--runs", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "not loopback" in err and "--tls-cert" in err and "keys add" in err


def test_client_commands_without_a_server_say_how_to_name_one(monkeypatch, capsys):
    monkeypatch.delenv("SCATTERLAB_SERVER", raising=False)
    assert main(["status"]) == 3
    assert "--server URL" in capsys.readouterr().err
    assert main(["resume"]) == 2
    assert "give the run to resume" in capsys.readouterr().out
