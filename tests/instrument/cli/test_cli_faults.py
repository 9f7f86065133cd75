"""Faults that end in one clear line, never a traceback or silence, through the command
line on the emulated ``sim`` bench: a cut run file without its journal, read the same way
by every analysis and by ``resume``."""

from __future__ import annotations

import h5py
import pytest

from instrument.cli import main
from instrument.run.layout import journal_path
from instrument.run.runfile import read_summary

#: A run without frames (power meter only, 21 points): seconds on the emulated bench, and
#: long enough that its status, written last, lies beyond its points table in the file.
SCALAR_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "cli faults"
order = "raster"
[sample]
name = "sim-grey"
[scan]
theta_i = [20.0, 40.0]
theta_r = {start = -80, stop = 80, step = 16}
skip_beam_points = true
[acquisition]
mode = "fixed"
exposure_us = 2000
detectors = ["power_meter"]
"""

ANALYSES = ("fit", "reconstruct", "locate", "spheres")


@pytest.fixture
def scalar_run(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(SCALAR_PLAN)
    out = tmp_path / "runs"
    assert main(["run", str(plan), "--out", str(out), "--no-fsync", "--quiet"]) == 0
    capsys.readouterr()
    return next(out.glob("*.h5")), out


def _words_of_every_analysis(path, capsys) -> str:
    messages = set()
    for command in ANALYSES:
        assert main([command, str(path)]) == 2
        messages.add(capsys.readouterr().out)
    (message,) = messages  # the same words from every analysis
    return message


def test_a_cut_run_without_journal_is_salvaged_as_every_command_says(scalar_run, capsys):
    """Cut before its points table: the run record (plan, bench) reads, the status written
    at the end does not. The analyses promise a salvage; ``resume`` keeps the promise."""
    path, out = scalar_run
    with h5py.File(path) as f:
        cut = f["entry/points/index"].id.get_chunk_info(0).byte_offset
    journal_path(path).unlink()
    with open(path, "r+b") as fh:
        fh.truncate(cut)
    message = _words_of_every_analysis(path, capsys)
    assert "no journal" in message and "of 21 planned" in message
    assert (f"`scatterlab resume {path}` makes a new run file of the readable points "
            "(the damaged one is kept beside it as .corrupt) and measures the rest"
            ) in message
    assert "nothing" not in message
    rc = main(["resume", str(path), "--out", str(out), "--no-fsync", "--quiet"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "journal was missing" in text and "nothing" not in text
    assert path.with_suffix(".h5.corrupt").exists()
    summary = read_summary(path)
    assert summary.n_points == 21 and summary.status == "finished"


def test_a_run_cut_inside_its_run_record_reads_unrecoverable_everywhere(scalar_run, capsys):
    """Cut inside the plan record: nothing can be rebuilt, and every command, ``resume``
    included, says so in the same sentence."""
    path, out = scalar_run
    with h5py.File(path) as f:
        cut = f["entry/plan/plan_text"].id.get_offset()
    journal_path(path).unlink()
    with open(path, "r+b") as fh:
        fh.truncate(cut)
    message = _words_of_every_analysis(path, capsys)
    assert message.startswith("error: ") and "nothing in it can be recovered" in message
    assert main(["resume", str(path), "--out", str(out), "--quiet"]) == 2
    assert capsys.readouterr().out == message
