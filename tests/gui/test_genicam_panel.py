"""The emulated Basler camera in the GUI: found by its device kind, its exposure, gain, bit
depth and trigger mode shown as read back and set through the driver, a refused setting
shown in the driver's own words, and its frames in the camera view."""

from __future__ import annotations

import pytest

from drivers.genicam_camera import TriggerMode
from gui.model.session import Action, SetSetting
from gui.qt.panels import GenICamCameraPanel
from instrument.bench.device_state import is_camera_kind, kind_of
from tests.drivers.basler_emulation import require_pylon
from tests.gui.conftest import connect

require_pylon()

T = 60000  # ms: bounds a hang only


def open_panel(qtbot, make_window, fast_bench_file):
    """The main window on sim-basler, connected: (session, the camera's panel, camera)."""
    w = make_window(fast_bench_file("sim-basler"))
    connect(qtbot, w, timeout=T)
    return w.session, w.bench_panel.panels["camera"], w.session._bench.devices["camera"]


def test_the_basler_panel_shows_and_sets_the_cameras_settings(qtbot, make_window,
                                                              fast_bench_file):
    session, panel, cam = open_panel(qtbot, make_window, fast_bench_file)
    assert isinstance(panel, GenICamCameraPanel)
    assert kind_of(cam).name == "genicam_camera" and is_camera_kind("genicam_camera")
    # what the camera offers, from its node map
    qtbot.waitUntil(lambda: panel.bit_depth.count() == 4, timeout=T)
    assert [panel.bit_depth.itemData(k) for k in range(4)] == [8, 10, 12, 16]
    assert panel.bit_depth.currentData() == 12  # sim-basler asks for Mono12
    assert panel.trigger.currentData() == "software"
    assert "hardware (Line1)" in [panel.trigger.itemText(k) for k in range(3)]
    assert "Basler" in panel.identity.text() and "0815-0000" in panel.identity.text()
    # exposure and gain typed in and set: the camera's read-back comes back to the fields
    panel.new_exposure.setValue(1500.4)
    panel.findChild(type(panel.reconnect), "set_exposure_us").click()
    qtbot.waitUntil(lambda: session.states()["camera"].values.get("exposure_us") == 1500.0,
                    timeout=T)
    assert cam.genicam.get("ExposureTime") == 1500.0  # the camera's 1 µs step
    qtbot.waitUntil(lambda: panel.new_exposure.value() == 1500.0, timeout=T)
    panel.new_gain.setValue(6.0)
    panel.findChild(type(panel.reconnect), "set_gain").click()
    qtbot.waitUntil(lambda: abs(cam.genicam.get("Gain") - 6.0) < 0.01, timeout=T)
    # bit depth and trigger mode chosen from the lists
    k = panel.bit_depth.findData(16)
    panel.bit_depth.setCurrentIndex(k)
    panel.bit_depth.activated.emit(k)
    qtbot.waitUntil(lambda: session.states()["camera"].values.get("bit_depth") == 16,
                    timeout=T)
    assert cam.genicam.get("PixelFormat") == "Mono16"
    # the panel shows the state once the GUI thread has it (the session's dict is ahead)
    qtbot.waitUntil(lambda: "16-bit" in panel.summary.text(), timeout=T)
    k = panel.trigger.findData("hardware")
    panel.trigger.setCurrentIndex(k)
    panel.trigger.activated.emit(k)
    qtbot.waitUntil(lambda: cam.trigger_mode is TriggerMode.HARDWARE, timeout=T)
    assert cam.genicam.get("TriggerSource") == "Line1"
    session.submit(SetSetting("camera", "trigger_mode", "software"))
    qtbot.waitUntil(lambda: panel.trigger.currentData() == "software", timeout=T)
    assert not panel.outcome.isVisible()


def test_a_setting_the_camera_refuses_shows_the_drivers_error(qtbot, make_window,
                                                              fast_bench_file):
    session, panel, cam = open_panel(qtbot, make_window, fast_bench_file)
    before = cam.exposure_us
    panel.new_exposure.setValue(30e6)  # past the node map's 10 s
    panel.findChild(type(panel.reconnect), "set_exposure_us").click()
    qtbot.waitUntil(lambda: panel.outcome.isVisible(), timeout=T)
    with pytest.raises(ValueError) as err:
        cam.exposure_us = 30e6
    assert panel.outcome.text() == str(err.value)  # the driver's own words
    assert "outside" in panel.outcome.text() and "10 s" in panel.outcome.text()
    assert cam.exposure_us == before
    qtbot.waitUntil(lambda: panel.new_exposure.value() == before, timeout=T)
    # a bit depth no mono format has: refused by name, in the camera's panel
    session.submit(Action("camera", "set_bit_depth", (14,)))
    qtbot.waitUntil(lambda: "no mono format of 14 bits" in panel.outcome.text(), timeout=T)
    assert cam.bit_depth == 12



def test_the_camera_view_streams_the_basler_camera(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file("sim-basler"))
    connect(qtbot, w, timeout=T)
    view = w.camera
    qtbot.waitUntil(lambda: view.role == "camera", timeout=T)  # found by its kind's ABC
    view.stream.click()
    qtbot.waitUntil(lambda: view.shown >= 3, timeout=T)
    frame = view.last_frame
    assert frame.data.shape == (1040, 1024) and frame.saturation_dn == 4095  # Mono12
    view.stream.click()
    qtbot.waitUntil(lambda: not w.session.states()["camera"].value("streaming"), timeout=T)
