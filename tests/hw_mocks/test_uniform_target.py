"""The integrating-sphere port of the sim-camera-ptc bench: uniform, fed by the source."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hw_mocks.sim.camera import SimulatedCamera
from hw_mocks.sim.sensor import SensorParams
from hw_mocks.sim.uniform_target import IntegratingSphereTarget
from hw_mocks.sim.world import VirtualBench


def bench(power_w: float = 5e-3) -> VirtualBench:
    return VirtualBench.from_config("ptc-test", {
        "scene": {"kind": "integrating_sphere", "sphere_diameter_mm": 100.0,
                  "wall_reflectance": 0.98, "port_fraction": 0.05},
        "source": {"power_w": power_w, "max_power_w": 5e-3}})


def test_port_radiance_follows_the_sphere_equation_and_the_source() -> None:
    world = bench()
    world.update_source(on=True)
    state = world.snapshot()
    wall = math.pi * 0.1**2
    expected = 5e-3 / (math.pi * wall) * 0.98 / (1 - 0.98 * 0.95)
    dirs = np.array([[0.0, 0.0, -1.0], [0.6, 0.0, -0.8]])
    np.testing.assert_allclose(state.scene.radiance(np.zeros(3), dirs, state), expected)
    world.update_source(power_w=2.5e-3)
    assert world.snapshot().scene.port_radiance(world.snapshot()) == pytest.approx(
        expected / 2)
    world.update_source(on=False)
    assert world.snapshot().scene.port_radiance(world.snapshot()) == 0.0


def test_the_camera_sees_a_flat_field_but_for_the_lens_fall_off() -> None:
    world = bench()
    world.update_source(on=True)
    cam = SimulatedCamera(world=world, seed=1, sensor=SensorParams(width=256, height=256))
    try:
        rate = cam.photon_rate()
    finally:
        cam.close()
    # cos⁴ across ±0.7 mm at f = 50 mm: below 1e-3 peak to peak, far below the 1 % PRNU
    assert rate.std() / rate.mean() < 3e-4
    assert rate.max() / rate.min() - 1 < 1e-3


def test_bad_sphere_parameters_are_named() -> None:
    with pytest.raises(ValueError, match="wall_reflectance"):
        IntegratingSphereTarget(wall_reflectance=1.0)
    with pytest.raises(ValueError, match="unknown integrating-sphere scene keys"):
        IntegratingSphereTarget.from_config({"kind": "integrating_sphere", "colour": 1})
