"""A bus of addressed modules in the virtual world: each Elliptec mount is its own axis.

The world reads one stage per role; a role bound with the bus's ``address`` reads that
module, so four ELL14s on one serial line are four polarimeter mounts of the world.
"""

from __future__ import annotations

import pytest

from hw_mocks import registry
from hw_mocks.clock import ManualClock
from hw_mocks.firmware.elliptec import ElliptecEmulator
from hw_mocks.sim.world import RoleSpec, VirtualBench
from instrument.bench.devices import simulation_config
from instrument.bench.profile import load_profile

BUS = "simell://polarimeter?addresses=0123&speed=20"


def test_the_ell14_profile_binds_each_mount_by_its_address():
    world, config = simulation_config(load_profile("sim-polarimetric-ell14"))
    assert world == "sim-polarimetric-ell14"
    roles = config["roles"]
    assert [roles[r] for r in ("psg_polariser", "psg_retarder", "psa_retarder",
                               "psa_polariser")] == [
        {"url": BUS, "address": a} for a in "0123"]
    # a mount on its own line keeps the plain URL binding
    assert roles["sample_theta"].startswith("simapt://sample_theta")


def test_the_world_reads_the_addressed_module_and_nothing_else():
    clock = ManualClock()
    bus = registry.get_or_create(
        "simell", "polarimeter",
        lambda name, _options: ElliptecEmulator(name, addresses="0123", clock=clock))
    world = VirtualBench("bus-world", roles={
        role: {"url": BUS, "address": a}
        for role, a in (("psg_retarder", "1"), ("psa_retarder", "2"))})
    assert bus.receive(b"2ma00004600") == []  # 17920 pulses = 45°, on module 2 only
    clock.advance(1.0)
    assert bus.poll() == [b"2PO00004600\r\n"]
    assert world.position("psa_retarder") == pytest.approx(45.0)
    assert world.position("psg_retarder") == pytest.approx(0.0)
    # a binding without an address reads the bus's first module
    world.set_role("sample_theta", BUS)
    assert bus.receive(b"0ma00002300") == []  # 8960 pulses = 22.5°
    clock.advance(1.0)
    assert world.position("sample_theta") == pytest.approx(22.5)
    assert world.position("psa_retarder") == pytest.approx(45.0)


def test_a_bad_address_binding_is_refused_naming_it():
    with pytest.raises(ValueError, match="needs the bus's 'url'"):
        RoleSpec.parse({"address": "2"})
    assert RoleSpec.parse({"url": BUS, "address": "a"}).address == "A"
    bus = ElliptecEmulator("b", addresses="01", clock=ManualClock())
    with pytest.raises(KeyError, match="no module at address 'A'; its addresses are 01"):
        bus.stage_at("A")
