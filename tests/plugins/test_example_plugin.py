"""The example plugin (``examples/plugin_driver``, installed into the test environment):
a profile names its driver, a scan runs through it, the power-meter contract holds for
it, over its emulator's URL and over a pseudo-terminal, and the GUI's device model shows
it through the power-meter kind with no change to ``gui/``."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from drivers.errors import ControllerError
from hw_mocks import registry
from hw_mocks.pty_server import serve_url
from instrument.bench.devices import configure_simulation, open_bench, open_device
from instrument.bench.profile import load_profile
from instrument.cli import main
from tests.drivers.power_meter_contract import PowerMeterContract

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "plugin_driver"
BENCH = EXAMPLE / "bench_em1.toml"
PLAN = EXAMPLE / "brdf_em1.toml"


@pytest.fixture
def profile():
    profile = load_profile(BENCH)
    configure_simulation(profile)
    return profile


def test_the_profile_names_the_plugin_driver_and_opens_it_with_its_settings(profile):
    spec = profile.device("power_meter")
    assert (spec.driver, spec.kind) == ("example_meter", "power_meter")
    with open_bench(profile, roles=["power_meter"]) as bench:
        meter = bench.power_meter
        assert type(meter).__name__ == "Em1PowerMeter"
        assert meter.identity.model == "EM-1" and meter.identity.serial == "EM0001"
        assert meter.wavelength_nm == pytest.approx(633.0)
        assert meter.averaging == 4


def test_the_meter_reports_the_controllers_refusals_as_typed_errors(profile):
    with open_device(profile.device("power_meter")) as meter:
        registry.get("simem1", "power_meter").enter_error_state("2")
        with pytest.raises(ControllerError, match="value out of range") as info:
            meter.read_power_w()
        assert info.value.device == "power_meter" and info.value.command == "POW?"
        with pytest.raises(ValueError, match="at most 1000"):
            meter.averaging = 5000
        assert meter.averaging == 4  # nothing was sent


def test_a_scan_runs_through_the_plugin_meter_with_the_engine(tmp_path, capsys):
    out = tmp_path / "runs"
    assert main(["run", str(PLAN), "--bench", str(BENCH), "--out", str(out),
                 "--no-fsync"]) == 0
    assert "run finished: 7 of 7 points" in capsys.readouterr().out
    with h5py.File(next(out.glob("*.h5")), "r") as f:
        e = f["entry"]
        assert e.attrs["status"] == "finished"
        assert e["instrument/power_meter"].attrs["driver"] == "example_meter"
        assert e["instrument/power_meter"].attrs["model"] == "EM-1"
        lit, dark = e["points/power_w"][:], e["points/power_dark_w"][:]
        theta_r = e["points/theta_r"][:]
    # What the profile's scene sends into the aperture: its Lambertian part alone is
    # P0·(ρ/π)·cos θr·Ω (the whole beam P0 = 1 mW on the sample, ρ = 0.5, Ω the 5 mm
    # aperture at 300 mm); the GGX lobe adds to it, most near the specular θr = 30°
    # (≈ 3.7 times at θr = 40°). The meter's noise (1e-4 relative, 1e-10 W floor) is
    # below 1 % of these readings, so each lies within [0.97, 5] times the Lambertian part.
    omega = 2 * np.pi * (1 - np.cos(np.arctan2(2.5, 300.0)))
    lambert = 1e-3 * 0.5 / np.pi * np.cos(np.radians(theta_r)) * omega
    ratio = (lit - dark) / lambert
    assert np.all((ratio > 0.97) & (ratio < 5.0)), ratio


class _Em1Contract(PowerMeterContract):
    @pytest.fixture
    def light(self, profile):
        source = open_device(profile.device("source"))
        yield lambda on: source.turn_on() if on else source.turn_off()
        source.close()


class TestEm1ContractOverItsUrl(_Em1Contract):
    @pytest.fixture
    def meter_factory(self, profile):
        return lambda: open_device(profile.device("power_meter"))


class TestEm1ContractOverAPty(_Em1Contract):
    @pytest.fixture
    def meter_factory(self, profile):
        from example_meter.driver import Em1PowerMeter

        server = serve_url(profile.device("power_meter").url, handlers="example_meter.urlhandler")
        yield lambda: Em1PowerMeter(server.path, name="power_meter")
        server.close()


def test_the_gui_shows_the_plugin_meter_through_the_power_meter_kind(profile):
    from instrument.bench.device_state import kind_of, read_state

    with open_device(profile.device("power_meter")) as meter:
        state = read_state("power_meter", meter, with_info=True)
        assert state.kind == "power_meter" and state.connected and state.error is None
        assert state.info["identity"]["model"] == "EM-1"
        assert state.info["wavelength_range_nm"] == (300.0, 1100.0)
        assert state.value("wavelength_nm") == pytest.approx(633.0)
        assert np.isfinite(state.value("power_w"))
        # what the operator may set and do on a power meter, the plugin meter takes
        kind = kind_of(meter)
        assert "wavelength_nm" in kind.settings and "zero" in kind.actions
        kind.actions["zero"](meter)


def test_the_gui_gives_the_plugin_meter_the_power_meter_panel():
    from gui.qt.panels import PowerMeterPanel, panel_for

    assert panel_for("power_meter") is PowerMeterPanel


def test_serve_sim_serves_the_plugins_emulator_on_a_pty(capsys):
    """The plugin's registered scheme is an emulated serial controller like the built-in
    ones: ``serve-sim`` puts it on a pseudo-terminal next to the stages."""
    assert main(["serve-sim", "--bench", str(BENCH), "--duration", "0.01"]) == 0
    out = capsys.readouterr().out
    served = {line.split(":")[0]: line for line in out.splitlines() if "->" in line}
    assert set(served) == {"sample_theta", "detector_theta", "power_meter"}
    assert "simem1://power_meter" in served["power_meter"] and "/dev/pts/" in out
