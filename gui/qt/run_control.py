"""Run control: start/pause/resume/abort, progress and ETA, the fault panel and the
operator's choice after a fault (retry, skip the point, abort)."""

from __future__ import annotations

import time

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QBrush, QColor, QGuiApplication
from PySide6.QtWidgets import (
    QAbstractItemView,
    QFrame,
    QHBoxLayout,
    QLabel,
    QProgressBar,
    QPushButton,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from gui.model import format as fmt
from gui.model.faults import FaultLog, PauseState, Recovery, point_number, recovery_for
from gui.model.live import ProgressClock
from gui.model.session import BenchSession, RunHandle
from gui.qt.ask import Questions
from gui.qt.tables import fit_columns
from instrument.run.events import (
    Event,
    Fault,
    Paused,
    Progress,
    Resumed,
    RunFinished,
    RunStarted,
)

__all__ = ["FaultPanel", "RunControl"]

SEVERITY_COLOURS = {"info": "#e3f2fd", "warning": "#fff3e0", "error": "#ffebee"}


class FaultPanel(QWidget):
    """Every fault event of the run: time, point, device, cause, action, meaning."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("fault_panel")
        self.log = FaultLog()
        self.table = QTableWidget(0, 6)
        self.table.setObjectName("faults")
        self.table.setHorizontalHeaderLabels(["time", "point", "device", "cause", "action",
                                              "what it means"])
        self.table.horizontalHeaderItem(1).setToolTip(
            "the point's number as the progress counts it (from 1)")
        self.table.setEditTriggers(QAbstractItemView.NoEditTriggers)
        self.table.setSelectionBehavior(QAbstractItemView.SelectRows)
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.setWordWrap(True)
        fit_columns(self.table)
        self.copy = QPushButton("Copy")
        self.copy.clicked.connect(self.copy_selected)
        self.summary = QLabel("no faults")
        self.summary.setObjectName("fault_summary")
        row = QHBoxLayout()
        row.addWidget(self.summary, 1)
        row.addWidget(self.copy)
        lay = QVBoxLayout(self)
        lay.addLayout(row)
        lay.addWidget(self.table, 1)

    def add(self, ev: Fault) -> None:
        row = self.log.add(ev)
        k = self.table.rowCount()
        if k >= self.log.maxlen:
            self.table.removeRow(0)
            k -= 1
        self.table.insertRow(k)
        cells = (time.strftime("%H:%M:%S", time.localtime(row.time)),
                 point_number(row.index), row.device, row.cause,
                 row.action, row.meaning)
        brush = QBrush(QColor(SEVERITY_COLOURS[row.severity]))
        for j, text in enumerate(cells):
            item = QTableWidgetItem(text)
            item.setBackground(brush)
            item.setToolTip(text)
            self.table.setItem(k, j, item)
        self.table.scrollToBottom()
        self.summary.setText(f"{self.log.total} fault event(s)")

    def clear(self) -> None:
        self.log.clear()
        self.table.setRowCount(0)
        self.summary.setText("no faults")

    def rows(self) -> list[tuple[str, ...]]:
        return [tuple(self.table.item(r, c).text() for c in range(6))
                for r in range(self.table.rowCount())]

    def copy_selected(self) -> str:
        rows = sorted({i.row() for i in self.table.selectedItems()}) or \
            list(range(self.table.rowCount()))
        text = "\n".join("\t".join(self.table.item(r, c).text() for c in range(6))
                         for r in rows)
        QGuiApplication.clipboard().setText(text)
        return text


class RunControl(QWidget):
    """State, progress with ETA, pause/resume/abort, and the recovery choice."""

    finished = Signal(object)  # RunFinished

    def __init__(self, session: BenchSession, fault_panel: FaultPanel,
                 parent: QWidget | None = None, *, questions: Questions | None = None
                 ) -> None:
        super().__init__(parent)
        self.setObjectName("run_control")
        self.session = session
        self.questions = questions or Questions()
        self.clock = ProgressClock()
        self.faults = fault_panel
        self.run: RunHandle | None = None
        self.pause_state: PauseState | None = None
        self.last_finished: RunFinished | None = None
        self._last_fault: Fault | None = None
        self.state = QLabel("no run")
        self.state.setObjectName("run_state")
        self.state.setWordWrap(True)
        self.state.setTextInteractionFlags(Qt.TextSelectableByMouse)
        self.progress = QProgressBar()
        self.progress.setObjectName("progress")
        self.progress.setRange(0, 1)
        self.progress.setValue(0)
        self.eta = QLabel("")
        self.eta.setObjectName("eta")
        self.pause = QPushButton("Pause  (Space)")
        self.pause.setObjectName("pause")
        self.resume = QPushButton("Resume  (Space)")
        self.resume.setObjectName("resume")
        self.abort = QPushButton("Abort")
        self.abort.setObjectName("abort")
        buttons = QHBoxLayout()
        for b in (self.pause, self.resume, self.abort):
            buttons.addWidget(b)
        self.recovery = QFrame()
        self.recovery.setObjectName("recovery")
        self.recovery.setFrameShape(QFrame.StyledPanel)
        self.recovery.setStyleSheet("#recovery { background: #fff8e1; border: 1px solid "
                                    "#ffb300 }")
        self.question = QLabel("")
        self.question.setObjectName("question")
        self.question.setWordWrap(True)
        self.retry = QPushButton("Retry the point")
        self.retry.setObjectName("retry")
        self.skip = QPushButton("Skip the point")
        self.skip.setObjectName("skip")
        self.abort_run = QPushButton("Abort the run")
        self.abort_run.setObjectName("abort_run")
        rl = QVBoxLayout(self.recovery)
        rl.addWidget(self.question)
        rb = QHBoxLayout()
        for b in (self.retry, self.skip, self.abort_run):
            rb.addWidget(b)
        rl.addLayout(rb)
        self.recovery.hide()
        lay = QVBoxLayout(self)
        lay.addWidget(self.state)
        lay.addWidget(self.progress)
        lay.addWidget(self.eta)
        lay.addLayout(buttons)
        lay.addWidget(self.recovery)
        lay.addStretch(1)
        self.pause.clicked.connect(self.session.pause_run)
        self.resume.clicked.connect(lambda: self.session.resume_run())
        self.abort.clicked.connect(self.confirm_abort)
        self.retry.clicked.connect(lambda: self.choose(Recovery.RETRY))
        self.skip.clicked.connect(lambda: self.choose(Recovery.SKIP))
        self.abort_run.clicked.connect(lambda: self.choose(Recovery.ABORT))
        self._buttons(None)

    def confirm_abort(self) -> bool:
        """Abort the run after asking (the points not yet measured are lost to this
        session; *Stop all* and Esc abort at once, they are the safety path)."""
        run = self.session.run
        if run is None:
            return False
        done, total = run.engine.n_done, len(run.plan.points)
        if not self.questions.ask(
                "abort", self, "Abort the run?",
                f"Abort run {run.path.name}? {done} of {total} points are measured.\n\n"
                "Motion stops, the light goes off and the file is closed; it stays valid, "
                "and Resume this run (Runs dock) measures the missing points later."):
            return False
        return self.session.abort_run()

    def choose(self, choice: Recovery) -> None:
        """Carry out the operator's choice after a pause."""
        if choice is Recovery.ABORT:
            if not self.confirm_abort():
                return
        elif choice is Recovery.SKIP:
            self.session.resume_run(skip_point=True)
        else:
            self.session.resume_run()
        self.recovery.hide()

    def _buttons(self, state: str | None) -> None:
        self.pause.setEnabled(state == "running")
        self.resume.setEnabled(state == "paused")
        self.abort.setEnabled(state in ("running", "paused"))

    # from the main window ---------------------------------------------------------
    def on_run(self, run: RunHandle | None) -> None:
        if run is not None:
            self.run = run
            self.faults.clear()
            self._last_fault = None
            self.pause_state = None
            self.progress.setRange(0, max(1, len(run.plan.points)))
            self.progress.setValue(run.engine.n_done)
            self.state.setText(f"starting {run.path.name} …")
            self._buttons("running")
        else:
            self._buttons(None)

    def on_event(self, ev: Event) -> None:
        match ev:
            case RunStarted():
                self.clock.start(ev.n_done)
                self.progress.setRange(0, max(1, ev.n_total))
                self.progress.setValue(ev.n_done)
                what = "resumed" if ev.n_done else "running"
                self.state.setText(f"{what}: {ev.plan_kind} run {ev.run_id}, {ev.n_total} "
                                   f"points, estimated {fmt.duration(ev.estimated_s)}")
                self._buttons("running")
            case Progress():
                self.progress.setValue(ev.n_done)
                elapsed, left = self.clock.times(ev)  # pauses left out of both
                paused = self.clock.paused_s()
                note = f" (paused {fmt.duration(paused)} not counted)" if paused >= 1 else ""
                self.eta.setText(f"{ev.n_done}/{ev.n_total} points, elapsed "
                                 f"{fmt.duration(elapsed)}, ETA {fmt.duration(left)}{note}")
            case Fault():
                self._last_fault = ev
                self.faults.add(ev)
            case Paused():
                self.clock.paused()
                self.pause_state = recovery_for(ev, self._last_fault)
                self.state.setText(f"paused: {ev.reason}")
                self._buttons("paused")
                if self.pause_state.kind.value != "operator":
                    self.question.setText(self.pause_state.question)
                    self.skip.setVisible(Recovery.SKIP in self.pause_state.choices)
                    self.recovery.show()
            case Resumed():
                self.clock.resumed()
                self.pause_state = None
                self.recovery.hide()
                self.state.setText("running")
                self._buttons("running")
            case RunFinished():
                self.last_finished = ev
                self.recovery.hide()
                self.progress.setValue(ev.n_done)
                extra = f", {ev.n_skipped} skipped" if ev.n_skipped else ""
                note = f" — {ev.message}" if ev.message else ""
                resume = "" if ev.status == "finished" else " (resume it from the run browser)"
                self.state.setText(f"run {ev.status}: {ev.n_done} of {ev.n_total} points in "
                                   f"{fmt.duration(ev.elapsed_s)}{extra}{note}. File "
                                   f"{ev.path}{resume}")
                self.eta.setText("")
                self._buttons(None)
                self.finished.emit(ev)
