"""PowerMeter and LightSource contracts against their implementations on the sim bench."""

from __future__ import annotations

import pytest

from instrument.bench.devices import configure_simulation, open_device
from instrument.bench.profile import load_profile
from tests.drivers.light_source_contract import LightSourceContract
from tests.drivers.power_meter_contract import PowerMeterContract


@pytest.fixture
def sim_profile():
    profile = load_profile("sim")
    configure_simulation(profile)
    return profile


class TestPM100USBContract(PowerMeterContract):
    @pytest.fixture
    def meter_factory(self, sim_profile):
        return lambda: open_device(sim_profile.device("power_meter"))

    @pytest.fixture
    def light(self, sim_profile):
        source = open_device(sim_profile.device("source"))
        yield lambda on: source.turn_on() if on else source.turn_off()
        source.close()


class TestSimulatedSourceContract(LightSourceContract):
    @pytest.fixture
    def source_factory(self, sim_profile):
        return lambda: open_device(sim_profile.device("source"))
