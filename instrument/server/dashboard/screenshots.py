"""Pictures of the dashboard for the guide (``docs/screenshots/dashboard_*.png``).

:func:`render_dashboard` does what a lab would: ``scatterlab serve`` on the simulated bench
with an operator's and an observer's key, the operator queues two camera scans and starts
the queue; pictures are taken in a real Chromium (:mod:`.chromium`) of the operator's page
while the first scan runs, of the observer's page (greyed buttons, with the reason), and
of the first scan's fit report opened in the run browser once ``fit`` has written it.
``python docs/screenshots/render.py [FOLDER]`` runs it after the GUI's pictures.
"""

from __future__ import annotations

import contextlib
import re
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["DASHBOARD_VIEWS", "render_dashboard", "serve_sim"]

#: File names (without .png) of the pictures, in the order they are taken.
DASHBOARD_VIEWS = ("dashboard_run", "dashboard_observer", "dashboard_report")

PLAN = """# the dashboard screenshots' scan: in-plane BRDF with dark frames, for a fit
[plan]
kind = "brdf_in_plane"
name = "in-plane BRDF, two incidence angles"
[sample]
name = "sim-grey"
[scan]
theta_i = [20.0, 45.0]
theta_r = {{ start = -70.0, stop = 80.0, step = {step} }}
skip_beam_points = true
[acquisition]
mode = "auto"
exposure_us = 2000
max_exposure_us = 200000
dark = "per_point"
detectors = ["camera", "power_meter"]
"""


def _wait(cond: Callable[[], object], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError(f"dashboard screenshots: timed out waiting for {what}")
        time.sleep(0.2)


def serve_sim(runs: Path) -> tuple[subprocess.Popen[str], str]:
    """``scatterlab serve --bench sim`` on a free loopback port: the process, its URL."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "instrument.cli", "serve", "--bench", "sim", "--runs",
         str(runs), "--listen", "127.0.0.1:0", "--no-fsync"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert proc.stdout is not None  # stdout=PIPE
    lines = []
    for line in proc.stdout:
        lines.append(line)
        m = re.search(r"on (http://127\.0\.0\.1:\d+)", line)
        if m:
            # keep reading its output so that a full pipe never blocks it
            threading.Thread(target=proc.stdout.read, daemon=True).start()
            return proc, m.group(1)
    raise RuntimeError("the server did not start:\n" + "".join(lines))


def render_dashboard(out_dir: str | Path) -> dict[str, Path]:
    """Take every picture of :data:`DASHBOARD_VIEWS` into ``out_dir``."""
    from instrument.client import BenchClient
    from instrument.pipelines.brdf.pipeline import fit_run
    from instrument.server.dashboard.chromium import browser, sign_in, wait_run_state
    from instrument.server.db import ServerDB
    from instrument.server.keys import KeyStore

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="scatterlab-dashboard-shots-"))
    runs = work / "runs"
    with ServerDB(runs) as db:
        store = KeyStore(db)
        operator = store.add("ada", "operator")[1]
        observer = store.add("olga", "observer")[1]
    proc, url = serve_sim(runs)
    shots: dict[str, Path] = {}
    try:
        with browser() as new_page, BenchClient(url, operator) as ada:
            page = new_page(work / "operator", height=1000)
            sign_in(page, url, operator)
            obs = new_page(work / "observer", height=1000)  # watching from the start
            sign_in(obs, url, observer)
            ada.add_plan(PLAN.format(step=7.5), "grey sample, fine steps")
            ada.add_plan(PLAN.format(step=15.0), "grey sample, coarse check")
            page.click("#queue-start")
            wait_run_state(page, "running")
            _wait(lambda: (ada.status()["run"] or {}).get("n_done", 0) >= 16, 900,
                  "points of the first scan")
            page.wait_for_function("() => document.getElementById('frame').hidden === false")
            time.sleep(1.0)  # the next redraw (5 a second) has the newest values
            shots["dashboard_run"] = _shot(page, out / "dashboard_run.png")
            shots["dashboard_observer"] = _shot(obs, out / "dashboard_observer.png")
            obs.context.close()
            ada.stop_queue()  # the first scan goes on to its end; the second waits
            # the history row lands a moment after the run leaves the status
            _wait(lambda: ada.status()["run"] is None and bool(ada.history()), 1800,
                  "the end of the first scan")
            (first,) = ada.history()
            fit_run(first["run_file"])
            page.click("#runs-refresh")
            row = page.locator("#runs tbody tr", has_text=Path(first["run_file"]).name)
            row.locator(".open-report").click()
            page.wait_for_selector("#report:not([hidden])")
            page.locator("#report").scroll_into_view_if_needed()
            time.sleep(1.0)
            path = out / "dashboard_report.png"
            page.locator("#runs-panel").screenshot(path=str(path))
            shots["dashboard_report"] = path
    finally:
        with contextlib.suppress(ProcessLookupError):
            proc.terminate()
        proc.wait(120)
    return shots


def _shot(page: Any, path: Path) -> Path:
    page.screenshot(path=str(path), full_page=True)
    return path
