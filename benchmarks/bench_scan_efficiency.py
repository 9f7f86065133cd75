"""Scan efficiency: a ~500-point in-plane BRDF scan in real time against its physical bound.

The axes are the real drivers over the firmware emulators running at wall-clock speed
(``speed=1``) with realistic dynamics: K10CR1 sample rotation (10 °/s, 10 °/s²) and
SMC100 detector arm (20 °/s, 80 °/s²). The camera is an ideal one that integrates for
its exposure in real time (10 ms, no readout), the power meter and source are ideal.

Lower bound = Σ over steps of the slowest axis's trapezoidal move time plus its servo
settling (``settle_s``: the SMC100 reports READY 10 ms after the profile ends) (both axes
start together) + Σ exposures. Efficiency = measured run time / lower bound (target ≤ 1.05).
Also reported: the motion time of the travel-optimised order against a naive raster of
the same points (planner model).

    python benchmarks/bench_scan_efficiency.py            # ~500 points (~3 min)
    python benchmarks/bench_scan_efficiency.py --quick    # ~100 points
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.transport import add_url_handler_package  # noqa: E402
from hw_mocks.sim.ideal import IdealCamera, IdealPowerMeter, IdealSource  # noqa: E402
from instrument.bench.devices import Bench, open_device  # noqa: E402
from instrument.bench.dynamics import route_time  # noqa: E402
from instrument.bench.profile import parse_profile  # noqa: E402
from instrument.plans import build_plan, parse_plan  # noqa: E402
from instrument.plans.build import dynamics_of  # noqa: E402
from instrument.run.runner import start_run  # noqa: E402

EXPOSURE_US = 10000.0

PROFILE = """
[bench]
name = "real-time emulated goniometer"
[devices.sample_theta]
driver = "thorlabs_apt"
url = "simapt://sample_theta?model=K10CR1&speed=1"
stage = "K10CR1"
limits = [-90.0, 90.0]
velocity = 10.0
acceleration = 10.0
position_tolerance = 0.01
[devices.detector_theta]
driver = "newport_smc100"
url = "simsmc://detector_theta?kind=rotary&speed=1"
limits = [-170.0, 170.0]
velocity = 20.0
acceleration = 80.0
position_tolerance = 0.005
settle_s = 0.01
[devices.camera]
driver = "sim_camera"
url = "ideal://camera"
[devices.power_meter]
driver = "pm100usb"
url = "ideal://power_meter"
[devices.source]
driver = "sim_source"
url = "ideal://source"
[geometry]
kind = "in_plane"
min_bistatic_deg = 6.0
"""


def plan_text(theta_i: list[float], n_r: int, order: str) -> str:
    theta_r = [round(-72.0 + 1.5 * k, 3) for k in range(n_r)]
    return f"""
[plan]
kind = "brdf_in_plane"
name = "efficiency"
order = "{order}"
[sample]
name = "bench"
[scan]
theta_i = {theta_i}
theta_r = {theta_r}
skip_beam_points = true
[acquisition]
mode = "fixed"
exposure_us = {EXPOSURE_US}
detectors = ["camera"]
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="about 100 points")
    args = ap.parse_args()
    theta_i = [15.0, 45.0] if args.quick else [10.0, 20.0, 30.0, 40.0, 50.0]
    add_url_handler_package("hw_mocks.urlhandler")
    profile = parse_profile(PROFILE)
    spec = parse_plan(plan_text(theta_i, 108 if not args.quick else 50, "optimised"))
    plan = build_plan(spec, profile, start={"sample_theta": 0.0, "detector_theta": 0.0})
    raster = build_plan(replace(spec, order="raster"), profile)
    dyn = dynamics_of(profile, plan.axes)
    home = [0.0] * len(plan.axes)
    t_opt, _ = route_time(plan.targets_array(), plan.axes, dyn, start=home)
    t_raster, _ = route_time(raster.targets_array(), raster.axes, dyn, start=home)
    bound = t_opt + len(plan.points) * EXPOSURE_US * 1e-6
    print(f"{len(plan.points)} points; motion (model): optimised {t_opt:.1f} s, naive raster "
          f"{t_raster:.1f} s ({t_opt / t_raster:.2f}); lower bound with exposures "
          f"{bound:.1f} s")

    source = IdealSource("source")
    devices = {r: open_device(profile.devices[r]) for r in plan.axes}
    devices.update(camera=IdealCamera("camera", source=source, real_time=True),
                   power_meter=IdealPowerMeter("power_meter"), source=source)
    with Bench(profile, devices) as bench, tempfile.TemporaryDirectory() as tmp:
        for axis in bench.axes.values():
            axis.enable()
            axis.home(timeout=600.0)
            axis.move_to(0.0, wait=True, timeout=600.0)
        engine = start_run(plan, bench, runs_dir=tmp, fsync=True, catalog=False)
        t0 = time.perf_counter()
        engine.run()
        measured = time.perf_counter() - t0
        assert engine.n_done == len(plan.points)
    print(f"measured {measured:.1f} s; efficiency measured/bound = {measured / bound:.3f} "
          f"({1e3 * (measured - bound) / len(plan.points):.1f} ms overhead per point)")


if __name__ == "__main__":
    main()
