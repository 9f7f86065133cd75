"""Runs on the emulated type (i) bench (``sim-type-i``, ADR 0099): the engine moves the
arms over the wire, splits a move that would bring them together, and the readings are
those of the ``sim`` bench at the same angles."""

from __future__ import annotations

import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from instrument.bench import guard
from instrument.bench.devices import open_bench
from instrument.bench.kinematics import TYPE_I_AXES
from instrument.bench.profile import load_profile
from instrument.plans import build_plan, parse_plan
from instrument.plans.planfile import load_plan
from instrument.run.engine import EngineState
from instrument.run.runner import start_run

ROOT = Path(__file__).resolve().parents[3]

#: θi = 30°: the detector goes from beyond the source head (θr = −70°, source side) to
#: between it and the pole (−10°), which it can only do around the source arm.
CROSSING = """
[plan]
kind = "brdf_in_plane"
name = "past the source arm"
order = "raster"
[sample]
name = "sim"
[scan]
points = [[30.0, -70.0], [30.0, -10.0], [30.0, 40.0], [30.0, 20.0]]
[acquisition]
detectors = ["power_meter"]
"""


def _run(name: str, text: str, tmp_path: Path):
    bench = open_bench(load_profile(name))
    try:
        plan = build_plan(parse_plan(text), bench.profile)
        engine = start_run(plan, bench, runs_dir=tmp_path / name, fsync=False)
        assert engine.run() is EngineState.FINISHED
    finally:
        bench.close()
    with h5py.File(engine.store.path) as f:
        pts = f["entry/points"]
        order = np.argsort(pts["index"][:])
        angles = np.column_stack([pts[k][:][order] for k in ("theta_i", "phi_i", "theta_r",
                                                             "phi_r")])
        power = pts["power_w"][:][order]
        log = [json.loads(s) for s in f["entry/events/log"][:]]
    return plan, angles, power, log


def test_the_arms_go_around_each_other_and_read_what_the_sim_bench_reads(tmp_path):
    plan, angles, power, log = _run("sim-type-i", CROSSING, tmp_path)
    routes = [e for e in log if e.get("kind") == "route"]
    assert routes and all(e["legs"] > 1 for e in routes)
    want = np.array([p.angles.as_tuple() for p in sorted(plan.points, key=lambda p: p.index)])
    # the read-back angles: within the stages' resolution of the plan's (φ at 0/360)
    d_phi = (angles[:, [1, 3]] - want[:, [1, 3]] + 180.0) % 360.0 - 180.0
    assert np.allclose(angles[:, [0, 2]], want[:, [0, 2]], atol=0.01)
    assert np.allclose(d_phi, 0.0, atol=0.01)
    _, _, power_ii, _ = _run("sim", CROSSING, tmp_path)
    # the meter's noise (sim.toml: 1e-4 of a reading and a 2.6e-10 W floor) on each
    sigma = np.hypot(2.6e-10, 1e-4 * power_ii) * math.sqrt(2.0)
    assert np.all(np.abs(power - power_ii) < 5.0 * sigma), (power, power_ii)


def test_a_plan_where_the_arms_collide_is_refused_before_anything_moves():
    text = CROSSING.replace("[30.0, 20.0]", "[30.0, -30.0]")  # θr = −θi: onto the source
    bench = open_bench(load_profile("sim-type-i"))
    try:
        before = {r: bench.devices[r].position for r in TYPE_I_AXES}
        with pytest.raises(guard.GuardError) as err:
            build_plan(parse_plan(text), bench.profile)
        assert {v.reason for v in err.value.violations} >= {"arms"}
        assert {r: bench.devices[r].position for r in TYPE_I_AXES} == before
    finally:
        bench.close()


@pytest.mark.slow
@pytest.mark.parametrize("example", ["brdf_inplane.toml", "brdf_hemisphere.toml"])
def test_the_example_plans_run_end_to_end_on_the_type_i_bench(example, tmp_path):
    """The README's in-plane plan and the hemisphere plan, unchanged, with the camera."""
    spec = load_plan(ROOT / "examples" / example)
    bench = open_bench(load_profile("sim-type-i"))
    try:
        plan = build_plan(spec, bench.profile)
        engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False)
        assert engine.run() is EngineState.FINISHED
    finally:
        bench.close()
    with h5py.File(engine.store.path) as f:
        status = f["entry/points/status"][:]
        power = f["entry/points/power_w"][:]
    assert len(status) == len(plan.points) and set(status) == {0}
    assert np.all(power > 0)


def test_a_move_with_no_route_from_where_the_arms_stand_pauses_before_moving(tmp_path):
    """The engine decides each move's route from the read-back positions. With the
    azimuth stages held at 0 (soft limits hugging it) the detector cannot go around the
    source arm: the run pauses at that point, naming why, and no stage has moved."""
    import dataclasses
    import threading

    from hw_mocks import registry
    from instrument.bench.profile import parse_profile
    from instrument.run.events import Fault, Paused, PointCompleted

    profile = load_profile("sim-type-i")
    held = parse_profile(profile.source_text.replace("limits = [-180.0, 180.0]",
                                                     "limits = [-0.01, 0.01]"))
    bench = open_bench(profile)
    try:
        plan = build_plan(parse_plan(CROSSING), profile)
        engine = start_run(dataclasses.replace(plan, profile=held), bench,
                           runs_dir=tmp_path, fsync=False)
        paused, seen = threading.Event(), []

        def on(ev):
            seen.append(ev)
            if isinstance(ev, Paused):
                paused.set()

        engine.subscribe(on)
        engine.start()
        assert paused.wait(120)
        fault = [e for e in seen if isinstance(e, Fault)][-1]
        assert "no collision-free route" in fault.cause and fault.action == "pause"
        # the first move already: from the homed arms (the source head at θ 60°, φ 0°,
        # the detector's on the far side) the detector must pass over the source head to
        # reach (30, -70) on the source's side; with both azimuths held, no route
        assert not [e for e in seen if isinstance(e, PointCompleted)]
        for role, scheme in (("source_arc", "simapt"), ("source_azimuth", "simzaber"),
                             ("detector_arc", "simsmc"), ("detector_azimuth", "simapt")):
            stage = registry.get(scheme, role).stage
            assert stage.physical_position() == pytest.approx(0.0, abs=1e-6), role
        engine.abort()
        engine.wait(60)
    finally:
        bench.close()
