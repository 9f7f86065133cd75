"""Runs from a script (instrument.open_bench): the same engine, file and guard as the CLI;
control through the handle; a bench always left safe; results as labelled arrays.

Every wait is on the run's own events (ADR 0020): nothing here depends on how fast the
machine is.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import instrument
from instrument import open_bench, open_run, plans
from instrument.bench.guard import GuardError
from instrument.pipelines.brdf.reduce import reduce_run
from instrument.run.events import Paused, PointCompleted, Progress, RunFinished, RunStarted
from instrument.run.runfile import read_run

EVENT_WAIT_S = 120.0


def small_plan(theta_r=(-40.0, 10.0, 50.0), **acq):
    return plans.in_plane(theta_i=[30.0], theta_r=list(theta_r), sample="sim-grey",
                          skip_beam_points=True,
                          acquisition={"mode": "auto", "dark": "per_point",
                                       "detectors": ["camera"], **acq})


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    runs = tmp_path_factory.mktemp("runs")
    with open_bench("sim", runs_dir=runs, fsync=False) as bench:
        dry = bench.dry_run(small_plan())
        handle = bench.run(small_plan(), progress=False)
    return dry, handle


def test_a_blocking_run_ends_finished_with_every_planned_point(finished):
    dry, handle = finished
    assert handle.status == "finished" and handle.done
    assert isinstance(handle.finished, RunFinished)
    run = handle.result()
    assert run.status == "finished" and run.n_points == dry.n_points == 3
    assert sorted(run.data.index.tolist()) == [0, 1, 2]
    assert run.data.plan_text == small_plan().source_text  # the plan as a file would say it


def test_to_xarray_is_the_reduction_of_scatterlab_fit_with_labelled_angles(finished):
    dry, handle = finished
    ds = open_run(handle.path).to_xarray()
    red = reduce_run(handle.path)
    np.testing.assert_array_equal(ds["brdf"].values, red.points.brdf)
    np.testing.assert_array_equal(ds["u_brdf"].values, red.points.u_point)
    assert ds["brdf"].attrs["units"] == "1/sr" and ds["theta_r"].attrs["units"] == "deg"
    # read-back angles within the stages' resolution of the planned directions
    planned = {int(k): tuple(a) for k, a in enumerate(dry.angles)}
    for k, th_r, th_i in zip(ds["point"].values, ds["theta_r"].values, ds["theta_i"].values,
                             strict=True):
        assert th_i == pytest.approx(planned[int(k)][0], abs=0.01)
        assert th_r == pytest.approx(planned[int(k)][2], abs=0.01)
    assert np.all(ds["u_brdf"].values > 0) and not ds["clipped"].values.any()
    df = open_run(handle.path).to_pandas()
    assert len(df) == ds.sizes["point"] and df.attrs["units"]["brdf"] == "1/sr"


def test_the_stored_table_and_a_fit_through_the_facade(finished):
    _, handle = finished
    raw = open_run(handle.path).to_xarray(reduced=False)
    assert raw.attrs["content"] == "stored point table"
    assert raw["signal"].attrs["units"] == "DN/us"
    assert set(raw["label"].values) == {"sample"}
    res = instrument.fit(handle.path, ["lambertian"], report=False, write=False,
                         cross_validation=False)
    assert res.result.chosen == "lambert"  # the alias finds its model (and is named so)
    assert res.reduced.points.n == 3


def test_a_run_of_another_kind_has_no_reduced_brdf(tmp_path):
    with open_bench("sim", runs_dir=tmp_path, fsync=False) as bench:
        handle = bench.run(plans.dark(exposures_us=[100], frames=1), progress=False)
    run = handle.result()
    with pytest.raises(ValueError, match=r"reduced=False"):
        run.to_xarray(reduced=True)
    assert run.to_xarray()["n_frames"].values.tolist() == [1]


def test_events_as_an_iterator_and_as_a_callback_are_the_same_sequence(tmp_path):
    seen = []
    with open_bench("sim", runs_dir=tmp_path, fsync=False) as bench:
        handle = bench.run(small_plan(), block=False, on_event=seen.append)
        events = list(handle.events(timeout=EVENT_WAIT_S))
    assert isinstance(events[0], RunStarted) and isinstance(events[-1], RunFinished)
    assert events[-1].status == "finished"
    assert [type(e) for e in events] == [type(e) for e in seen]
    assert sum(isinstance(e, PointCompleted) for e in events) == 3
    assert [e.n_done for e in events if isinstance(e, Progress)][-1] == 3


def _until(it, kind):
    for ev in it:
        if isinstance(ev, kind):
            return ev
    raise AssertionError(f"the run ended before a {kind.__name__} event")


def test_pause_resume_abort_then_resume_measures_each_point_once(tmp_path):
    plan = small_plan(theta_r=(-60.0, -40.0, 10.0, 30.0, 50.0))
    with open_bench("sim", runs_dir=tmp_path, fsync=False) as bench:
        assert bench.dry_run(plan).n_points == 5
        handle = bench.run(plan, block=False)
        events = handle.events(timeout=EVENT_WAIT_S)
        _until(events, RunStarted)
        handle.pause()
        paused = _until(events, Paused)
        assert handle.status == "paused" and paused.reason == "paused from a script"
        handle.resume()
        _until(events, PointCompleted)
        assert handle.abort(timeout=EVENT_WAIT_S) == "aborted"
        n_first = read_run(handle.path).n_points
        assert 1 <= n_first < 5
        again = bench.resume(handle.path, progress=False)
    assert again.status == "finished" and again.path == handle.path
    idx = read_run(handle.path).index.tolist()
    assert sorted(idx) == [0, 1, 2, 3, 4]  # nothing lost, nothing twice


def test_leaving_the_block_aborts_a_running_run_and_closes_the_bench(tmp_path):
    with open_bench("sim", runs_dir=tmp_path, fsync=False) as bench:
        handle = bench.run(small_plan(), block=False)
        _until(handle.events(timeout=EVENT_WAIT_S), PointCompleted)
        source = bench.devices["source"]
    assert handle.done and handle.status in ("aborted", "finished")
    assert read_run(handle.path).status == handle.status
    with pytest.raises(Exception):  # noqa: B017 - any error: the device is closed
        source.turn_on()


INTERRUPTED_SCRIPT = """
import os, signal, sys
from instrument import open_bench, plans
from instrument.run.events import PointCompleted

# as at a console: a test runner's worker may pass SIGINT on ignored to its children
signal.signal(signal.SIGINT, signal.default_int_handler)

def interrupt_once(ev, sent=[]):
    if isinstance(ev, PointCompleted) and not sent:
        sent.append(ev)
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C, or a notebook's stop button

plan = plans.in_plane(theta_i=[30.0], theta_r=[-60.0, -40.0, 10.0, 30.0, 50.0],
                      sample="s", skip_beam_points=True,
                      acquisition={"mode": "auto", "dark": "per_point",
                                   "detectors": ["camera"]})
with open_bench("sim", runs_dir=sys.argv[1], fsync=False) as bench:
    try:
        bench.run(plan, progress=False, on_event=interrupt_once)
    except KeyboardInterrupt:
        print("interrupted")
"""


def test_ctrl_c_in_a_blocking_run_aborts_it_cleanly_and_re_raises(tmp_path):
    """In a process of its own: the interrupt goes to the main thread, as at a console."""
    out = subprocess.run([sys.executable, "-c", INTERRUPTED_SCRIPT, str(tmp_path)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "interrupted" and "Traceback" not in out.stderr
    run = read_run(next(tmp_path.glob("*.h5")))
    assert run.status in ("aborted", "finished")  # a fast machine may finish first
    assert run.status == "finished" or run.n_points < 5


def test_a_second_run_while_one_goes_is_refused(tmp_path):
    with open_bench("sim", runs_dir=tmp_path, fsync=False) as bench:
        first = bench.run(small_plan(), block=False)
        with pytest.raises(RuntimeError, match="still running"):
            bench.run(small_plan(), block=False)
        first.wait(EVENT_WAIT_S)
    assert len(list(tmp_path.glob("*.h5"))) == 1


def test_a_guarded_plan_is_refused_before_any_file_is_made(tmp_path):
    beam = plans.in_plane(theta_i=[30.0], theta_r=[-30.0], sample="s")  # detector in beam
    with open_bench("sim", runs_dir=tmp_path, fsync=False) as bench:
        with pytest.raises(GuardError, match="beam"):
            bench.dry_run(beam)
        with pytest.raises(GuardError):
            bench.run(beam)
    assert not list(tmp_path.glob("*.h5"))


def test_dry_run_counts_travel_and_draws_coverage(tmp_path):
    with open_bench("sim", runs_dir=tmp_path) as bench:
        dry = bench.dry_run("examples/brdf_inplane.toml")
    assert dry.n_points == 57 and dry.points.shape == (57, len(dry.axes))
    assert dry.travel["detector_theta"] > 0 and dry.estimate.total_s > 0
    assert dry.coverage(tmp_path / "c.png").stat().st_size > 1000


def test_the_facade_is_loaded_on_first_use_only():
    code = ("import sys, instrument; assert 'instrument.scripting' not in sys.modules; "
            "from instrument import open_bench, plans, open_run, fit; "
            "assert 'instrument.scripting' in sys.modules; "
            "assert all(getattr(instrument, n) is not None for n in instrument.__all__)")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
