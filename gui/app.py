"""Start the operator GUI: ``scatterlab gui [--server URL | --in-process] [--bench PROFILE]
[--out FOLDER]``.

:func:`main` is the GUI as a client of the bench server (docs/decisions/0084): it opens a
:class:`gui.qt.client_window.ClientWindow` on the server named by ``--server`` or
``SCATTERLAB_SERVER`` (key: ``SCATTERLAB_KEY``), or on the local server of the runs
folder, started as a child process for the chosen bench (``sim`` unless told otherwise or
a bench was used last time) when none is running. The engine never runs in the GUI's
process. Closing the window leaves a run going on the server; a local server with no run
going is stopped.

:func:`main_in_process` (``scatterlab gui --in-process``) opens the full in-process
window instead, the engine in the GUI's process: the fallback for what the client window
does not show yet. :func:`create_window` builds that window (bench session, bridge,
settings); the GUI's widget tests, the screenshot script and the in-process benchmark run
on it.
"""

from __future__ import annotations

import gc
import os
import sys
from collections.abc import Callable
from pathlib import Path

from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QApplication, QMainWindow

from gui.model.session import BenchSession
from gui.qt.bridge import SessionBridge
from gui.qt.client_window import ClientWindow
from gui.qt.main_window import MainWindow
from instrument.bench.devices import Bench, open_bench
from instrument.bench.profile import BenchProfile
from instrument.client import ENV_KEY, server_from_env
from instrument.client.local import LocalServer, LocalServerError, local_server
from instrument.run.runner import DEFAULT_RUNS_DIR

__all__ = ["create_window", "main", "main_in_process"]

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


def main(*, bench: str | None = None, out: str | None = None, server: str | None = None,
         key: str | None = None, say: Callable[[str], None] = print) -> int:
    """Run the GUI, a client of the bench server, until its window closes; returns the
    exit status."""
    app = _application()
    settings = QSettings(ORGANIZATION, APPLICATION)
    key = key or os.environ.get(ENV_KEY) or None
    url = server or server_from_env()
    local = None
    note = ""
    if url is None:
        runs_dir = Path(out) if out is not None else Path(
            str(settings.value("runs_dir", str(DEFAULT_RUNS_DIR))))
        profile = bench or str(settings.value("bench", "sim"))
        try:
            local = local_server(profile, runs_dir, key=key)
        except LocalServerError as err:
            say(f"error: {err}")
            return 2
        url = local.url
        note = (f"Local server (process {local.pid}, bench {local.bench!r}"
                f"{', started now' if local.started else ''}): closing this window "
                "leaves a run going on it; `scatterlab gui --stop-server` stops it.")
        settings.setValue("runs_dir", str(runs_dir))
        settings.setValue("bench", profile)
    after = None if local is None else (lambda w: say(_after_close(w, local)))
    return _exec(app, ClientWindow(url, key, note=note), after)


def main_in_process(*, bench: str | None = None, out: str | None = None,
                    settings: QSettings | None = None) -> int:
    """Run the full in-process window (``scatterlab gui --in-process``) until it closes:
    the engine runs in the GUI's process, with the goniometer drawing, camera settings
    and per-device panels that the client window does not show yet (docs/decisions/0084).
    Closing the window ends a run (resumable). ``settings``: the window's settings (default:
    the user's). Returns the exit status."""
    app = _application()
    window = create_window(bench=bench, out=out, settings=settings, connect=True)
    if out is not None:
        window.settings.setValue("runs_dir", str(out))
    return _exec(app, window)


def _application() -> QApplication:
    app = QApplication.instance() or QApplication(sys.argv[:1])
    app.setOrganizationName(ORGANIZATION)
    app.setApplicationName(APPLICATION)
    return app


def _exec(app: QApplication, window: QMainWindow,
          after: Callable[[QMainWindow], None] | None = None) -> int:
    """Show the window, run the event loop until it closes, then ``after(window)``."""
    window.show()
    status = app.exec()
    if after is not None:
        after(window)
    # Destroy the widgets while Qt and Python are both alive (a pyqtgraph view left to
    # the interpreter's final garbage collection can crash it).
    window.deleteLater()
    app.processEvents()
    del window
    gc.collect()
    return int(status)


def _after_close(window: ClientWindow, local: LocalServer) -> str:
    """Stop the local server unless a run is going on it; say which."""
    st = window.state
    busy = (st.run is not None and st.run.alive) or st.queue_running or not st.stream_up
    if busy:
        return (f"the local server (process {local.pid}) at {local.url} keeps running the "
                "run; reopen the GUI to watch it, `scatterlab gui --stop-server` stops it")
    local.stop()
    return f"stopped the local server (process {local.pid}): no run was going"
