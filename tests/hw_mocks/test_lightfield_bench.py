"""The light-field scene on the virtual bench (hw_mocks.sim.lightfield_bench)."""

from __future__ import annotations

import numpy as np
import pytest

from hw_mocks.sim.camera import OpticsParams, SimulatedCamera
from hw_mocks.sim.lightfield_bench import CameraTrack, LightFieldBenchScene, flatland_ray
from hw_mocks.sim.sensor import SensorParams
from hw_mocks.sim.world import VirtualBench

CONFIG = {
    "roles": {"camera_z": 12.5},
    "source": {"power_w": 1e-3, "on": True},
    "scene": {
        "kind": "lightfield",
        "material": "brushed_metal",
        "wall": [-100.0, 100.0],
        "camera_track": {"x0_mm": -5.0, "z_mm": 40.0, "direction": -1.0},
        "objects": [
            {"kind": "point", "y_mm": 0.0, "z_mm": -150.0, "radius_mm": 2.0, "radiance": 4.0},
            {"kind": "bar", "y_min_mm": 10.0, "y_max_mm": 20.0, "z_mm": -200.0},
        ],
    },
}


def _camera(world: VirtualBench) -> SimulatedCamera:
    return SimulatedCamera("camera", world=world,
                           sensor=SensorParams(width=256, height=4, pixel_pitch_um=22.0),
                           optics=OpticsParams(4.0, 1.0))


def test_world_builds_the_scene_and_the_camera_rides_the_track():
    world = VirtualBench.from_config("lf", CONFIG)
    assert isinstance(world.scene, LightFieldBenchScene)
    centre, forward, _right, _down = _camera(world).camera_frame(world.snapshot())
    np.testing.assert_allclose(centre, [-5.0 - 12.5, 0.0, 40.0])
    np.testing.assert_allclose(forward, [0.0, 0.0, -1.0], atol=1e-12)


def test_rendered_radiance_is_the_renderers_at_the_flatland_rays():
    world = VirtualBench.from_config("lf", CONFIG)
    scene = world.scene
    state = world.snapshot()
    centre = scene.camera_center_mm(state)
    rng = np.random.default_rng(5)
    d = np.column_stack([rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.2, 0.2, 50),
                         -np.ones(50)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    got = scene.radiance(centre, d, state)
    y_m, th, _ = flatland_ray(centre, d, 40.0)
    np.testing.assert_allclose(got, scene.hidden.radiance(y_m, th), rtol=1e-12, atol=1e-15)
    # the out-of-plane component does not matter (the scene is extruded along lab y)
    flat = d.copy()
    flat[:, 1] = 0.0
    flat /= np.linalg.norm(flat, axis=1, keepdims=True)
    np.testing.assert_allclose(scene.radiance(centre, flat, state), got, rtol=1e-12)
    # rays that never reach the wall see nothing
    assert scene.radiance(centre, np.array([[0.0, 0.0, 1.0]]), state)[0] == 0.0


def test_objects_shine_with_the_source():
    world = VirtualBench.from_config("lf", CONFIG)
    cam = _camera(world)
    on = np.array(cam.photon_rate(world.snapshot()), dtype=float)
    assert on.max() > 0
    world.update_source(power_w=2e-3)
    np.testing.assert_allclose(np.array(cam.photon_rate(world.snapshot()), dtype=float),
                               2 * on, rtol=1e-6)
    world.update_source(on=False)
    assert not np.any(cam.photon_rate(world.snapshot()))


def test_bad_configurations_are_rejected():
    scene = dict(CONFIG["scene"])
    with pytest.raises(ValueError, match="unknown light-field scene keys"):
        LightFieldBenchScene.from_config({**scene, "colour": "red"})
    with pytest.raises(ValueError, match="unknown material"):
        LightFieldBenchScene.from_config({**scene, "material": "velvet"})
    with pytest.raises(ValueError, match="object kind"):
        LightFieldBenchScene.from_config({**scene, "objects": [{"kind": "cube"}]})
    with pytest.raises(ValueError, match="either"):
        LightFieldBenchScene.from_config({**scene, "brdf": {"specular_reflectance": 0.1,
                                                            "specular_width_deg": 2,
                                                            "diffuse_reflectance": 0.2}})
    with pytest.raises(ValueError, match="d2"):
        CameraTrack(z_mm=0.0)
