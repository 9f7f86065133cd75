"""A plan that moves no axis (dark frames) is stored like any other; a writer that fails
for a reason other than storage still ends the run instead of leaving it hanging."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from instrument.plans import build_plan, parse_plan
from instrument.run.engine import EngineState
from instrument.run.recovery import recover
from instrument.run.runner import start_run
from tests.instrument.helpers import ideal_bench

ROOT = Path(__file__).resolve().parents[3]


def test_the_dark_calibration_example_runs_to_the_end(tmp_path):
    bench = ideal_bench()
    plan = build_plan(parse_plan((ROOT / "examples" / "calibration_dark.toml").read_text()),
                      bench.profile)
    assert plan.axes == ()
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False, catalog=False)
    assert engine.run() is EngineState.FINISHED
    with h5py.File(engine.store.path, "r") as f:
        assert f["entry/points/index"].shape[0] == len(plan.points)
        assert np.isnan(f["entry/points/positions"][()]).all()  # nothing was moved
    assert recover(engine.store.path).repairs == ()


def test_a_writer_bug_fails_the_run_instead_of_hanging(tmp_path):
    bench = ideal_bench()
    plan = build_plan(parse_plan((ROOT / "examples" / "calibration_dark.toml").read_text()),
                      bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False, catalog=False)

    def broken(rec) -> None:
        raise TypeError("a bug in the writer")

    engine.store.append = broken
    assert engine.run() is EngineState.FAILED
    assert not engine.alive
