"""Render every main view of the GUI on the simulated bench to PNG (``docs/screenshots``).

:func:`render_all` drives the real window as an operator would — connect the ``sim``
bench, home and move the stages, stream the camera, load a plan, run it (a picture is
taken while it runs), fit the finished run in the browser — and saves each view with
``QWidget.grab()``. ``python docs/screenshots/render.py [FOLDER]`` runs it; a test renders
them and checks that none is blank. Works offscreen (``QT_QPA_PLATFORM=offscreen``).

On a type (i) bench (``--bench sim-type-i``) the stages are its four arm axes and the
pictures are the views that differ from a type (ii) bench's, :data:`TYPE_I_VIEWS`: the
bench panel with the arms' axes and the goniometer view of both arms over the stationary
sample, saved with the suffix ``_type_i``.

:func:`render_polarimetric_planner` takes the plan editor on ``sim-polarimetric`` with the
example dual-rotating-retarder plan and its speed/accuracy trade of the steps per geometry
(``plan_editor_polarimetric.png``); it needs no connected bench (the planner reads the
profile), so ``render.py --only polarimetric`` takes it alone.
"""

from __future__ import annotations

import gc
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from PySide6.QtCore import QEvent, QSettings
from PySide6.QtWidgets import QApplication

from gui.app import create_window
from gui.model.session import Home, MoveTo, SetLight
from gui.qt.main_window import MainWindow
from instrument.bench.kinematics import TYPE_I_AXES

__all__ = ["POLARIMETRIC_VIEW", "TYPE_I_VIEWS", "VIEWS", "render_all",
           "render_polarimetric_planner"]

#: File names (without .png) of the pictures, in the order they are taken.
VIEWS = ("bench", "goniometer", "camera", "plan_editor", "run_in_progress", "run_browser_fit",
         "main_window")
#: The pictures of a type (i) bench (module docstring).
TYPE_I_VIEWS = ("bench", "goniometer")
#: The polarimetric planner's picture (:func:`render_polarimetric_planner`).
POLARIMETRIC_VIEW = "plan_editor_polarimetric"
#: Its plan: the example DRR plan (36 steps per geometry), on the bench it is written for.
POLARIMETRIC_PLAN = Path(__file__).resolve().parents[1] / "examples" / "brdf_polarimetric.toml"

#: Where the stages stand in the bench picture, by role, in the order they are moved: on
#: a type (ii) bench the sample turned and the detector out of the beam; on a type (i)
#: bench the source arm at θi = 40° and the detector arm near the mirror direction, its
#: rail turned 20° out of the plane of incidence (manual moves pass the arms' guard).
POSES = {
    "type_ii": {"detector_theta": 50.0, "sample_theta": 25.0},
    "type_i": {"source_arc": -20.0, "detector_arc": 25.0, "detector_azimuth": 20.0},
}

PLAN = """# the screenshots' scan: in-plane BRDF with dark frames, for a fit
[plan]
kind = "brdf_in_plane"
name = "in-plane BRDF, two incidence angles"
[sample]
name = "sim-grey"
description = "simulated glossy sample of the sim bench"
[scan]
theta_i = [20.0, 45.0]
theta_r = { start = -70.0, stop = 80.0, step = 7.5 }
skip_beam_points = true
[acquisition]
mode = "auto"
exposure_us = 2000
max_exposure_us = 200000
dark = "per_point"
detectors = ["camera", "power_meter"]
"""


def _wait(cond: Callable[[], bool], timeout: float, what: str) -> None:
    app = QApplication.instance()
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError(f"screenshots: timed out waiting for {what}")
        app.processEvents()
        time.sleep(0.01)
    app.processEvents()


def _settle(seconds: float = 0.3) -> None:
    app = QApplication.instance()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        app.processEvents()
        time.sleep(0.01)


def _arrived(session: Any, role: str, target: float) -> bool:
    """Whether ``role`` stands at ``target`` (its read-back), no longer moving."""
    state = session.states()[role]
    return bool(abs(state.value("position") - target) < 0.01 and not state.value("moving"))


def _grab(window: MainWindow, dock: str, path: Path) -> Path:
    d = window.docks[dock]
    d.show()
    d.raise_()
    _settle(0.4)
    if not d.widget().grab().save(str(path)):
        raise OSError(f"could not write {path}")
    return path


def render_all(out_dir: str | Path, *, bench: str = "sim") -> dict[str, Path]:
    """Take every picture of :data:`VIEWS` (:data:`TYPE_I_VIEWS` on a type (i) bench)
    into ``out_dir``; returns name → path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    app = QApplication.instance() or QApplication([])
    work = Path(tempfile.mkdtemp(prefix="scatterlab-screenshots-"))
    settings = QSettings(str(work / "gui.ini"), QSettings.IniFormat)
    window = create_window(bench=bench, out=work / "runs", settings=settings, fsync=False)
    shots: dict[str, Path] = {}
    try:
        window.resize(1680, 1050)
        window.show()
        window.default_sizes()
        window.bench_panel.connect_bench()
        s = window.session
        _wait(lambda: s.connected and len(window.bench_panel.panels) == len(s.states())
              and bool(s.states()), 60, "the bench")
        profile = s.profile
        type_i = profile is not None and profile.geometry.is_type_i
        suffix = "_type_i" if type_i else ""
        pose = POSES["type_i" if type_i else "type_ii"]
        axes = [r for r in (*TYPE_I_AXES, "sample_theta", "detector_theta", "camera_z")
                if r in s.states()]
        for role in axes:
            s.submit(Home(role))
        _wait(lambda: all(s.states()[r].value("homed") and not s.states()[r].value("moving")
                          for r in axes), 120, "homing")
        for role, target in pose.items():  # one after the other: each passes the guard
            s.submit(MoveTo(role, target))
            _wait(partial(_arrived, s, role, target), 60, f"the move of {role}")
        s.submit(SetLight(True))
        _wait(lambda: s.states()["source"].value("on") is True, 20, "the light")
        _settle(0.8)
        shots["bench"] = _grab(window, "bench", out / f"bench{suffix}.png")

        plan_path = work / "screenshot_plan.toml"
        plan_path.write_text(PLAN, encoding="utf-8")
        editor = window.plan_editor
        editor.open_plan(plan_path)
        _wait(lambda: editor.validation is not None and editor.validation.ok, 60,
              "the plan's validation")
        _settle(0.5)
        shots["goniometer"] = _grab(window, "goniometer", out / f"goniometer{suffix}.png")
        if type_i:
            return shots

        cam = window.camera
        cam.stream.click()
        _wait(lambda: cam.shown >= 5, 60, "camera frames")
        _settle(1.2)
        shots["camera"] = _grab(window, "camera", out / "camera.png")
        cam.stream.click()
        _wait(lambda: not s.states()["camera"].value("streaming", False), 20, "stream stop")
        shots["plan_editor"] = _grab(window, "plan", out / "plan_editor.png")

        _wait(editor.start.isEnabled, 30, "Start")
        editor.start.click()
        _wait(lambda: window.current_run is not None, 30, "the run")
        run = window.current_run
        _wait(lambda: run.live.n_received >= max(6, len(run.plan.points) // 2), 300,
              "half the points")
        window.docks["live"].raise_()
        window.docks["run"].raise_()
        _settle(0.5)
        app.processEvents()
        path = out / "run_in_progress.png"
        window.grab().save(str(path))
        shots["run_in_progress"] = path
        _wait(lambda: s.run is None and window.run_control.last_finished is not None, 600,
              "the end of the run")

        browser = window.browser
        browser.refresh()
        _wait(lambda: bool(browser.rows), 30, "the catalog")
        browser.select(browser.rows[0].run_id)
        _wait(lambda: browser.details is not None, 30, "the run's details")
        browser.start_analysis("fit")
        _wait(lambda: browser.outcome is not None and not browser.busy.isVisible(), 600,
              "the fit")
        shots["run_browser_fit"] = _grab(window, "runs", out / "run_browser_fit.png")
        window.docks["goniometer"].raise_()
        window.docks["plan"].raise_()
        _settle(0.5)
        path = out / "main_window.png"
        window.grab().save(str(path))
        shots["main_window"] = path
    finally:
        window.confirm_close_during_run(True)
        window.close()
        _wait(lambda: s.run is None, 60, "the bench to be safe")
        window.deleteLater()
        app.processEvents()
        QApplication.sendPostedEvents(None, QEvent.DeferredDelete)
        gc.collect()
    return shots


def render_polarimetric_planner(out_dir: str | Path) -> Path:
    """The plan editor on ``sim-polarimetric`` with the example DRR plan, its Pareto front
    of the steps per geometry (target mean σ 0.003) and the fastest row reaching it chosen;
    returns the picture's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    app = QApplication.instance() or QApplication([])
    work = Path(tempfile.mkdtemp(prefix="scatterlab-screenshots-"))
    settings = QSettings(str(work / "gui.ini"), QSettings.IniFormat)
    window = create_window(bench="sim-polarimetric", out=work / "runs", settings=settings,
                           fsync=False)
    try:
        window.resize(1680, 1050)
        window.show()
        window.default_sizes()
        editor = window.plan_editor
        editor.open_plan(POLARIMETRIC_PLAN)
        _wait(lambda: editor.validation is not None and editor.validation.ok, 60,
              "the plan's validation")
        editor.target_sigma.setValue(0.003)
        editor.run_planner()
        _wait(lambda: editor.planner_result.text().startswith(("fastest", "no step",
                                                                "planner")), 120,
              "the polarimetric trade")
        best = editor._best
        if best is not None:
            editor.choose_row(next(k for k, r in enumerate(editor._front) if r is best))
        return _grab(window, "plan", out / f"{POLARIMETRIC_VIEW}.png")
    finally:
        window.close()
        window.deleteLater()
        app.processEvents()
        QApplication.sendPostedEvents(None, QEvent.DeferredDelete)
        gc.collect()


def main(out_dir: str | None = None, bench: str = "sim") -> int:
    """Render the screenshots of ``bench`` into ``out_dir`` (default:
    ``docs/screenshots``)."""
    folder = Path(out_dir) if out_dir else Path(__file__).resolve().parents[1] / "docs" / \
        "screenshots"
    for name, path in render_all(folder, bench=bench).items():
        print(f"{name}: {path}")
    return 0
