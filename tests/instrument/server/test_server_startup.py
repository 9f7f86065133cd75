"""`scatterlab serve` loads no SciPy, matplotlib, OpenCV or Qt before it serves: every
server start (a lab PC's, and each of the suite's server tests) would otherwise pay about a
second of CPU for modules only a fit, a plot or the emulated camera's laser speckle needs.
Checked on ``sys.modules`` of a fresh interpreter at the moment uvicorn would start
serving, never on time."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.instrument.server.helpers import fast_profile_text

ROOT = Path(__file__).resolve().parents[3]
HEAVY = ("scipy", "matplotlib", "cv2", "PySide6")

# uvicorn's Server.run is where `serve` hands over to the event loop: the probe replaces
# it with a report of what is loaded by then, so the server stops instead of serving.
PROBE = """
import json, sys
import uvicorn
from instrument.cli import main

def report(self, sockets=None):
    print(json.dumps([m for m in {heavy!r} if m in sys.modules]))

uvicorn.Server.run = report
main(["serve", "--bench", {bench!r}, "--runs", {runs!r}, "--listen", "127.0.0.1:0",
      "--no-fsync"])
"""


def test_serving_the_emulated_bench_loads_nothing_heavy(tmp_path):
    bench = tmp_path / "sim-fast.toml"
    bench.write_text(fast_profile_text(), encoding="utf-8")
    code = PROBE.format(heavy=HEAVY, bench=str(bench), runs=str(tmp_path / "runs"))
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, check=True)
    assert "serving bench" in done.stdout, done.stdout + done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1]) == []
