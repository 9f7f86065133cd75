"""The operator's workflow on a real X display, driven by input events on the real window.

``python -m tests.gui.xcb_smoke BENCH RUNS PLAN SETTINGS SHOTS`` (with ``DISPLAY`` set and
``QT_QPA_PLATFORM=xcb``): opens the main window at its default size, then with mouse
clicks and keys through QTest on the mapped X window — connect, Home all, jog, start,
pause (Space), resume (Space), abort (confirmed), close — and checks after each step that
the screen is not blank and that no visible button is cut off by its parent. Prints one
JSON line: the steps done, the problems found, the screenshots written. Every wait has a
generous timeout and polls a condition; no step depends on the machine's speed.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from PySide6.QtCore import QPoint, QSettings, Qt
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QApplication, QPushButton

#: Seconds any one step may take on a loaded machine before the smoke test gives up.
STEP_TIMEOUT_S = 120.0


def wait(app: QApplication, cond, what: str, timeout: float = STEP_TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out waiting for {what}")
        app.processEvents()
        time.sleep(0.01)


def clipped_buttons(window) -> list[str]:
    """Buttons partly shown: part of them cut off by a parent (a scroll area, a dock too
    narrow, the window's edge). A button wholly hidden (another tab in front) is not."""
    bad = []
    for b in window.findChildren(QPushButton):
        if not b.isVisible() or b.width() == 0:
            continue
        shown = b.visibleRegion().boundingRect()
        if shown.isEmpty():
            continue  # wholly behind another tab of its dock: not shown, not cut off
        if shown.size() != b.size():
            bad.append(f"{b.text() or b.objectName()} ({shown.width()}×{shown.height()} of "
                       f"{b.width()}×{b.height()} shown)")
    return bad


def blank(image) -> bool:
    """A screenshot of one colour (or nearly): nothing drawn."""
    small = image.scaled(64, 40)
    colours = {small.pixel(x, y) for x in range(small.width()) for y in range(small.height())}
    return len(colours) < 8


def click(app, widget) -> None:
    assert widget.isVisible() and widget.isEnabled(), widget.objectName()
    QTest.mouseClick(widget, Qt.LeftButton, Qt.NoModifier, QPoint(widget.width() // 2,
                                                                   widget.height() // 2))
    app.processEvents()


def main(bench: str, runs: str, plan: str, settings_file: str, shots: str) -> int:
    from gui.app import create_window
    from instrument.run.engine import EngineState

    app = QApplication.instance() or QApplication(sys.argv[:1])
    report: dict = {"steps": [], "problems": [], "shots": [], "platform": app.platformName()}
    settings = QSettings(settings_file, QSettings.IniFormat)
    w = create_window(bench=bench, out=runs, settings=settings, fsync=False)
    w.show()
    wait(app, lambda: w.isVisible() and w.windowHandle() is not None
         and w.windowHandle().isExposed(), "the window to be mapped")
    w.activateWindow()

    def shot(name: str) -> None:
        app.processEvents()
        image = app.primaryScreen().grabWindow(0).toImage()  # what the X server shows
        path = Path(shots) / f"{name}.png"
        image.save(str(path))
        report["shots"].append(str(path))
        if blank(image):
            report["problems"].append(f"{name}: the screen is blank")
        cut = clipped_buttons(w)
        if cut:
            report["problems"].append(f"{name}: buttons cut off: {', '.join(cut)}")

    def step(name: str) -> None:
        report["steps"].append(name)
        shot(name)

    try:
        shot("launch")
        click(app, w.bench_panel.connect_button)
        wait(app, lambda: w.session.connected and len(w.bench_panel.panels)
             == len(w.session.states()) > 0, "the bench to connect")
        step("connect")
        click(app, w.home_all_button)
        wait(app, lambda: all(s.value("homed") and not s.value("moving")
                              for s in w.session.states().values()
                              if s.kind == "motion_axis"), "every axis homed")
        step("home all")
        axis = w.bench_panel.panels["detector_theta"]
        before = w.session.states()["detector_theta"].value("position")
        w.docks["bench"].raise_()
        axis.plus.parentWidget().ensurePolished()
        click(app, axis.plus)
        wait(app, lambda: w.session.states()["detector_theta"].value("position") != before
             and not w.session.states()["detector_theta"].value("moving"), "the jog")
        step("jog")
        assert w.plan_editor.open_plan(plan)
        w.docks["plan"].raise_()
        wait(app, w.plan_editor.start.isEnabled, "the plan to validate")
        click(app, w.plan_editor.start)
        wait(app, lambda: w.session.run is not None and w.current_run is not None
             and w.current_run.live.n_received >= 1, "the run's first point")
        run = w.current_run
        step("start")
        w.activateWindow()
        QTest.keyClick(w.run_control.progress, Qt.Key_Space)  # Space pauses
        wait(app, lambda: run.engine.state is EngineState.PAUSED, "the pause")
        step("pause")
        QTest.keyClick(w.run_control.progress, Qt.Key_Space)  # Space resumes
        wait(app, lambda: run.engine.state is EngineState.RUNNING, "the resume")
        step("resume")
        w.questions.answer("abort", True)  # the confirmation box answered Yes
        click(app, w.run_control.abort)
        wait(app, lambda: w.session.run is None and w.run_control.last_finished is not None,
             "the run to end")
        report["run_status"] = w.run_control.last_finished.status
        step("abort")
        w.close()
        wait(app, lambda: not w.isVisible(), "the window to close")
        report["steps"].append("close")
    except (TimeoutError, AssertionError) as err:
        report["problems"].append(f"after {report['steps'][-1:] or 'launch'}: {err}")
        w.confirm_close_during_run(True)
        w.close()
    finally:
        w.session.close(20)
    print(json.dumps(report), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:6]))
