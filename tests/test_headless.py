"""The README's test command needs no display and no environment variables.

A GUI test is run in a fresh interpreter with every display and backend variable removed,
as on an SSH login or in a container with no X server. Without the suite's own choice of
Qt's offscreen platform (``tests/conftest.py``), Qt aborts the interpreter ("could not
connect to display") as soon as the test creates its ``QApplication``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("pytestqt")

REPO = Path(__file__).resolve().parents[1]
# One real window on the simulated bench: it creates the QApplication, connects the bench
# and draws the goniometer view.
GUI_TEST = "tests/gui/test_goniometer_view.py::test_the_drawing_follows_the_stages"
# What a headless login lacks, and what .ci/run sets as a speed-up only.
UNSET = ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM", "MPLBACKEND",
         "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
         "PYTEST_XDIST_WORKER", "PYTEST_XDIST_WORKER_COUNT", "PYTEST_ADDOPTS")


def test_a_gui_test_passes_without_a_display_or_qt_variables(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in UNSET}
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", GUI_TEST, "-q", "-n", "0", "-p", "no:cacheprovider",
         "--basetemp", str(tmp_path / "basetemp")],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    output = proc.stdout + proc.stderr
    assert "Fatal Python error" not in output, output[-3000:]
    assert proc.returncode == 0, output[-3000:]
    assert "1 passed" in output, output[-3000:]
