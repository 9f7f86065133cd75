"""GUI-test fixtures: the main window on a simulated bench, with its own settings file."""

from __future__ import annotations

import gc
import time

import pytest

pytest.importorskip("pytestqt")

from PySide6.QtCore import QEvent, QSettings, Qt
from PySide6.QtWidgets import QApplication

from tests.gui.helpers import fast_profile


@pytest.fixture
def fast_bench_file(tmp_path):
    """The built-in `sim` bench with fast stage clocks, as a profile file."""

    def make(name: str = "sim", speed: int = 200):
        path = tmp_path / f"{name}-fast.toml"
        path.write_text(fast_profile(name, speed).source_text, encoding="utf-8")
        return str(path)

    return make


@pytest.fixture
def settings(tmp_path):
    return QSettings(str(tmp_path / "gui.ini"), QSettings.IniFormat)


@pytest.fixture
def make_window(qtbot, tmp_path, settings):
    """Build the main window (not yet connected); closes it and its session afterwards."""
    from gui.app import create_window

    windows = []

    def make(bench: str | None = None, **kw):
        kw.setdefault("out", tmp_path / "runs")
        kw.setdefault("settings", settings)
        kw.setdefault("fsync", False)
        w = create_window(bench=bench, **kw)
        # pytest-qt closes its widgets before this fixture's teardown: a window closed with a
        # run going would ask "Close anyway?" in a modal box that nobody answers.
        qtbot.addWidget(w, before_close_func=lambda w: w.confirm_close_during_run(True))
        w.show()
        windows.append(w)
        return w

    yield make
    for w in windows:
        w.confirm_close_during_run(True)
        w.close()
        qtbot.waitUntil(lambda w=w: not w.session.run, timeout=60000)
        w.session.close(20)
        w.deleteLater()
    flush_deleted()


def flush_deleted() -> None:
    """Destroy widgets scheduled for deletion now, while Qt and Python are both alive (a
    pyqtgraph view left to the interpreter's last garbage collection can crash it)."""
    app = QApplication.instance()
    if app is not None:
        app.processEvents()
        QApplication.sendPostedEvents(None, QEvent.DeferredDelete)
    gc.collect()


# A modal dialog left open this long is one that the test does not answer (tests that
# answer one do so within a second or two of it opening).
UNANSWERED_DIALOG_S = 20.0


@pytest.fixture(autouse=True)
def _unanswered_modal_dialogs_fail(request):
    """Close a modal dialog that nobody answers, and fail the test that left it.

    A modal dialog runs Qt's nested event loop, in which Python's signal handlers do not
    run: pytest-timeout cannot interrupt it, and the test (and the whole suite) would wait
    for ever. A Qt timer does fire in that loop, so it rejects the dialog instead."""
    if "qtbot" not in request.fixturenames:
        yield
        return
    from PySide6.QtCore import QTimer

    request.getfixturevalue("qapp")
    left_open: list[str] = []
    seen: dict[int, float] = {}

    def look() -> None:
        dialog = QApplication.activeModalWidget()
        if dialog is None:
            seen.clear()
            return
        opened = seen.setdefault(id(dialog), time.monotonic())
        if time.monotonic() - opened > UNANSWERED_DIALOG_S:
            left_open.append(f"{type(dialog).__name__} {dialog.windowTitle()!r}")
            seen.pop(id(dialog), None)
            dialog.close()

    timer = QTimer()
    timer.setInterval(500)
    timer.timeout.connect(look)
    timer.start()
    yield
    timer.stop()
    assert not left_open, f"modal dialogs left unanswered by the test: {left_open}"


@pytest.fixture(scope="session", autouse=True)
def _destroy_widgets_before_exit():
    yield
    flush_deleted()


def mouse_click(qtbot, widget) -> None:
    """Click ``widget`` with the mouse once it is laid out (a button that a busy machine has
    not yet given its height is a zero-sized rectangle: a click there reaches nothing)."""
    qtbot.waitUntil(lambda: widget.isVisible() and not widget.rect().isEmpty(), timeout=60000)
    qtbot.mouseClick(widget, Qt.LeftButton)


def connect(qtbot, window, timeout: int = 60000) -> None:
    """Click Connect and wait until every device has its panel."""
    window.bench_panel.connect_button.click()
    qtbot.waitUntil(lambda: window.session.connected and bool(window.bench_panel.panels)
                    and len(window.bench_panel.panels) == len(window.session.states()),
                    timeout=timeout)
