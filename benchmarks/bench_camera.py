"""Camera benchmarks: simulated frames per second and HDR merge throughput.

Run ``python benchmarks/bench_camera.py`` (or ``--quick`` for a short smoke run). Prints a
Markdown table for BENCHMARKS.md.

* Simulated camera (:mod:`hw_mocks.sim.camera`), MONO16, a Lambertian + Cook–Torrance GGX
  sample on the goniometer scene, full-frame ROI:
  - "still scene": the world does not change between frames, so the noise-free rendering
    is cached and each frame costs the EMVA 1288 sensor model (shot, read noise, fixed
    pattern, quantisation);
  - "moving arm": the detector arm moves before every frame, so every frame is traced anew
    (one ray per pixel) and exposed.
* HDR merge (:func:`analysis.hdr.merge_hdr`) of five 16-bit brackets, hat and
  inverse-variance weighting; throughput in output megapixels per second.
* PM100USB ``MEAS:POW?`` queries per second through the emulated USB path (the real
  USBTMC/pyusb stack over the emulated backend), measured by ``bench_power_meter.run_case``;
  ``bench_power_meter.py`` has the full table.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

from analysis.hdr import merge_hdr
from drivers.base import PixelFormat
from hw_mocks.sim.camera import SimulatedCamera
from hw_mocks.sim.goniometer_scene import GoniometerScene, brdf_from_model
from hw_mocks.sim.sensor import SensorParams
from hw_mocks.sim.world import VirtualBench

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_power_meter import open_meter, run_case  # sibling benchmark module


def _camera(side: int) -> tuple[SimulatedCamera, VirtualBench]:
    scene = GoniometerScene(brdf=brdf_from_model("lambert+ggx", [0.3, 0.5, 0.2]))
    world = VirtualBench("bench", roles={"sample_theta": 30.0, "detector_theta": 55.0},
                         scene=scene)
    world.update_source(on=True, power_w=1e-3)
    cam = SimulatedCamera(world=world, seed=1, sensor=SensorParams(width=side, height=side),
                          pixel_format=PixelFormat.MONO16)
    cam.exposure_us = 200.0
    return cam, world


def bench_sim_camera(side: int, frames: int) -> tuple[float, float]:
    """(still-scene fps, moving-arm fps) at side × side, MONO16."""
    cam, world = _camera(side)
    cam.acquire(1)  # warm the cache
    t0 = time.perf_counter()
    cam.acquire(frames, timeout=600.0)
    still = frames / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    for k in range(frames):
        world.set_role("detector_theta", 55.0 + 0.01 * (k + 1))
        cam.acquire(1, timeout=600.0)
    moving = frames / (time.perf_counter() - t0)
    cam.close()
    return still, moving


def bench_hdr(side: int, repeats: int, weighting: str) -> float:
    """Output megapixels per second for a merge of five 16-bit brackets."""
    rng = np.random.default_rng(0)
    exposures = np.array([10.0, 100.0, 1e3, 1e4, 1e5])
    rate = np.exp(rng.uniform(np.log(1e-2), np.log(1e3), (side, side)))  # e⁻/µs
    frames = np.stack([
        np.clip(np.rint(rng.poisson(np.minimum(rate * t, 1e9)) * 1.0 + 100.0), 0, 65535)
        .astype(np.uint16) for t in exposures
    ])
    kw = dict(darks=100.0, saturation_dn=60000.0, weighting=weighting,
              system_gain_dn_per_e=1.0, read_noise_dn=3.0)
    merge_hdr(frames, exposures, **kw)
    t0 = time.perf_counter()
    for _ in range(repeats):
        merge_hdr(frames, exposures, **kw)
    return repeats * side * side / 1e6 / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="few frames, small HDR")
    args = parser.parse_args(argv)
    frames = 3 if args.quick else 20
    print(f"python {platform.python_version()}, numpy {np.__version__}, "
          f"{platform.machine()}, quick={args.quick}")
    print()
    print("| simulated camera, MONO16 | still scene (frames/s) | moving arm (frames/s) |")
    print("|---|---|---|")
    for side in (1024, 2048):
        still, moving = bench_sim_camera(side, frames if side == 1024 else max(frames // 2, 2))
        print(f"| {side}×{side} | {still:.1f} | {moving:.2f} |")
    print()
    side = 512 if args.quick else 2048
    repeats = 1 if args.quick else 3
    print("| HDR merge, 5 brackets uint16 | size | throughput (output MP/s) |")
    print("|---|---|---|")
    for weighting in ("hat", "inverse_variance"):
        mps = bench_hdr(side, repeats, weighting)
        print(f"| {weighting} | {side}×{side} | {mps:.1f} |")
    print()
    meter = open_meter("simusb://bench_pm?serial=P2000000")
    try:
        pm = run_case(meter.read_power_w, 0.5 if args.quick else 3.0)
    finally:
        meter.close()
    print("| PM100USB over emulated USB | queries/s | median µs |")
    print("|---|---|---|")
    print(f"| `read_power_w()` (`MEAS:POW?`) | {pm['ops_per_s']:.0f} | {pm['median_us']:.0f} |")


if __name__ == "__main__":
    main()
