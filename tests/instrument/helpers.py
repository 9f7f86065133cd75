"""Shared test helpers: an ideal (zero-latency) bench and small plan texts."""

from __future__ import annotations

from drivers.base import AxisKind
from hw_mocks.sim.ideal import IdealAxis, IdealCamera, IdealPowerMeter, IdealSource
from instrument.bench.devices import Bench
from instrument.bench.profile import parse_profile

IDEAL_PROFILE = """
[bench]
name = "ideal"
[devices.sample_theta]
driver = "thorlabs_apt"
url = "ideal://sample_theta"
limits = [-90.0, 90.0]
velocity = 10.0
acceleration = 10.0
[devices.sample_theta.retry]
attempts = 2
backoff_s = 0.0
on_failure = "pause"
[devices.detector_theta]
driver = "newport_smc100"
url = "ideal://detector_theta"
limits = [-170.0, 170.0]
velocity = 20.0
acceleration = 80.0
[devices.camera_z]
driver = "thorlabs_apt"
url = "ideal://camera_z"
limits = [0.0, 25.0]
velocity = 2.0
acceleration = 4.0
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
min_bistatic_deg = 5.0
"""

INPLANE_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "test"
[sample]
name = "test-sample"
[scan]
theta_i = [10.0, 30.0]
theta_r = {{ start = -45.0, stop = 75.0, step = {step} }}
skip_beam_points = true
[acquisition]
mode = "{mode}"
exposure_us = 1000
dark = "{dark}"
detectors = {detectors}
"""


def inplane_plan(step: float = 15.0, mode: str = "fixed", dark: str = "none",
                 detectors: str = '["camera", "power_meter"]') -> str:
    return INPLANE_PLAN.format(step=step, mode=mode, dark=dark, detectors=detectors)


def ideal_bench(profile_text: str = IDEAL_PROFILE, *, shape=(8, 8), brightness=None,
                noise_dn: float = 0.0) -> Bench:
    profile = parse_profile(profile_text, source="ideal profile")
    source = IdealSource("source")
    devices = {
        "sample_theta": IdealAxis("sample_theta", soft_limits=(-90, 90)),
        "detector_theta": IdealAxis("detector_theta", soft_limits=(-170, 170)),
        "camera_z": IdealAxis("camera_z", kind=AxisKind.LINEAR, soft_limits=(0, 25)),
        "camera": IdealCamera("camera", shape=shape, brightness=brightness, source=source,
                              noise_dn=noise_dn),
        "power_meter": IdealPowerMeter("power_meter"),
        "source": source,
    }
    return Bench(profile, devices)
