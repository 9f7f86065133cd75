"""Photon-transfer runs on the emulated camera-characterization bench, and their truth.

A run goes through the real engine (``scatterlab run examples/calibration_ptc.toml
--bench sim-camera-ptc``), with the camera's seed (fixed pattern and every frame's noise)
changed in a copy of the built-in profile. The truth is the simulated sensor's EMVA 1288
parameters (hw_mocks.sim.sensor.SensorParams) and the photon count its renderer computes.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from hw_mocks.sim.camera import open_from_url
from hw_mocks.sim.world import VirtualBench
from instrument.cli import main

ROOT = Path(__file__).resolve().parents[4]
PLAN = ROOT / "examples" / "calibration_ptc.toml"
PROFILE = ROOT / "instrument" / "bench" / "profiles" / "sim-camera-ptc.toml"


def ptc_profile(seed: int, folder: Path) -> Path:
    """A copy of the sim-camera-ptc profile whose camera has ``seed``."""
    text = PROFILE.read_text(encoding="utf-8")
    path = folder / f"sim-camera-ptc-{seed}.toml"
    path.write_text(re.sub(r"seed=\d+", f"seed={seed}", text, count=1), encoding="utf-8")
    return path


def run_ptc(seed: int, folder: Path) -> Path:
    """Run the example photon-transfer plan on the bench with camera ``seed``; its run file."""
    out = folder / f"runs-{seed}"
    rc = main(["run", str(PLAN), "--bench", str(ptc_profile(seed, folder)), "--out", str(out),
               "--no-fsync", "--quiet"])
    assert rc == 0
    (path,) = sorted(out.glob("*.h5"))
    return path


def truth() -> dict[str, float]:
    """The EMVA 1288 parameters the evaluation should recover (K at 0 dB and MONO12), and
    the photons per pixel per second of the sweep (the mean over the sensor)."""
    profile = tomllib.loads(PROFILE.read_text(encoding="utf-8"))
    sim = dict(profile["simulation"])
    sim.pop("world")
    world = VirtualBench.from_config("ptc-truth", sim)
    world.update_source(on=True)
    url = profile["devices"]["camera"]["url"].replace("world=sim-camera-ptc", "world=sim")
    cam = open_from_url(url)
    try:
        p = cam.sensor.params
        photons = float(cam.photon_rate(world.snapshot()).mean())
        return {"system_gain_dn_per_e": p.system_gain(0.0, 12), "dark_noise_e": p.read_noise_e,
                "saturation_capacity_e": cam.sensor.emva_saturation_capacity_e(),
                "linearity_error_percent": 0.0,
                "dark_current_e_per_s": p.dark_current_e_per_s, "dsnu_e": p.dsnu_e,
                "prnu_rel": p.prnu, "quantum_efficiency": p.quantum_efficiency,
                "photons_per_pixel_s": photons}
    finally:
        cam.close()


#: Parameters compared with the truth, by their key in the calibration file's "emva1288".
CHECKED = ("system_gain_dn_per_e", "dark_noise_e", "saturation_capacity_e",
           "dark_current_e_per_s", "dsnu_e", "prnu_rel", "quantum_efficiency")


def z_scores(content: dict, truth_values: dict) -> dict[str, float]:
    """(recovered − truth)/u of every checked parameter of a calibration file, and of LE
    less its noise floor (the simulated sensor is linear: truth 0)."""
    e = content["emva1288"]
    z = {k: (e[k][0] - truth_values[k]) / e[k][1] for k in CHECKED}
    z["linearity_error_percent"] = (e["linearity_error_unbiased_percent"]
                                    / e["linearity_error_percent"][1])
    return z
