"""``scatterlab manual …`` against a real server process: home, jog, move, light and Stop
all go through the server's guard; a refusal is one line on stderr and nothing moves."""

from __future__ import annotations

import pytest

from instrument.cli import main
from instrument.client import BenchClient

ARM = ("sample_theta", "detector_theta")


def wait_still(url: str, roles=ARM) -> dict:
    """The first device state in which ``roles`` are homed and standing still (the
    server publishes one at least every 2 s while idle)."""
    with BenchClient(url) as c:
        for msg in c.events():
            if msg.type != "devices":
                continue
            axes = msg.data["axes"]
            if all(r in axes and axes[r]["homed"] and not axes[r]["moving"] for r in roles):
                return axes
    raise AssertionError("the event stream ended")


@pytest.fixture
def server_url(bench_file, start_server, monkeypatch) -> str:
    """A server process on the fast sim bench, named in $SCATTERLAB_SERVER (no key)."""
    server = start_server(bench_file())
    monkeypatch.setenv("SCATTERLAB_SERVER", server.url)
    monkeypatch.delenv("SCATTERLAB_KEY", raising=False)
    return server.url


def refused_line(capsys) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert not captured.out
    return lines[0]


@pytest.mark.timeout(600)
def test_manual_commands_from_the_command_line_pass_the_guard(server_url, capsys):
    for role in ARM:
        assert main(["manual", "home", role]) == 0
        assert f"{role}: homing" in capsys.readouterr().out
    before = wait_still(server_url)
    # the detector at 0 faces the source: light on is refused, with the guard's reason
    assert main(["manual", "light", "on"]) == 2
    line = refused_line(capsys)
    assert line.startswith("error: light on refused:") and "beam" in line
    assert "(HTTP 422)" in line
    # beyond the sample stage's travel: refused, the axis named, nothing moved
    assert main(["manual", "move", "sample_theta=89"]) == 2
    line = refused_line(capsys)
    assert "refused" in line and "sample_theta" in line and "(HTTP 422)" in line
    assert wait_still(server_url) == before
    # allowed: a jog, a move of two axes, the light once the detector is out of the beam
    assert main(["manual", "jog", "detector_theta", "40"]) == 0
    assert "moving" in capsys.readouterr().out
    axes = wait_still(server_url)
    assert axes["detector_theta"]["position"] == pytest.approx(40.0, abs=1e-3)
    assert main(["manual", "move", "sample_theta=10", "detector_theta=50"]) == 0
    axes = wait_still(server_url)
    assert axes["sample_theta"]["position"] == pytest.approx(10.0, abs=1e-3)
    assert axes["detector_theta"]["position"] == pytest.approx(50.0, abs=1e-3)
    assert main(["manual", "light", "on"]) == 0
    assert "light on" in capsys.readouterr().out
    assert main(["manual", "light", "off"]) == 0
    assert main(["manual", "stop-all"]) == 0
    assert "all axes stopped" in capsys.readouterr().out


def test_manual_move_targets_are_role_equals_value(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["manual", "move", "sample_theta"])
    assert exc.value.code == 2
    assert "give ROLE=VALUE" in capsys.readouterr().err


@pytest.mark.timeout(600)
def test_manual_set_changes_a_device_and_waits_for_its_outcome(server_url, capsys):
    assert main(["manual", "set", "filter_wheel", "position=4", "speed=normal"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("filter_wheel: applying position=4, speed=normal (request ")
    assert out[1] == "filter_wheel: position=4, speed=normal done"
    with BenchClient(server_url) as c:
        for msg in c.events():  # the sampler reads the wheel afresh after the change
            states = msg.data.get("states") or {} if msg.type == "devices" else {}
            if states.get("filter_wheel", {}).get("values", {}).get("position") == 4:
                assert states["filter_wheel"]["values"]["speed"] == "normal"
                break
    # refused before anything is sent: one line naming the field, exit 2
    assert main(["manual", "set", "power_meter", "wavelength_nm=5"]) == 2
    line = refused_line(capsys)
    assert line.startswith("error: power_meter.wavelength_nm: 5 nm is outside")
    assert "(HTTP 422)" in line
    # not FIELD=VALUE: the parser says how
    with pytest.raises(SystemExit):
        main(["manual", "set", "filter_wheel", "position"])
    assert "give FIELD=VALUE" in capsys.readouterr().err
