"""The lock-in, shutter and filter-wheel panels on the emulated spectral bench: found by
device kind (no driver names), their readings from the device worker, and their commands
reaching the real drivers (SR830, SC10, FW102C over their emulators)."""

from __future__ import annotations

import pytest

from drivers.base import FilterWheel, LightSource, LockIn, Shutter
from gui.model.devices import kind_of
from gui.qt.panels import FilterWheelPanel, LockInPanel, ShutterPanel
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
    assert isinstance(session._bench.devices["lockin"], LockIn)
    assert isinstance(session._bench.devices["filter_wheel"], FilterWheel)
    # a shutter is a light source too: the most derived kind wins
    sc10 = session._bench.devices["shutter"]
    assert isinstance(sc10, Shutter) and isinstance(sc10, LightSource)
    assert kind_of(sc10).name == "shutter"
    # the wheel: its slots with their bands, then a move through the driver
    qtbot.waitUntil(lambda: wheel.slot.count() == 6, timeout=10000)
    assert wheel.slot.itemText(1) == "slot 2: 550 nm, FWHM 10 nm"
    wheel.slot.setCurrentIndex(2)
    wheel.go.click()
    qtbot.waitUntil(lambda: session.states()["filter_wheel"].values.get("position") == 3,
                    timeout=20000)
    qtbot.waitUntil(lambda: wheel.position.text() == "slot 3: 650 nm, FWHM 10 nm",
                    timeout=5000)
    # the shutter: open, then closed again
    shutter.open.click()
    qtbot.waitUntil(lambda: session.states()["shutter"].values.get("state") == "open",
                    timeout=10000)
    assert "OPEN" in shutter.status.text()
    shutter.close_button.click()
    qtbot.waitUntil(lambda: session.states()["shutter"].values.get("state") == "closed",
                    timeout=10000)
    # the lock-in: its range table from the instrument, a range set through the driver
    qtbot.waitUntil(lambda: lockin.sensitivity.count() == 27, timeout=10000)
    (k,) = [i for i in range(lockin.sensitivity.count())
            if lockin.sensitivity.itemData(i) == pytest.approx(1e-3)]
    lockin.sensitivity.setCurrentIndex(k)
    lockin.sensitivity.activated.emit(k)
    qtbot.waitUntil(lambda: session.states()["lockin"].values.get("sensitivity_v")
                    == pytest.approx(1e-3), timeout=10000)
    assert lockin.reading.text().startswith("R ") and "Hz" in lockin.detail.text()
