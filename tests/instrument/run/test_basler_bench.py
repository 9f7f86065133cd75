"""Runs on the emulated Basler bench (``sim-basler``): the engine, the run file and the
retry policy with the GenICam driver on pylon's camera emulation."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from instrument.bench.devices import open_bench
from instrument.bench.profile import load_profile
from instrument.plans import build_plan, parse_plan
from instrument.run.engine import EngineState
from instrument.run.events import EventQueue, Fault, PointCompleted
from instrument.run.runner import start_run
from tests.drivers.basler_emulation import require_pylon, unplug
from tests.instrument.helpers import inplane_plan

require_pylon()

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture
def bench():
    opened = open_bench(load_profile("sim-basler"))
    yield opened
    opened.close()


def _run(bench, plan_text: str, tmp_path, subscriber=None):
    plan = build_plan(parse_plan(plan_text), bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False)
    events = EventQueue()
    engine.subscribe(events)
    if subscriber is not None:
        engine.subscribe(subscriber)
    assert engine.run() is EngineState.FINISHED
    return engine, plan, events.drain()


def _camera_attrs(path) -> tuple[dict, tuple, list]:
    with h5py.File(path) as f:
        attrs = dict(f["entry/instrument/camera"].attrs)
        shape = f["entry/data/frames"].shape
        status = list(f["entry/points/status"][:])
        log = [json.loads(s) for s in f["entry/events/log"][:]]
    return attrs, shape, [status, log]


@pytest.mark.slow
def test_the_readme_inplane_plan_runs_end_to_end(bench, tmp_path):
    """examples/brdf_inplane.toml, the README's scan, with the emulated Basler as camera."""
    text = (ROOT / "examples" / "brdf_inplane.toml").read_text(encoding="utf-8")
    engine, plan, _ = _run(bench, text, tmp_path)
    attrs, shape, (status, _log) = _camera_attrs(engine.store.path)
    assert (attrs["driver"], attrs["vendor"], attrs["serial"]) == ("basler", "Basler",
                                                                   "0815-0000")
    # a light and a dark frame per point (dark = "per_point"), the camera's full frame
    assert shape == (2 * len(plan.points), 1040, 1024)
    assert len(status) == len(plan.points) and set(status) == {0}


def test_a_camera_removed_mid_run_is_retried_and_reopened_by_serial(bench, tmp_path):
    unplugged = []

    def on(ev):
        if isinstance(ev, PointCompleted) and ev.index == 1 and not unplugged:
            unplugged.append(ev.index)
            unplug(bench.camera)  # pylon's removal callback, as when the cable is pulled

    engine, plan, events = _run(bench, inplane_plan(step=30.0), tmp_path, on)
    assert unplugged
    faults = [e for e in events if isinstance(e, Fault)]
    assert faults and faults[0].device == "camera" and faults[0].action.startswith("retry")
    assert "removed" in faults[0].cause
    _attrs, shape, (status, log) = _camera_attrs(engine.store.path)
    assert set(status) == {0} and shape[0] == len(plan.points)  # every point taken
    assert any(e["kind"] == "fault" and e["device"] == "camera" for e in log)


def test_the_run_file_holds_the_exposure_the_camera_took(bench, tmp_path):
    """The emulated camera takes whole microseconds: a plan's 1000.4 µs is stored as the
    1000 µs the frames were exposed for (the signal is divided by it)."""
    text = inplane_plan(step=60.0).replace("exposure_us = 1000", "exposure_us = 1000.4")
    engine, plan, _ = _run(bench, text, tmp_path)
    with h5py.File(engine.store.path) as f:
        taken = f["entry/data/frame_exposure_us"][:]
        planned = f["entry/plan/planned_exposure_us"][:]
    assert len(taken) == len(plan.points) and set(taken) == {1000.0}
    assert set(planned[~np.isnan(planned)]) <= {1000.4}
