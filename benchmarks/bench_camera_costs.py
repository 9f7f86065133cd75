"""CPU seconds of the simulated camera's two costs in the README's main job: rendering a lit
view (the fast renderer, 1024² px, the `sim` bench's glossy sample lambert+ggx 0.5/0.2/0.2,
a 2 mm beam) at six of the job's θi/θr pairs, and the sensor's noise synthesis of one
1024² frame at three exposures (a 400² px patch at 10⁶ photons/s, the rest unlit).

    python benchmarks/bench_camera_costs.py            # from the repository root
    python benchmarks/bench_camera_costs.py --save DIR # also the views' photon rates (.npz)

CPU time of the process (all threads), so the figures compare across loads better than
wall time; run two trees one after the other in the same sitting to compare them. The
saved photon rates let two trees' renderings be compared pixel by pixel.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path.cwd()))

from hw_mocks.sim.camera import SimulatedCamera
from hw_mocks.sim.goniometer_scene import GoniometerScene, brdf_from_model
from hw_mocks.sim.sensor import Sensor
from hw_mocks.sim.world import VirtualBench

VIEWS = [(20.0, 40.0), (40.0, 80.0), (60.0, 120.0), (20.0, -30.0), (40.0, 10.0), (60.0, 0.0)]
EXPOSURES_US = (10.0, 2000.0, 200000.0)


def render_views(save: Path | None) -> float:
    total, rates = 0.0, {}
    for theta_s, theta_d in VIEWS:
        world = VirtualBench("bench", roles={"sample_theta": theta_s,
                                             "detector_theta": theta_d},
                             scene=GoniometerScene(brdf=brdf_from_model(
                                 "lambert+ggx", [0.5, 0.2, 0.2])))
        world.update_source(on=True, power_w=1e-3, beam_radius_mm=2.0)
        cam = SimulatedCamera(world=world, seed=1)
        cam.photon_rate()  # the lens grid, cached per lens: not a view's cost
        world.update_source(power_w=1.0001e-3)  # a new view of the same geometry
        t0 = time.process_time()
        rate = cam.photon_rate()
        seconds = time.process_time() - t0
        total += seconds
        rates[f"{theta_s:g}_{theta_d:g}"] = np.array(rate)
        print(f"view θs={theta_s:g}° θd={theta_d:g}°: {seconds:.3f} s CPU")
    if save is not None:
        save.mkdir(parents=True, exist_ok=True)
        np.savez(save / "views.npz", **rates)
    return total


def noise(frames: int = 10) -> None:
    sensor = Sensor(seed=1)
    rate = np.zeros((1024, 1024), np.float32)
    rate[300:700, 300:700] = 1e6
    for exposure in EXPOSURES_US:
        t0 = time.process_time()
        for i in range(frames):
            sensor.expose(rate, exposure, gain_db=0.0, bits=12, roi=(0, 0, 1024, 1024),
                          frame_index=i)
        ms = (time.process_time() - t0) / frames * 1e3
        print(f"noise, {exposure:g} µs exposure: {ms:.0f} ms CPU a frame")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--save", type=Path, default=None)
    args = ap.parse_args()
    print(f"six lit views: {render_views(args.save):.2f} s CPU")
    noise()


if __name__ == "__main__":
    main()
