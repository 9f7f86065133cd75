"""From worker threads to Qt signals: the session's reports and the engine's events.

:class:`SessionBridge` is the :class:`gui.model.session.SessionListener` of the GUI. Its
methods are called on the device worker's (or the engine's) thread and only emit
signals; Qt delivers them, queued, to the widgets on the GUI thread. Engine events come
through the run's bounded :class:`instrument.run.events.EventQueue`, drained by a timer
(20 Hz) on the GUI thread, live values coalesced, so a fast run never floods the GUI's
event loop and the worker that drives the hardware never waits for it.
"""

from __future__ import annotations

import shiboken6
from PySide6.QtCore import QObject, QTimer, Signal

from gui.model.session import CommandResult, ConnectionStatus, RunHandle
from instrument.run.events import PointCompleted, Progress

__all__ = ["SessionBridge"]

#: Milliseconds between drains of the engine's event queue.
EVENT_DRAIN_MS = 50


class SessionBridge(QObject):
    """Signals carrying the session's reports to the GUI thread."""

    statesChanged = Signal(object)      # dict[str, DeviceState]
    resultReady = Signal(object)        # CommandResult
    connectionChanged = Signal(object)  # ConnectionStatus
    runChanged = Signal(object)         # RunHandle | None (after its last events)
    engineEvent = Signal(object)        # an instrument.run.events event
    _runChangedRaw = Signal(object)

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._run: RunHandle | None = None
        self._timer = QTimer(self)
        self._timer.setInterval(EVENT_DRAIN_MS)
        self._timer.timeout.connect(self.drain)
        self._runChangedRaw.connect(self._on_run_changed)

    # SessionListener (worker threads) ---------------------------------------------
    def states(self, states) -> None:
        self._emit(self.statesChanged, states)

    def result(self, result: CommandResult) -> None:
        self._emit(self.resultReady, result)

    def connection(self, status: ConnectionStatus) -> None:
        self._emit(self.connectionChanged, status)

    def run_changed(self, run: RunHandle | None) -> None:
        self._emit(self._runChangedRaw, run)

    def _emit(self, signal, value) -> None:
        # The worker may report once more after the window closed and Qt destroyed this
        # bridge (a run handed back during shutdown): nobody is left to tell, and raising
        # on the worker's thread would only end the worker that is making the bench safe.
        if shiboken6.isValid(self):
            signal.emit(value)

    # GUI thread ---------------------------------------------------------------------
    @property
    def run(self) -> RunHandle | None:
        return self._run

    def drain(self) -> int:
        """Emit the queued engine events of the current run; return how many were queued.

        Live values are coalesced: of the :class:`Progress` events only the newest is
        emitted, and :class:`PointCompleted` not at all (the live plots read every point
        from the run's :class:`gui.model.live.LiveData`); lifecycle events all, in order.
        """
        run = self._run
        if run is None:
            return 0
        events = run.events.drain()
        last_progress = max((k for k, ev in enumerate(events) if isinstance(ev, Progress)),
                            default=-1)
        for k, ev in enumerate(events):
            if isinstance(ev, PointCompleted) or (isinstance(ev, Progress)
                                                  and k != last_progress):
                continue
            self.engineEvent.emit(ev)
        return len(events)

    def _on_run_changed(self, run: RunHandle | None) -> None:
        if run is None:
            self.drain()  # the run's last events (RunFinished) before it is gone
            self._timer.stop()
        self._run = run
        if run is not None:
            self._timer.start()
        self.runChanged.emit(run)
