"""The bench panel on the simulated bench: launch, connect, home, jog, refusals, Stop all."""

from __future__ import annotations

import subprocess
import sys

import pytest
from PySide6.QtCore import Qt

from hw_mocks import registry
from tests.gui.conftest import connect, mouse_click


def _stage(scheme: str, role: str) -> float:
    return registry.get(scheme, role).stage.physical_position()


def _state(window, role):
    return window.session.states()[role]


def _home(qtbot, window, *roles):
    for role in roles:
        window.bench_panel.panels[role].home.click()
    qtbot.waitUntil(lambda: all(_state(window, r).value("homed")
                                and not _state(window, r).value("moving") for r in roles),
                    timeout=60000)


def test_launch_connect_home_jog(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file())
    assert w.stop_button.isVisible()
    connect(qtbot, w)
    panels = w.bench_panel.panels
    assert set(panels) == {"sample_theta", "detector_theta", "camera_z", "camera",
                           "power_meter", "source", "filter_wheel"}
    assert "K10CR1" in panels["sample_theta"].identity.text()
    assert "PM100USB" in panels["power_meter"].identity.text()
    _home(qtbot, w, "sample_theta", "detector_theta")
    axis = panels["detector_theta"]
    assert "homed" in axis.status.text()
    axis.step.setValue(25.0)
    mouse_click(qtbot, axis.plus)
    qtbot.waitUntil(lambda: axis.position.text() == "25.000 deg", timeout=60000)
    assert _stage("simsmc", "detector_theta") == pytest.approx(25.0, abs=0.005)
    assert axis.velocity.text() == "20 deg/s"
    mouse_click(qtbot, axis.minus)
    qtbot.waitUntil(lambda: axis.position.text() == "0.000 deg", timeout=60000)
    sample = panels["sample_theta"]
    sample.target.setValue(-12.5)
    mouse_click(qtbot, sample.go)
    qtbot.waitUntil(lambda: sample.position.text() == "-12.500 deg", timeout=60000)
    assert _stage("simapt", "sample_theta") == pytest.approx(-12.5, abs=0.01)
    # the power meter's reading comes with its wavelength
    pm = panels["power_meter"]
    qtbot.waitUntil(lambda: pm.wavelength.text() == "633 nm", timeout=60000)
    assert pm.reading.text().endswith("W")


def test_refused_jogs_say_why_and_nothing_moves(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    _home(qtbot, w, "sample_theta", "detector_theta")
    det = w.bench_panel.panels["detector_theta"]
    det.target.setValue(30.0)
    det.go.click()
    qtbot.waitUntil(lambda: det.position.text() == "30.000 deg", timeout=60000)
    # outside the soft limits [-85, 85]
    sample = w.bench_panel.panels["sample_theta"]
    sample.step.setValue(100.0)
    sample.plus.click()
    qtbot.waitUntil(lambda: "refused" in w.bench_panel.message.text(), timeout=60000)
    assert "outside the soft limits [-85, 85]" in w.bench_panel.message.text()
    # into the incident beam with the light on
    w.bench_panel.panels["source"].on.click()
    qtbot.waitUntil(lambda: _state(w, "source").value("on") is True, timeout=60000)
    det.target.setValue(3.0)
    det.go.click()
    qtbot.waitUntil(lambda: "incident beam" in w.bench_panel.message.text(), timeout=60000)
    assert w.session.wait_idle(60)
    assert _stage("simapt", "sample_theta") == pytest.approx(0.0, abs=0.01)
    assert _stage("simsmc", "detector_theta") == pytest.approx(30.0, abs=0.005)
    w.bench_panel.panels["source"].off.click()
    qtbot.waitUntil(lambda: _state(w, "source").value("on") is False, timeout=60000)


def test_stop_all_during_a_move(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file(speed=20))
    connect(qtbot, w)
    _home(qtbot, w, "detector_theta")
    det = w.bench_panel.panels["detector_theta"]
    det.new_velocity.setValue(1.0)  # 150° take 150 s of emulated time
    det.set_velocity.click()
    qtbot.waitUntil(lambda: det.velocity.text() == "1 deg/s", timeout=60000)
    det.target.setValue(150.0)
    emulator = registry.get("simsmc", "detector_theta")
    # Emulated time stands still from Go to the stop reaching the controller, but for 20 s
    # let pass by hand: the axis is stopped under way however slowly the machine runs.
    with emulator.clock.held():
        det.go.click()
        qtbot.waitUntil(lambda: _state(w, "detector_theta").value("moving"), timeout=60000)
        emulator.clock.advance(20.0)
        w.activateWindow()
        qtbot.waitUntil(w.isActiveWindow, timeout=60000)
        sent = len(emulator.received_log)
        qtbot.keyClick(w.bench_panel.panels["sample_theta"].step, Qt.Key_Escape)  # Stop all
        qtbot.waitUntil(lambda: b"ST" in bytes(emulator.received_log[sent:]), timeout=60000)
    qtbot.waitUntil(lambda: not _state(w, "detector_theta").value("moving"), timeout=60000)
    stopped = _stage("simsmc", "detector_theta")
    assert 0.0 < stopped < 149.0
    assert "all axes stopped" in w.bench_panel.message.text()
    qtbot.waitUntil(lambda: abs(_state(w, "detector_theta").value("position") - stopped)
                    < 0.01, timeout=60000)


def test_settings_remember_the_bench_and_the_layout(qtbot, make_window, settings,
                                                    fast_bench_file):
    path = fast_bench_file()
    w = make_window(path)
    w.docks["goniometer"].hide()  # the operator closed a dock
    w.save_settings()
    assert settings.value("bench") == path
    assert settings.value("geometry") is not None
    w2 = make_window(None)
    assert w2.bench_panel.chosen == path
    assert w2.docks["goniometer"].isHidden() and not w2.docks["bench"].isHidden()
    w2.reset_layout()
    assert not w2.docks["goniometer"].isHidden()


def test_the_cli_starts_no_qt_for_other_commands():
    code = ("import sys; from instrument.cli import build_parser; build_parser(); "
            "import instrument.cli.gui; "
            "assert 'PySide6' not in sys.modules and 'pyqtgraph' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
    out = subprocess.run([sys.executable, "-m", "instrument.cli", "gui", "--help"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "--bench" in out.stdout and "--out" in out.stdout


def test_the_type_i_bench_shows_its_arms_and_refuses_a_jog_into_the_other_arm(
        qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file("sim-type-i"))
    connect(qtbot, w)
    panels = w.bench_panel.panels
    arms = ("source_arc", "source_azimuth", "detector_arc", "detector_azimuth")
    assert set(arms) <= set(panels)
    _home(qtbot, w, *arms)
    # homed, the arcs stand 60° either side of the pole: the source head at θ 60°, φ 0°;
    # the detector arc at 120° (its offset 60°) would put its head on the source's
    det = panels["detector_arc"]
    det.target.setValue(120.0)
    det.go.click()
    qtbot.waitUntil(lambda: "refused" in w.bench_panel.message.text(), timeout=60000)
    assert "arms collide" in w.bench_panel.message.text()
    assert w.session.wait_idle(60)
    assert _stage("simsmc", "detector_arc") == pytest.approx(0.0, abs=0.005)
    # turned aside first, the same arc is allowed
    panels["detector_azimuth"].target.setValue(40.0)
    panels["detector_azimuth"].go.click()
    qtbot.waitUntil(lambda: panels["detector_azimuth"].position.text() == "40.000 deg",
                    timeout=60000)
    det.go.click()
    qtbot.waitUntil(lambda: det.position.text() == "120.000 deg", timeout=60000)
