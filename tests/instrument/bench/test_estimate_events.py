"""A duration estimate's countable parts against the events of a run on the emulated bench.

The simulated bench computes what a real one does not: the emulated power meter and
lock-in integrate the scattered light over their aperture at every new world state, and
the simulated camera renders every frame the auto-exposure takes while it climbs to new
light behind a neutral-density filter. The estimate counts both
(:attr:`instrument.plans.build.PlanEstimate.events`); these tests run plans through the
engine and count the same events where the emulators compute them, so nothing here
depends on how fast or loaded the machine is.
"""

from __future__ import annotations

import collections
from pathlib import Path

import pytest

from hw_mocks.sim import photodiode
from hw_mocks.sim.camera import SimulatedCamera
from hw_mocks.sim.goniometer_scene import GoniometerScene
from instrument.bench.devices import open_bench
from instrument.bench.profile import load_profile
from instrument.bench.timing import SIM_APERTURE_INTEGRAL_S, bench_timing
from instrument.plans import build_plan, parse_plan
from instrument.run.engine import EngineState
from instrument.run.runner import start_run

ROOT = Path(__file__).resolve().parents[3]



def _lockin_plan(dark: str) -> str:
    """The spectral bench's lock-in scan (three angles) with the power meter beside the
    lock-in, through two filters."""
    from tests.instrument.bench.test_spectral_bench import LOCKIN_PLAN

    return (LOCKIN_PLAN.replace('detectors = ["lockin"]',
                                'detectors = ["lockin", "power_meter"]')
            .replace('dark = "none"', f'dark = "{dark}"') + "[spectral]\nfilters = [1, 2]\n")


@pytest.fixture
def integrals(monkeypatch):
    """Counts of the scene's aperture integrals by (detector, light on) while the test runs."""
    counts: collections.Counter = collections.Counter()
    caller = {"who": "power_meter"}
    integral = GoniometerScene.power_on_aperture
    split = photodiode.split_power_w

    def counted(self, center, facing, diameter_mm, state):
        counts[caller["who"], bool(state.source.on)] += 1
        return integral(self, center, facing, diameter_mm, state)

    def lockin_split(*args, **kwargs):
        caller["who"] = "lockin"  # the engine reads one detector at a time
        try:
            return split(*args, **kwargs)
        finally:
            caller["who"] = "power_meter"

    monkeypatch.setattr(GoniometerScene, "power_on_aperture", counted)
    monkeypatch.setattr(photodiode, "split_power_w", lockin_split)
    return counts


def _run(plan, profile, tmp_path) -> None:
    with open_bench(profile) as bench:
        engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False, catalog=False)
        assert engine.run() is EngineState.FINISHED


@pytest.mark.parametrize("dark", ["none", "per_point"])
def test_the_estimate_counts_the_emulated_detectors_integrals(tmp_path, integrals, dark):
    """Three angles through two filters on sim-spectral: six world states with the light
    on (every point moves or turns the filter), each integrated once by the power meter
    and twice by the lock-in's photodiode (the light, and its ambient part with the
    source off), and the lock-in's first reading as the bench opens (light off); with
    per-point darks one dark state per angle for each detector (dark, the filter does not
    change what the detectors see, and the emulators cache it). Counted where the scene
    integrates, they are the estimate's counts."""
    profile = load_profile("sim-spectral")
    plan = build_plan(parse_plan(_lockin_plan(dark)), profile)
    est = plan.estimate()
    _run(plan, profile, tmp_path)
    ev = est.events
    assert integrals["power_meter", True] == ev["power_meter_integrals_lit"] == 6
    assert integrals["lockin", True] == ev["lockin_integrals_lit"] == 6
    assert integrals["power_meter", False] == ev["power_meter_integrals_dark"] \
        == (3 if dark == "per_point" else 0)
    assert integrals["lockin", False] == ev["lockin_integrals_dark"] \
        == 1 + 6 + (3 if dark == "per_point" else 0)
    # and the seconds they add are the measured costs of this scene
    lit_s, dark_s = SIM_APERTURE_INTEGRAL_S["spectral"]
    timing = bench_timing(profile, plan.axes)
    assert timing.power_meter_integral_s == timing.lockin_integral_s == (lit_s, dark_s)


def test_a_finer_aperture_rule_costs_in_proportion_to_its_nodes():
    """A profile that asks the emulator for a finer rule over the aperture
    (``aperture_samples = 27``: 324 nodes instead of 36) pays 9× for each lit integral;
    the dark integral (the ambient term only) is the same."""
    from instrument.bench.profile import parse_profile
    from instrument.bench.timing import aperture_nodes

    text = (ROOT / "instrument" / "bench" / "profiles" / "sim-spectral.toml").read_text(
        encoding="utf-8")
    fine = text.replace("[simulation.scene]\n", "[simulation.scene]\naperture_samples = 27\n")
    assert fine != text
    lit_s, dark_s = SIM_APERTURE_INTEGRAL_S["spectral"]
    timing = bench_timing(parse_profile(fine))
    assert timing.lockin_integral_s == pytest.approx((9 * lit_s, dark_s))
    assert timing.power_meter_integral_s == timing.lockin_integral_s
    assert [aperture_nodes(m) for m in (1, 3, 9, 10, 27)] == [4, 4, 36, 64, 324]


def test_real_detectors_and_other_scenes_cost_no_integrals():
    """A real power meter (no simulated world) and the light-field bench's scene have no
    measured integral cost: nothing is added, nothing counted."""
    real = load_profile("sim-spectral")
    devices = dict(real.devices)
    pm, li = devices["power_meter"], devices["lockin"]
    devices["power_meter"] = type(pm)(pm.role, pm.driver, "usb://0x1313:0x8072")
    devices["lockin"] = type(li)(li.role, li.driver, "/dev/ttyUSB0")
    from dataclasses import replace
    timing = bench_timing(replace(real, devices=devices))
    assert timing.power_meter_integral_s == timing.lockin_integral_s == (0.0, 0.0)
    assert bench_timing(load_profile("sim-lightfield")).power_meter_integral_s == (0.0, 0.0)


def test_the_estimate_counts_the_auto_exposure_climb_behind_nd_filters(tmp_path,
                                                                       monkeypatch):
    """The ND calibration plan on sim, starting at the exposure the open slot needs
    (31.25 µs for its two geometries): behind each denser filter (OD 1, 2, 3; 10× less
    light each) the auto-exposure climbs one factor of 8 (log 10 / log 8 = 1.1 steps,
    rounded) before the frame it keeps; the frames it did not keep, counted where the
    simulated camera exposes them, are the estimate's."""
    lit_frames: list[float] = []
    capture = SimulatedCamera._capture

    def counted(self):
        if self.world.snapshot().source.on:
            lit_frames.append(float(self._exposure_us))
        return capture(self)

    monkeypatch.setattr(SimulatedCamera, "_capture", counted)
    text = (ROOT / "examples" / "calibration_nd.toml").read_text(encoding="utf-8")
    text = text.replace("\nexposure_us = 2000\n", "\nexposure_us = 31.25\n")
    assert "\nexposure_us = 31.25\n" in text
    profile = load_profile("sim")
    plan = build_plan(parse_plan(text), profile)
    est = plan.estimate()
    assert est.events["auto_exposure_climb_frames"] == 3
    _run(plan, profile, tmp_path)
    lit_points = sum(1 for p in plan.points if p.light)
    assert len(lit_frames) - lit_points == 3
    assert any("3 auto-exposure frames" in note for note in est.predicted)
