"""Data loss is never hidden, and every command names a bad file the same way (issue 12 §1,
§2): a damaged finished run on the emulated bench, repaired, listed and re-measured through
the command line; runs of the wrong kind refused by name before anything is read."""

from __future__ import annotations

import math
import os
import signal
import threading
import time

import h5py
import numpy as np
import pytest

from instrument.cli import main
from instrument.run.layout import journal_path
from instrument.run.recovery import describe_points
from instrument.run.runfile import read_summary
from instrument.run.storage import RunHeader, RunStore

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "cli recovery"
order = "raster"
[sample]
name = "sim-grey with a rather long sample name that a table must not cut"
[scan]
theta_i = [30.0]
theta_r = [10.0, 30.0, 50.0, 70.0]
[acquisition]
mode = "fixed"
exposure_us = 2000
detectors = ["camera"]
"""


@pytest.fixture
def finished(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    out = tmp_path / "runs"
    assert main(["run", str(plan), "--out", str(out), "--no-fsync"]) == 0
    text = capsys.readouterr().out
    # the summary lists what this bench recorded: no power meter in the policy, no
    # "power readings"
    holds = next(line for line in text.splitlines() if "holds:" in line)
    assert "angles" in holds and "exposures" in holds and "power readings" not in holds
    return next(out.glob("*.h5")), out


def cut_inside_frames(path) -> set[int]:
    """Cut the file inside the chunk of its third-last frame: the points owning that
    frame and every frame stored beyond it lose them."""
    with h5py.File(path, "r") as f:
        ds = f["entry/data/frames"]
        spans = [ds.id.get_chunk_info_by_coord((k, 0, 0)) for k in range(ds.shape[0])]
        owner = f["entry/data/frame_point"][()]
    order = sorted(range(len(spans)), key=lambda k: spans[k].byte_offset)
    cut = spans[order[-3]].byte_offset + 8
    os.truncate(path, cut)
    return {int(owner[k]) for k, s in enumerate(spans) if s.byte_offset + s.size > cut}


def test_a_damaged_finished_run_is_reported_listed_and_remeasured(finished, capsys):
    path, out = finished
    lost = cut_inside_frames(path)
    assert lost
    assert main(["resume", str(path), "--out", str(out)]) == 1  # finished, but lost data
    text = capsys.readouterr().out
    assert "repaired: " in text and "cut short" in text
    assert f"the frames of point(s) {describe_points(lost)} are lost" in text
    assert f"scatterlab resume --remeasure-lost {path.resolve()}" in text
    assert "already finished" in text
    # the listing shows the repair and what is still lost; the sample name is whole
    assert main(["runs", "--out", str(out)]) == 0
    listing = capsys.readouterr().out
    assert "repaired " in listing and "frames still lost" in listing
    assert "a rather long sample name that a table must not cut" in listing
    # the analysis refuses nothing silently: the lost points are named in the summary
    assert set(read_summary(path).lost) == lost
    # measured again, into the same file: exactly those points
    assert main(["resume", str(path), "--out", str(out), "--remeasure-lost",
                 "--no-fsync"]) == 0
    text = capsys.readouterr().out
    assert "measuring point(s)" in text
    assert "run finished: 4 of 4 points" in text
    s = read_summary(path)
    assert s.lost == () and s.n_points == 4 and s.status == "finished"
    with h5py.File(path, "r") as f:
        assert np.all(f["entry/points/status"][()] == 0)
        events = [e for e in f["entry/events/log"].asstr()[()] if "remeasure" in e]
    assert len(events) == 1 and all(str(i) in events[0] for i in lost)
    assert main(["runs", "--out", str(out)]) == 0
    assert "frames still lost" not in capsys.readouterr().out


def test_a_cut_run_without_journal_is_named_by_every_command_then_salvaged(finished,
                                                                          capsys):
    path, out = finished
    journal_path(path).unlink()
    cut_inside_frames(path)
    messages = set()
    for command in ("fit", "reconstruct", "locate", "spheres"):
        assert main([command, str(path)]) == 2
        text = capsys.readouterr().out
        assert "HDF5" not in text and "eof" not in text and "Errno" not in text
        messages.add(text)
    (message,) = messages  # the same words from every analysis
    assert "damaged scatterlab run file" in message and "no journal" in message
    assert "of 4 planned" in message and f"scatterlab resume {path}" in message
    rc = main(["resume", str(path), "--out", str(out), "--no-fsync", "--remeasure-lost"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "journal was missing" in text and ".corrupt" in text
    assert path.with_suffix(".h5.corrupt").exists()
    assert read_summary(path).n_points == 4 and read_summary(path).status == "finished"


def make_run(path, kind: str) -> None:
    """A finished run of plan kind ``kind`` with two points and no frames."""
    n = 2
    header = RunHeader(
        run_id=path.stem, plan_kind=kind, plan_name="p", plan_text="", profile_text="",
        bench_name="b", sample_name="s", sample_description="", axes=("camera_z",),
        planned_targets=[[0.0], [1.0]], planned_angles=[[math.nan] * 4] * n,
        planned_label=["sample"] * n, planned_light=[True] * n,
        planned_exposure_us=[math.nan] * n, acquisition_policy="{}", retry_policies="{}",
        identities={}, device_kinds={}, geometry={}, calibration={},
        software_version="test", created=time.time())
    RunStore.create(path, header, fsync=False, min_free_bytes=0).close("finished")


@pytest.mark.parametrize(("command", "kind", "words"), [
    ("fit", "lightfield", "is a lightfield run; `scatterlab fit` analyses BRDF runs"),
    ("fit", "sphere_capture", "use scatterlab spheres"),
    ("reconstruct", "brdf_in_plane", "is an in-plane BRDF run; `scatterlab reconstruct`"),
    ("locate", "sphere_capture", "is a sphere-capture run; `scatterlab locate`"),
    ("spheres", "lightfield", "use scatterlab reconstruct / scatterlab locate"),
    ("fit", "flat_field", "give it to scatterlab fit --flat"),
])
def test_each_analysis_checks_the_plan_kind_first(tmp_path, capsys, command, kind, words):
    path = tmp_path / "r.h5"
    make_run(path, kind)
    assert main([command, str(path)]) == 2
    text = capsys.readouterr().out
    assert words in text, text
    # refused before anything else was read: not the complaint of a later stage
    for later in ("no measured scattering points", "focal", "pixel", "no image"):
        assert later not in text


@pytest.mark.parametrize("command", ["fit", "reconstruct", "locate", "spheres", "resume"])
def test_missing_and_foreign_files_read_the_same_in_every_command(tmp_path, capsys, command):
    missing = tmp_path / "nope.h5"
    assert main([command, str(missing), "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().out == f"error: {missing}: no such run file\n"
    text = tmp_path / "notes.h5"
    text.write_text("not an HDF5 file")
    assert main([command, str(text), "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().out == (f"error: {text} is not a scatterlab run file (not an "
                                       "HDF5 file)\n")
    plain = tmp_path / "plain.h5"
    with h5py.File(plain, "w") as f:
        f["x"] = 1
    assert main([command, str(plain), "--out", str(tmp_path)]) == 2
    assert "is an HDF5 file but not a scatterlab run file" in capsys.readouterr().out


def test_a_forced_second_ctrl_c_names_the_resume_command(tmp_path, capsys):
    """The first Ctrl-C asks the engine to stop; a second one, while it still works, leaves
    at once — and says how to continue."""
    from instrument.cli.run import drive
    from instrument.plans import build_plan, parse_plan
    from instrument.run.events import PointCompleted
    from instrument.run.runner import start_run
    from tests.instrument.helpers import ideal_bench, inplane_plan

    bench = ideal_bench()
    plan = build_plan(parse_plan(inplane_plan(step=15.0)), bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False)
    release = threading.Event()

    def interrupt_twice(ev) -> None:
        if not isinstance(ev, PointCompleted) or ev.index != 2:
            return
        os.kill(os.getpid(), signal.SIGINT)
        deadline = time.monotonic() + 60
        while not engine._abort_requested and time.monotonic() < deadline:
            time.sleep(0.005)  # the first Ctrl-C has reached the main thread
        os.kill(os.getpid(), signal.SIGINT)
        release.wait(60)  # the engine is still busy when the second one lands

    engine.subscribe(interrupt_twice)
    try:
        assert drive(engine, quiet=True) == 130
    finally:
        release.set()
        engine.wait(60)
    text = capsys.readouterr().out
    assert "Ctrl-C again to force" in text
    assert f"continue the run with:\n  scatterlab resume {engine.store.path}" in text


def test_plan_writes_its_coverage_picture_into_the_runs_folder(tmp_path, capsys,
                                                               monkeypatch):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["plan", str(plan)]) == 0
    assert "coverage picture: runs/p_coverage.png" in capsys.readouterr().out
    assert (work / "runs" / "p_coverage.png").read_bytes()[:4] == b"\x89PNG"
    assert [p.name for p in work.iterdir()] == ["runs"]  # nothing in the current folder
    assert main(["plan", str(plan), "--out", str(tmp_path / "elsewhere")]) == 0
    assert (tmp_path / "elsewhere" / "p_coverage.png").exists()
