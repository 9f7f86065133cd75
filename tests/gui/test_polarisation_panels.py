"""The polarisation devices in the GUI, found by device kind: four ELL14 mounts on one
Elliptec bus are motion axes (their panels move the real driver, and the virtual world's
mount with it), and the PEM200 has the modulator panel, whose amplitude and wavelength
are set through the session's device-command path and read back from the controller."""

from __future__ import annotations

import pytest

from gui.model.session import Home, MoveTo
from gui.qt.panels import AxisPanel, ModulatorPanel
from hw_mocks.sim.world import find_world
from tests.gui.conftest import connect
from tests.gui.helpers import fast_profile

PEM = """
[devices.pem]
driver = "pem200"
url = "simpem://pem?frequency=50000"
options = { nm_per_drive = 1230.0 }
settings = { wavelength_nm = 632.8, retardation_waves = 0.383 }
"""

MOUNTS = ("psg_polariser", "psg_retarder", "psa_retarder", "psa_polariser")


@pytest.fixture
def bench_file(tmp_path):
    path = tmp_path / "ell14-pem.toml"
    path.write_text(fast_profile("sim-polarimetric-ell14").source_text + PEM, encoding="utf-8")
    return str(path)


def test_elliptec_mounts_are_axes_and_the_pem_has_its_panel(qtbot, make_window, bench_file):
    w = make_window(bench_file)
    connect(qtbot, w, timeout=60000)
    panels, session = w.bench_panel.panels, w.session
    assert all(isinstance(panels[role], AxisPanel) for role in MOUNTS)
    pem = panels["pem"]
    assert isinstance(pem, ModulatorPanel)
    # the mount at address 2 of the bus: homed, moved, and the world's retarder with it
    session.submit(Home("psa_retarder"))
    qtbot.waitUntil(lambda: session.states()["psa_retarder"].value("homed"), timeout=60000)
    session.submit(MoveTo("psa_retarder", 112.5))
    qtbot.waitUntil(lambda: panels["psa_retarder"].position.text().startswith("112.5"),
                    timeout=60000)
    world = find_world("sim-polarimetric-ell14")
    assert world is not None
    assert world.position("psa_retarder") == pytest.approx(112.5, abs=0.01)
    assert world.position("psg_retarder") == pytest.approx(0.0, abs=0.01)
    # the modulator: its settings read back, the frequency the head's resonance
    qtbot.waitUntil(lambda: "0.3830 waves at 632.8 nm" in pem.amplitude.text(), timeout=60000)
    assert pem.frequency.text() == "50 kHz"
    pem.new_amplitude.setValue(0.5)
    pem.set_amplitude.click()
    qtbot.waitUntil(lambda: pem.amplitude.text().startswith("0.5000 waves"), timeout=60000)
    assert session._bench.devices["pem"].retardation_waves == pytest.approx(0.5, abs=1e-4)
    assert "(3.142 rad)" in pem.amplitude.text()
    # the same drive at a longer wavelength is fewer waves: 0.5 × 632.8 / 700
    pem.new_wavelength.setValue(700.0)
    pem.set_wavelength.click()
    qtbot.waitUntil(lambda: "at 700 nm" in pem.amplitude.text(), timeout=60000)
    assert session.states()["pem"].values["retardation_waves"] == pytest.approx(
        0.5 * 632.8 / 700.0, abs=1e-3)
    # a refused amplitude (beyond the drive's range) is said under the PEM's panel
    pem.new_amplitude.setValue(4.0)
    pem.set_amplitude.click()
    qtbot.waitUntil(lambda: pem.outcome.isVisible(), timeout=60000)
    assert session._bench.devices["pem"].retardation_waves == pytest.approx(
        0.5 * 632.8 / 700.0, abs=1e-3)
