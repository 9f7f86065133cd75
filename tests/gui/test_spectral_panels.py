"""The lock-in, shutter and filter-wheel panels on the emulated spectral bench: found by
device kind (no driver names), their readings from the device worker, their commands
reaching the real drivers (SR830, SC10, FW102C over their emulators), and a refusal or a
driver's error shown in the panel of the device it concerns."""

from __future__ import annotations

import pytest

from drivers.base import LightSource, Shutter
from gui.model.session import Home, SetSetting
from gui.qt.panels import FilterWheelPanel, LockInPanel, ShutterPanel
from instrument.bench.device_state import kind_of
from tests.gui.conftest import connect


def test_the_spectral_bench_panels_read_and_command_their_devices(qtbot, make_window,
                                                                  fast_bench_file):
    w = make_window(fast_bench_file("sim-spectral"))
    connect(qtbot, w, timeout=60000)
    panels = w.bench_panel.panels
    lockin, shutter, wheel = panels["lockin"], panels["shutter"], panels["filter_wheel"]
    assert isinstance(lockin, LockInPanel) and isinstance(shutter, ShutterPanel)
    assert isinstance(wheel, FilterWheelPanel)
    session = w.session
    # a shutter is a light source too: the most derived kind wins
    sc10 = session._bench.devices["shutter"]
    assert isinstance(sc10, Shutter) and isinstance(sc10, LightSource)
    assert kind_of(sc10).name == "shutter"
    # the wheel: its slots with their bands, its speed, then a move through the driver
    qtbot.waitUntil(lambda: wheel.slot.count() == 6, timeout=60000)
    assert wheel.slot.itemText(1) == "slot 2: 550 nm, FWHM 10 nm"
    assert wheel.count.text() == "6" and wheel.speed.count() == 2
    wheel.slot.setCurrentIndex(2)
    wheel.go.click()
    qtbot.waitUntil(lambda: wheel.position.text() == "slot 3: 650 nm, FWHM 10 nm",
                    timeout=60000)
    assert session._bench.devices["filter_wheel"].position == 3
    # the shutter: open, then closed again
    shutter.open.click()
    qtbot.waitUntil(lambda: "OPEN" in shutter.status.text(), timeout=60000)
    assert sc10.shutter_state.value == "open"
    shutter.close_button.click()
    qtbot.waitUntil(lambda: "closed" in shutter.status.text(), timeout=60000)
    # the lock-in: its range table from the instrument, a range set through the driver
    qtbot.waitUntil(lambda: lockin.sensitivity.count() == 27, timeout=60000)
    (k,) = [i for i in range(lockin.sensitivity.count())
            if lockin.sensitivity.itemData(i) == pytest.approx(1e-3)]
    lockin.sensitivity.setCurrentIndex(k)
    lockin.sensitivity.activated.emit(k)
    qtbot.waitUntil(lambda: session.states()["lockin"].values.get("sensitivity_v")
                    == pytest.approx(1e-3), timeout=60000)
    assert lockin.reading.text().startswith("R ") and "Hz" in lockin.detail.text()
    assert lockin.reference.currentData() == "external"
    # a value the driver rejects: its words under the lock-in's panel, nothing changed
    session.submit(SetSetting("lockin", "time_constant_s", 1e6))
    qtbot.waitUntil(lambda: lockin.outcome.isVisible(), timeout=60000)
    assert "outside the instrument's" in lockin.outcome.text()
    assert session._bench.devices["lockin"].time_constant_s == pytest.approx(0.03)
    # the smallest range overloads: the badge and what to do
    session.submit(SetSetting("lockin", "sensitivity_v", 2e-9))
    qtbot.waitUntil(lambda: "OVERLOAD" in lockin.status.text(), timeout=60000)
    assert "Auto-range" in lockin.advice.text()


def test_opening_the_shutter_onto_the_detector_is_refused_in_its_panel(qtbot, make_window,
                                                                       fast_bench_file):
    w = make_window(fast_bench_file("sim-spectral"))
    connect(qtbot, w, timeout=60000)
    session, shutter = w.session, w.bench_panel.panels["shutter"]
    session.submit(Home("detector_theta"))
    session.submit(Home("sample_theta"))
    qtbot.waitUntil(lambda: all(session.states()[r].value("homed")
                                and not session.states()[r].value("moving")
                                for r in ("detector_theta", "sample_theta")), timeout=60000)
    shutter.open.click()  # the detector arm at home stands in the incident beam
    qtbot.waitUntil(lambda: shutter.outcome.isVisible(), timeout=60000)
    assert "beam" in shutter.outcome.text()
    assert session._bench.devices["shutter"].shutter_state.value == "closed"
    assert "closed" in shutter.status.text()
