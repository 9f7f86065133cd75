"""`scatterlab --help` loads nothing heavy: no HDF5, SciPy, matplotlib or OpenCV (issue 12
§6). Checked on ``sys.modules`` of a fresh interpreter, never on time."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
HEAVY = ("matplotlib", "scipy", "h5py", "cv2", "PySide6")

PROBE = """
import contextlib, io, json, sys
import instrument.cli as cli
loaded = {{"import": [m for m in {heavy!r} if m in sys.modules]}}
with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.suppress(SystemExit):
    cli.main({argv!r})
loaded["run"] = [m for m in {heavy!r} if m in sys.modules]
loaded["out"] = out.getvalue()
print(json.dumps(loaded))
"""


def probe(argv: list[str]) -> dict:
    code = PROBE.format(heavy=HEAVY, argv=argv)
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=60, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_importing_the_cli_and_its_help_load_nothing_heavy():
    got = probe(["--help"])
    assert got["import"] == [] and got["run"] == []
    for name in ("devices", "plan", "run", "resume", "runs", "fit", "reconstruct",
                 "locate", "spheres", "serve-sim"):
        assert name in got["out"]  # every subcommand is listed with its help line


@pytest.mark.parametrize("command", ["run", "resume", "runs", "plan", "reconstruct",
                                     "locate", "spheres", "devices", "serve-sim"])
def test_a_subcommand_help_loads_nothing_heavy(command):
    got = probe([command, "--help"])
    assert got["run"] == [], got["run"]
    assert "usage: scatterlab" in got["out"]


def test_fit_help_lists_its_options():
    got = probe(["fit", "--help"])  # its default model list comes from the pipeline
    assert "--into-run" in got["out"] and "--models" in got["out"]
