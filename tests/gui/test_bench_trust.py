"""What the bench dock shows is the bench's state, and no input changes a set-point by
accident: the wheel, the set-point fields, the run's read-backs, stale messages, the
layout at the default size."""

from __future__ import annotations

import pytest
from PySide6.QtCore import QPoint, QPointF, Qt
from PySide6.QtGui import QWheelEvent
from PySide6.QtWidgets import QApplication, QScrollArea

from gui.model.session import SetSetting
from hw_mocks import registry
from tests.gui.conftest import connect
from tests.gui.test_bench_panel import _home, _state
from tests.gui.test_run_control import start, wait_end


def _connect(qtbot, window) -> None:
    """Connect, and let the new panels be shown and laid out (posted events)."""
    connect(qtbot, window)
    for _ in range(3):
        QApplication.processEvents()


def _wheel(widget, notches: int = -3) -> None:
    """Turn the wheel over ``widget`` (down: negative), as the mouse would."""
    centre = QPointF(widget.width() / 2, widget.height() / 2)
    event = QWheelEvent(centre, QPointF(widget.mapToGlobal(centre.toPoint())), QPoint(0, 0),
                        QPoint(0, 120 * notches), Qt.NoButton, Qt.NoModifier,
                        Qt.ScrollPhase.NoScrollPhase, False)
    QApplication.sendEvent(widget, event)


def test_the_wheel_changes_no_unfocused_field(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file())
    _connect(qtbot, w)
    det = w.bench_panel.panels["detector_theta"]
    det.target.setValue(200.0)
    det.step.setValue(2.0)
    qtbot.waitUntil(lambda: det.new_velocity.value() == 20.0, timeout=60000)
    chooser = w.bench_panel.chooser
    chosen = chooser.currentIndex()
    for box in (det.target, det.step, det.new_velocity, chooser, w.camera.exposure):
        assert not box.hasFocus()
        _wheel(box)
        assert box.focusPolicy() != Qt.WheelFocus  # a wheel turn gives no focus either
    assert det.target.value() == 200.0
    assert det.step.value() == 2.0
    assert det.new_velocity.value() == 20.0
    assert chooser.currentIndex() == chosen
    # the field the operator is editing still takes the wheel
    w.activateWindow()
    qtbot.waitUntil(w.isActiveWindow, timeout=60000)
    det.target.setFocus()
    qtbot.waitUntil(det.target.hasFocus, timeout=60000)
    _wheel(det.target, -3)
    assert det.target.value() == 197.0


def test_set_point_fields_show_the_devices_settings(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file())
    _connect(qtbot, w)
    det = w.bench_panel.panels["detector_theta"]
    pm = w.bench_panel.panels["power_meter"]
    # at connect: the devices' values, not the fields' defaults (1 deg/s, 633 nm)
    qtbot.waitUntil(lambda: det.new_velocity.value() == 20.0, timeout=60000)
    w.session.submit(SetSetting("power_meter", "wavelength_nm", 550.0))
    w.session.submit(SetSetting("detector_theta", "velocity", 10.0))
    qtbot.waitUntil(lambda: pm.new_wavelength.value() == 550.0, timeout=60000)
    qtbot.waitUntil(lambda: det.new_velocity.value() == 10.0, timeout=60000)
    # an edit is pending (not overwritten by the polls) until its Set has a result
    det.new_velocity.setValue(5.0)
    assert det.velocity_field.pending
    w.session.submit(SetSetting("detector_theta", "acceleration", 50.0))  # new info read
    assert w.session.wait_idle()
    qtbot.waitUntil(lambda: det.velocity.text() == "10 deg/s", timeout=60000)
    assert det.new_velocity.value() == 5.0
    det.set_velocity.click()
    qtbot.waitUntil(lambda: _state(w, "detector_theta").info.get("velocity") == 5.0,
                    timeout=60000)
    qtbot.waitUntil(lambda: not det.velocity_field.pending, timeout=60000)
    assert det.new_velocity.value() == 5.0
    # a refused wavelength goes back to the meter's
    pm.new_wavelength.setValue(24000.0)
    pm.set_wavelength.click()
    qtbot.waitUntil(lambda: pm.outcome.text() != "", timeout=60000)
    qtbot.waitUntil(lambda: pm.new_wavelength.value() == 550.0, timeout=60000)


def test_the_bench_dock_follows_the_run(qtbot, make_window, fast_bench_file, tmp_path):
    """On an un-homed bench the engine homes the axes: the dock says so, its positions are
    the engine's read-backs, and the log tells of the homes."""
    w = make_window(fast_bench_file())
    _connect(qtbot, w)
    det = w.bench_panel.panels["detector_theta"]
    assert not _state(w, "detector_theta").value("homed")
    before = _state(w, "detector_theta").value("position")
    run = start(qtbot, w, tmp_path)
    qtbot.waitUntil(lambda: run.live.n_received >= 3, timeout=60000)
    w.session.pause_run()
    qtbot.waitUntil(lambda: w.run_control.pause_state is not None, timeout=60000)
    stage = registry.get("simsmc", "detector_theta").stage.physical_position()
    assert abs(stage - before) > 1.0  # the run moved it
    qtbot.waitUntil(lambda: _state(w, "detector_theta").value("position")
                    == pytest.approx(stage, abs=0.01), timeout=60000)
    qtbot.waitUntil(lambda: det.position.text() == "{:.3f} deg".format(
        _state(w, "detector_theta").value("position")), timeout=60000)
    assert "not homed" not in det.status.text() and "homed" in det.status.text()
    log = w.log_dock.book.as_text()
    assert "engine/detector_theta: homed by the run" in log
    assert "engine/sample_theta: homed by the run" in log
    # a device the run does not read shows how old its state is
    z = w.bench_panel.panels["camera_z"]
    qtbot.waitUntil(lambda: z.age.text().startswith("read "), timeout=60000)
    assert det.age.text() == "" or det.age.text().startswith("read ")
    w.session.abort_run()
    wait_end(qtbot, w)
    qtbot.waitUntil(lambda: z.age.text() == "", timeout=60000)  # polled again


def test_messages_clear_when_they_stop_applying(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file())
    _connect(qtbot, w)
    bp = w.bench_panel
    det = bp.panels["detector_theta"]
    clock = registry.get("simsmc", "detector_theta").clock
    # Emulated time stands still while the message is looked for: on a slow machine the
    # home (or move) would otherwise end before the GUI shows that it is under way.
    with clock.held():
        det.home.click()
        qtbot.waitUntil(lambda: "homing" in bp.message.text(), timeout=60000)
    qtbot.waitUntil(lambda: bp.message.text() == "", timeout=60000)
    assert _state(w, "detector_theta").value("homed")
    _home(qtbot, w, "sample_theta")
    det.target.setValue(40.0)
    with clock.held():
        det.go.click()
        qtbot.waitUntil(lambda: "moving" in bp.message.text(), timeout=60000)
    qtbot.waitUntil(lambda: bp.message.text() == "", timeout=60000)
    # the detector in the beam: light on is refused, until the detector moves away
    det.target.setValue(3.0)
    source = bp.panels["source"]
    det.go.click()
    qtbot.waitUntil(lambda: _state(w, "detector_theta").value("position")
                    == pytest.approx(3.0, abs=0.01) and bp.message.text() == "",
                    timeout=60000)
    source.on.click()
    qtbot.waitUntil(lambda: "light on refused" in source.outcome.text(), timeout=60000)
    assert "light on refused" in bp.message.text()
    det.target.setValue(60.0)
    det.go.click()
    qtbot.waitUntil(lambda: source.outcome.text() == "" and "refused" not in
                    bp.message.text(), timeout=60000)


def test_a_message_does_not_move_the_panels(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file())
    _connect(qtbot, w)
    bp = w.bench_panel
    det = bp.panels["detector_theta"]

    def y(widget) -> int:
        return widget.mapTo(bp, QPoint(0, 0)).y()

    target_at, z_at = y(det.target), y(bp.panels["camera_z"])
    det.step.setValue(5.0)
    det.plus.click()  # not homed: refused, a message under the panel and in the dock
    qtbot.waitUntil(lambda: det.outcome.isVisible() and bp.message.text() != "",
                    timeout=60000)
    QApplication.processEvents()
    assert (y(det.target), y(bp.panels["camera_z"])) == (target_at, z_at)
    bp.on_run(object())  # the notice that a run owns the bench
    QApplication.processEvents()
    assert bp.owner.text() != ""
    assert (y(det.target), y(bp.panels["camera_z"])) == (target_at, z_at)
    bp.on_run(None)


def _buttons_inside(panel, viewport) -> bool:
    for button in (panel.stop, panel.go, panel.set_velocity, panel.home, panel.plus):
        right = button.mapTo(viewport, QPoint(button.width() - 1, 0)).x()
        if right >= viewport.width() or button.height() < button.minimumSizeHint().height():
            return False  # cut off on the right, or squeezed
    return True


def test_the_default_layout_shows_every_axis_button(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file())
    assert (w.width(), w.height()) == (1500, 950)
    _connect(qtbot, w)
    scroll = w.bench_panel.findChild(QScrollArea)
    axes = [p for r, p in w.bench_panel.panels.items() if hasattr(p, "set_velocity")]
    assert len(axes) == 3

    def all_shown() -> bool:
        QApplication.processEvents()
        return (scroll.widget().minimumSizeHint().width() <= scroll.viewport().width()
                and not scroll.horizontalScrollBar().isVisible()
                and all(_buttons_inside(p, scroll.viewport()) for p in axes))

    qtbot.waitUntil(all_shown, timeout=60000)
    w.docks["bench"].setFloating(True)  # the operator moved the dock out, then resets
    w.reset_layout()
    qtbot.waitUntil(all_shown, timeout=60000)
