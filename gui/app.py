"""Start the operator GUI: ``scatterlab gui [--bench PROFILE] [--out FOLDER]``.

:func:`create_window` builds the window and its collaborators (bench session, bridge,
settings) and is what the tests, the screenshot script and the benchmark use;
:func:`main` adds the application and its event loop. It opens on the simulated bench
(``sim``) unless told otherwise or a bench was used last time, and connects it.
"""

from __future__ import annotations

import gc
import sys
from collections.abc import Callable
from pathlib import Path

from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QApplication

from gui.model.session import BenchSession
from gui.qt.bridge import SessionBridge
from gui.qt.main_window import MainWindow
from instrument.bench.devices import Bench, open_bench
from instrument.bench.profile import BenchProfile
from instrument.run.runner import DEFAULT_RUNS_DIR

__all__ = ["create_window", "main"]

ORGANIZATION = "scatterlab"
APPLICATION = "scatterlab-gui"


def create_window(*, bench: str | None = None, out: str | Path | None = None,
                  settings: QSettings | None = None,
                  opener: Callable[[BenchProfile], Bench] = open_bench,
                  fsync: bool = True, connect: bool = False) -> MainWindow:
    """The main window on a new bench session (a QApplication must exist).

    ``bench`` is a built-in profile name or a profile file; ``out`` the folder of run files
    and the catalog; ``opener`` opens a profile's devices (tests pass an in-process
    bench); with ``connect`` the chosen bench is connected at once.
    """
    bridge = SessionBridge()
    session = BenchSession(bridge, opener=opener, fsync=fsync)
    settings = settings if settings is not None else QSettings(ORGANIZATION, APPLICATION)
    runs_dir = Path(out) if out is not None else Path(
        str(settings.value("runs_dir", str(DEFAULT_RUNS_DIR))))
    window = MainWindow(session, bridge, settings=settings, runs_dir=runs_dir, bench=bench)
    bridge.setParent(window)
    if connect:
        window.bench_panel.connect_bench()
    return window


def main(*, bench: str | None = None, out: str | None = None) -> int:
    """Run the GUI until its window closes; returns the exit status."""
    app = QApplication.instance() or QApplication(sys.argv[:1])
    app.setOrganizationName(ORGANIZATION)
    app.setApplicationName(APPLICATION)
    window = create_window(bench=bench, out=out, connect=True)
    if out is not None:
        window.settings.setValue("runs_dir", str(out))
    window.show()
    status = app.exec()
    # Destroy the widgets while Qt and Python are both alive (a pyqtgraph view left to
    # the interpreter's final garbage collection can crash it).
    window.deleteLater()
    app.processEvents()
    del window
    gc.collect()
    return int(status)
