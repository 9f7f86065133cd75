"""The application on a real X server (Xvfb, Qt's xcb platform), driven by input events:
connect, Home all, jog, start, pause, resume, abort, close; the screen is never blank
and no button is cut off at the default window size (tests/gui/xcb_smoke.py).

Skipped, with the reason, where Xvfb or Qt's xcb platform is not available; ``.ci/run``
installs them on a Debian CI machine.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.gui.helpers import fast_profile
from tests.gui.test_run_control import PLAN

ROOT = Path(__file__).resolve().parents[2]


def _xvfb(tmp_path):
    """Start Xvfb on a free display; returns (process, display) or skips."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (apt-get install xvfb; .ci/run does)")
    for n in range(90, 120):
        if Path(f"/tmp/.X{n}-lock").exists():
            continue
        proc = subprocess.Popen(["Xvfb", f":{n}", "-screen", "0", "1600x1000x24", "-nolisten",
                                 "tcp"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            if Path(f"/tmp/.X11-unix/X{n}").exists():
                return proc, f":{n}"
            time.sleep(0.05)
        proc.kill()
        proc.wait()
    pytest.skip("no X display could be started with Xvfb")


@pytest.mark.timeout(1200)  # a whole session with a run, on a shared CI machine
def test_operator_workflow_on_a_real_display(tmp_path):
    proc, display = _xvfb(tmp_path)
    try:
        env = dict(os.environ, DISPLAY=display, QT_QPA_PLATFORM="xcb")
        probe = subprocess.run(
            [sys.executable, "-c", "from PySide6.QtWidgets import QApplication; "
             "QApplication([]); print('ok')"], env=env, capture_output=True, text=True,
            timeout=120)
        if probe.returncode != 0 or "ok" not in probe.stdout:
            last = (probe.stderr.strip().splitlines() or ["no message"])[-1]
            pytest.skip(f"Qt's xcb platform does not start here: {last}")
        bench = tmp_path / "bench.toml"
        bench.write_text(fast_profile("sim").source_text, encoding="utf-8")
        plan = tmp_path / "plan.toml"
        plan.write_text(PLAN.format(step=5.0), encoding="utf-8")
        shots = tmp_path / "shots"
        shots.mkdir()
        done = subprocess.run(
            [sys.executable, "-m", "tests.gui.xcb_smoke", str(bench), str(tmp_path / "runs"),
             str(plan), str(tmp_path / "gui.ini"), str(shots)], cwd=ROOT, env=env,
            capture_output=True, text=True, timeout=900)
    finally:
        proc.terminate()
        proc.wait(30)
    lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
    assert lines, done.stderr[-3000:]
    report = json.loads(lines[-1])
    assert report["platform"] == "xcb"
    assert report["steps"] == ["connect", "home all", "jog", "start", "pause", "resume",
                               "abort", "close"], "\n".join(report["problems"])
    assert report["run_status"] == "aborted"
    assert len(report["shots"]) == 8 and all(Path(p).stat().st_size > 0
                                             for p in report["shots"])
    assert not [p for p in report["problems"] if "blank" in p]
    assert report["problems"] == [], "\n".join(report["problems"])

