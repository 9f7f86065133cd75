"""The operator's main window: docks around the bench, an always-visible Stop all.

The window receives its collaborators (the session, its bridge, the settings store, the
runs folder) in the constructor, so tests build it on any bench with no patching.

Keyboard: **Esc** stops all motion (during a run: aborts it, the engine makes the bench
safe) from anywhere in the application; **Space** pauses or resumes the run unless a text
or number field has the focus (where a space is typed); the rest is listed by *Help →
Keyboard shortcuts* (:data:`SHORTCUTS`). Layout, window geometry, the last bench and the
last folders are kept in ``QSettings``.

Nothing reaches a different bench than the operator chose: resuming a run recorded on
another bench (or with none connected) asks before it connects the run's bench, and an
answer of *No* leaves the bench as it is.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from PySide6.QtCore import QByteArray, QEvent, QObject, QSettings, Qt, QTimer
from PySide6.QtGui import QAction, QCloseEvent, QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QAbstractSpinBox,
    QApplication,
    QComboBox,
    QDockWidget,
    QFileDialog,
    QLabel,
    QLineEdit,
    QMainWindow,
    QPlainTextEdit,
    QPushButton,
    QTextEdit,
    QToolBar,
    QWidget,
)

from gui.model.analyses import resume_refusal
from gui.model.remedies import event_for_gui, for_gui
from gui.model.session import (
    BenchSession,
    CommandResult,
    Connect,
    ConnectionStatus,
    Home,
    ResumeRun,
    RunHandle,
    StartRun,
)
from gui.qt.ask import Questions
from gui.qt.background import Background
from gui.qt.bench_panel import BenchPanel
from gui.qt.bridge import SessionBridge
from gui.qt.camera_view import CameraView
from gui.qt.goniometer_view import GoniometerView
from gui.qt.help_dialogs import about_html, shortcuts_html, text_dialog
from gui.qt.live_plot import LivePlot
from gui.qt.log_dock import LogDock
from gui.qt.plan_editor import PlanEditor
from gui.qt.run_browser import RunBrowser
from gui.qt.run_control import FaultPanel, RunControl
from gui.qt.wheel import install_wheel_guard
from instrument.bench.device_state import DeviceState
from instrument.bench.profile import ProfileError, load_profile, parse_profile

__all__ = ["SHORTCUTS", "MainWindow", "homed_positions", "unhomed_axes"]

#: Bump when the dock set changes: an old saved layout is then ignored.
LAYOUT_VERSION = 1

#: Every keyboard shortcut of the window (Help → Keyboard shortcuts shows this list).
SHORTCUTS = (
    ("Esc", "Stop every axis now; during a run: abort it (from anywhere)"),
    ("Space", "Pause a running run, resume a paused one (not while typing in a field)"),
    ("Ctrl+H", "Home all axes"),
    ("Ctrl+R", "Choose the runs folder"),
    ("Ctrl+Q", "Quit (asks first during a run)"),
    ("F1", "This list of shortcuts"),
)


def homed_positions(states: dict[str, DeviceState]) -> dict[str, float]:
    """Positions of the homed axes (an unhomed axis's counter is not a position)."""
    return {r: float(s.values["position"]) for r, s in states.items()
            if s.kind == "motion_axis" and s.values.get("homed")
            and s.values.get("position") is not None}


def unhomed_axes(states: dict[str, DeviceState]) -> list[str]:
    """The axes that read back not homed (homing in progress counts as not yet)."""
    return [r for r, s in states.items()
            if s.kind == "motion_axis" and s.error is None and not s.values.get("homed")]


class MainWindow(QMainWindow):
    """Docks: bench, goniometer, camera, plan, run, live plot, runs, log."""

    def __init__(self, session: BenchSession, bridge: SessionBridge, *,
                 settings: QSettings, runs_dir: Path, bench: str | None = None,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.session = session
        self.bridge = bridge
        self.settings = settings
        self.runs_dir = Path(runs_dir)
        self.setWindowTitle("scatterlab")
        self.setObjectName("main_window")
        self.setDockNestingEnabled(True)
        self.docks: dict[str, QDockWidget] = {}
        self.current_run: RunHandle | None = None  # the running run, or the last one
        self._closing = False
        self.questions = Questions()
        self.dialogs: dict[str, QWidget] = {}

        # Stop all: a toolbar that cannot be hidden, moved or floated away
        bar = QToolBar("Safety")
        bar.setObjectName("safety_toolbar")
        bar.setMovable(False)
        bar.setFloatable(False)
        bar.toggleViewAction().setEnabled(False)
        bar.setContextMenuPolicy(Qt.PreventContextMenu)
        self.stop_button = QPushButton("STOP ALL  (Esc)")
        self.stop_button.setObjectName("stop_all")
        self.stop_button.setMinimumHeight(36)
        self.stop_button.setStyleSheet(
            "QPushButton { background: #c62828; color: white; font-weight: 700; "
            "padding: 4px 18px; border-radius: 4px } QPushButton:pressed { background: #8e0000 }")
        self.stop_button.setToolTip("stop every axis now; during a run: abort it "
                                    "(motion stopped, light off, file finalised)")
        self.stop_button.clicked.connect(self.stop_all)
        bar.addWidget(self.stop_button)
        self.home_all_action = QAction("Home all", self)
        self.home_all_action.setObjectName("home_all")
        self.home_all_action.setShortcut(QKeySequence("Ctrl+H"))
        self.home_all_action.setToolTip("home every axis of the connected bench (Ctrl+H)")
        self.home_all_action.setEnabled(False)
        self.home_all_action.triggered.connect(self.home_all)
        self.home_all_button = QPushButton("Home all")
        self.home_all_button.setObjectName("home_all_button")
        self.home_all_button.setMinimumHeight(36)
        self.home_all_button.setToolTip(self.home_all_action.toolTip())
        self.home_all_button.setEnabled(False)
        self.home_all_button.clicked.connect(self.home_all)
        bar.addWidget(self.home_all_button)
        # a first-time operator is told to home: axes that are not homed cannot move
        self.home_hint = QLabel("")
        self.home_hint.setObjectName("home_hint")
        self.home_hint.setStyleSheet("color: #e65100; font-weight: 600; padding: 0 8px")
        bar.addWidget(self.home_hint)
        self.run_label = QLabel("")
        self.run_label.setObjectName("run_label")
        bar.addSeparator()
        bar.addWidget(self.run_label)
        self.addToolBar(Qt.TopToolBarArea, bar)
        self.safety_toolbar = bar

        self.escape = QShortcut(QKeySequence(Qt.Key_Escape), self)
        self.escape.setContext(Qt.ApplicationShortcut)
        self.escape.activated.connect(self.stop_all)

        self.bench_panel = BenchPanel(session)
        self.add_dock("bench", "Bench", self.bench_panel, Qt.LeftDockWidgetArea)

        bridge.statesChanged.connect(self.bench_panel.on_states)
        bridge.connectionChanged.connect(self._on_connection)
        bridge.resultReady.connect(self._on_result)
        bridge.runChanged.connect(self._on_run)
        self.bench_panel.benchChosen.connect(lambda b: self.settings.setValue("bench", b))

        self._file_menu = self.menuBar().addMenu("&File")
        self._bench_menu = self.menuBar().addMenu("&Bench")
        self._views_menu = self.menuBar().addMenu("&View")
        self._help_menu = self.menuBar().addMenu("&Help")
        self._build_views()
        self._build_menus()

        self._default_state = self.saveState(LAYOUT_VERSION)
        self._restore(bench)
        QApplication.instance().installEventFilter(self)
        install_wheel_guard()  # no set-point changes under a scrolling wheel
        self.browser.refresh()

    # docks ---------------------------------------------------------------------------
    def add_dock(self, name: str, title: str, widget: QWidget,
                 area: Qt.DockWidgetArea) -> QDockWidget:
        dock = QDockWidget(title, self)
        dock.setObjectName(f"dock_{name}")
        dock.setWidget(widget)
        dock.setFeatures(QDockWidget.DockWidgetMovable | QDockWidget.DockWidgetFloatable
                         | QDockWidget.DockWidgetClosable)
        self.addDockWidget(area, dock)
        self.docks[name] = dock
        return dock

    def _build_views(self) -> None:
        """The views beside the bench panel."""
        self.background = Background(workers=2, parent=self)
        self.goniometer = GoniometerView()
        self.add_dock("goniometer", "Goniometer", self.goniometer, Qt.RightDockWidgetArea)
        self.camera = CameraView(self.session, self.background)
        self.add_dock("camera", "Camera", self.camera, Qt.RightDockWidgetArea)
        self.live_plot = LivePlot()
        self.add_dock("live", "Live plot", self.live_plot, Qt.RightDockWidgetArea)
        self.tabifyDockWidget(self.docks["goniometer"], self.docks["camera"])
        self.tabifyDockWidget(self.docks["camera"], self.docks["live"])
        self.docks["goniometer"].raise_()
        self.plan_editor = PlanEditor(self.background, self.validation_profile,
                                      settings=self.settings)
        self.add_dock("plan", "Plan", self.plan_editor, Qt.RightDockWidgetArea)
        self.splitDockWidget(self.docks["goniometer"], self.docks["plan"], Qt.Vertical)
        self.plan_editor.startRequested.connect(self.start_run)
        self.fault_panel = FaultPanel()
        self.run_control = RunControl(self.session, self.fault_panel,
                                      questions=self.questions)
        self.add_dock("run", "Run", self.run_control, Qt.LeftDockWidgetArea)
        self.add_dock("faults", "Faults", self.fault_panel, Qt.RightDockWidgetArea)
        self.browser = RunBrowser(self.background, self.runs_dir, settings=self.settings)
        self.add_dock("runs", "Runs", self.browser, Qt.RightDockWidgetArea)
        self.tabifyDockWidget(self.docks["plan"], self.docks["runs"])
        self.tabifyDockWidget(self.docks["runs"], self.docks["faults"])
        self.docks["plan"].raise_()
        self.browser.resumeRequested.connect(self.resume_run)
        self.browser.folderChanged.connect(self._runs_dir_changed)
        self.run_control.finished.connect(lambda ev: self.browser.refresh())
        self.log_dock = LogDock()
        self.add_dock("log", "Log", self.log_dock, Qt.RightDockWidgetArea)
        self.tabifyDockWidget(self.docks["faults"], self.docks["log"])
        self.docks["plan"].raise_()
        # engine events and command results reach the docks with GUI remedies
        self.bridge.engineEvent.connect(self._on_engine_event)
        self.browser.analysisDone.connect(self.log_dock.on_analysis)
        self.browser.analysisFailed.connect(
            lambda name, msg: self.log_dock.log("error", name, msg))
        self.bridge.runChanged.connect(self.run_control.on_run)
        self.plan_editor.planChanged.connect(self._plan_changed)
        self.bridge.statesChanged.connect(self._on_states)
        self.bridge.statesChanged.connect(self.camera.on_states)
        self.bridge.runChanged.connect(self.camera.on_run)
        self._run_timer = QTimer(self)
        self._run_timer.setInterval(100)  # live views redraw at ≤ 10 Hz
        self._run_timer.timeout.connect(self._tick_run)

    def _build_menus(self) -> None:
        def action(menu, text: str, slot, shortcut: str | None = None,
                   name: str | None = None) -> QAction:
            a = QAction(text, self)
            if shortcut:
                a.setShortcut(QKeySequence(shortcut))
            if name:
                a.setObjectName(name)
            a.triggered.connect(slot)
            menu.addAction(a)
            return a

        f = self._file_menu
        self.runs_folder_action = action(f, "Runs folder…", self.browser.ask_folder,
                                         "Ctrl+R", "runs_folder")
        action(f, "Snapshot folder…", self._ask_snapshot_folder, name="snapshot_folder")
        f.addSeparator()
        action(f, "Quit", self.close, "Ctrl+Q", "quit")
        self._bench_menu.addAction(self.home_all_action)
        action(self._bench_menu, "Stop all  (Esc)", self.stop_all)
        for dock in self.docks.values():
            self._views_menu.addAction(dock.toggleViewAction())
        self._views_menu.addSeparator()
        action(self._views_menu, "Reset layout", self.reset_layout, name="reset_layout")
        action(self._help_menu, "Keyboard shortcuts", self.show_shortcuts, "F1",
               "shortcuts")
        action(self._help_menu, "About scatterlab", self.show_about, name="about")

    def show_shortcuts(self) -> QWidget:
        return self._show_dialog("shortcuts", "Keyboard shortcuts", shortcuts_html(SHORTCUTS))

    def show_about(self) -> QWidget:
        return self._show_dialog("about", "About scatterlab", about_html(
            self.runs_dir, self.settings.fileName()))

    def _show_dialog(self, key: str, title: str, html: str) -> QWidget:
        dialog = self.dialogs.get(key)
        if dialog is None:
            dialog = text_dialog(self, title, html)
            self.dialogs[key] = dialog
        dialog.show()
        dialog.raise_()
        return dialog

    # runs folder and snapshots ------------------------------------------------------
    def set_runs_dir(self, folder: str | Path) -> None:
        """New runs, the run browser and (unless chosen) snapshots use ``folder`` from
        now on; kept in the settings for the next launch."""
        self.browser.set_runs_dir(folder)  # emits folderChanged → _runs_dir_changed

    def _runs_dir_changed(self, folder: str) -> None:
        self.runs_dir = Path(folder)
        if not self.settings.value("snapshot_dir"):
            self.camera.snapshot_dir = self.runs_dir
        self.statusBar().showMessage(f"runs folder: {self.runs_dir} (new runs are written "
                                     "there)", 8000)

    def _ask_snapshot_folder(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Snapshot folder",
                                                  str(self.camera.snapshot_dir))
        if folder:
            self.set_snapshot_dir(folder)

    def set_snapshot_dir(self, folder: str | Path) -> None:
        self.camera.snapshot_dir = Path(folder)
        self.settings.setValue("snapshot_dir", str(folder))

    # bench ---------------------------------------------------------------------------
    def home_all(self) -> list[str]:
        """Home every axis of the connected bench (each through the guard, as its own
        Home button does). Returns the axes asked to home."""
        if not self.session.connected or self.session.run is not None:
            return []
        roles = [r for r, s in self.session.states().items() if s.kind == "motion_axis"]
        for role in roles:
            self.session.submit(Home(role))
        return roles

    def _update_home(self, states: dict[str, DeviceState] | None = None) -> None:
        idle = self.session.connected and self.session.run is None
        self.home_all_action.setEnabled(idle)
        self.home_all_button.setEnabled(idle)
        missing = unhomed_axes(states if states is not None else self.session.states()) \
            if idle else []
        self.home_hint.setText(
            f"{len(missing)} ax{'is' if len(missing) == 1 else 'es'} not homed: press "
            "Home all before moving" if missing else "")
        self.home_hint.setToolTip(", ".join(missing))

    def validation_profile(self):
        """The bench plans are checked against: the connected one, else the chosen one."""
        profile = self.session.profile if self.session.connected else None
        if profile is not None:
            return profile
        try:
            return load_profile(self.bench_panel.chosen)
        except (ProfileError, OSError):
            return None

    def start_run(self, plan) -> None:
        self.runs_dir.mkdir(parents=True, exist_ok=True)
        self.session.submit(StartRun(plan, self.runs_dir))

    def resume_run(self, details) -> bool:
        """Continue a run in its own file, on the bench it was recorded on.

        The connected bench is used only when it is that bench. Otherwise (none
        connected, or another) the operator is asked whether to connect the run's bench
        from the profile stored in the run; *No* changes nothing and says why. Returns
        whether the resume was submitted."""
        self.docks["run"].raise_()
        refusal = resume_refusal(details)
        if refusal is None and self.session.run is not None:
            refusal = "a run is in progress: let it finish or abort it first"
        if refusal is not None:
            return self._not_resumed(refusal)
        run_id = details.provenance.get("run id", details.path.stem)
        want = details.bench_name
        profile = self.session.profile if self.session.connected else None
        if profile is None or profile.name != want:
            now = ("No bench is connected." if profile is None else
                   f"Bench {profile.name!r} is connected; it is disconnected first (axes "
                   "stopped, light off).")
            if not self.questions.ask(
                    "resume_connect", self, "Connect the run's bench?",
                    f"Run {run_id} was recorded on bench {want!r}. {now}\n\nConnect bench "
                    f"{want!r} from the profile stored in the run, and resume?"):
                return self._not_resumed(
                    f"run {run_id} needs bench {want!r}: connect it in the Bench dock, "
                    "then press Resume this run again")
            try:
                stored = parse_profile(details.profile_text,
                                       source=f"bench profile stored in {details.path}")
            except ProfileError as err:
                return self._not_resumed(str(err))
            self.session.submit(Connect(stored))
        self.session.submit(ResumeRun(details.path))
        return True

    def _not_resumed(self, reason: str) -> bool:
        self.run_control.state.setText(f"not resumed: {reason}")
        self.statusBar().showMessage(f"not resumed: {reason}", 15000)
        return False

    def _plan_changed(self, plan) -> None:
        if self.session.run is None:
            self.goniometer.set_plan(plan)

    def _update_start(self) -> None:
        self.plan_editor.set_can_start(self.session.connected and self.session.run is None)
        self._update_home()

    def _on_states(self, states) -> None:
        self.goniometer.set_positions(homed_positions(states))
        self._update_home(states)

    def _tick_run(self) -> None:
        """Read the run's live values (a copy under a lock) and update the views."""
        run = self.current_run
        if run is None:
            return
        snap = run.live.snapshot()
        if snap.version == getattr(self, "_last_version", None):
            return
        self._last_version = snap.version
        self.goniometer.set_positions(snap.positions)
        self.live_plot.update_from(snap)
        done = np.zeros(snap.n_total, bool)
        done[snap.index[(snap.index >= 0) & (snap.index < snap.n_total)]] = True
        self.goniometer.set_done(done)

    def reset_layout(self) -> None:
        self.restoreState(self._default_state, LAYOUT_VERSION)
        for dock in self.docks.values():
            dock.show()
        self.default_sizes()

    def default_sizes(self) -> None:
        """The bench column (bench over run) 36 % of the width; on the right the views
        over the plan, runs, faults and log."""
        w, h = max(self.width(), 800), max(self.height(), 600)
        d = self.docks
        self.resizeDocks([d["bench"], d["goniometer"]], [int(0.36 * w), int(0.64 * w)],
                         Qt.Horizontal)
        self.resizeDocks([d["bench"], d["run"]], [int(0.68 * h), int(0.32 * h)], Qt.Vertical)
        self.resizeDocks([d["goniometer"], d["plan"]], [int(0.45 * h), int(0.55 * h)],
                         Qt.Vertical)

    # settings ------------------------------------------------------------------------
    def _restore(self, bench: str | None) -> None:
        geometry = self.settings.value("geometry")
        if isinstance(geometry, QByteArray | bytes):
            self.restoreGeometry(QByteArray(geometry))
        else:
            self.resize(1500, 950)
            self.default_sizes()
        state = self.settings.value("window_state")
        if isinstance(state, QByteArray | bytes):
            self.restoreState(QByteArray(state), LAYOUT_VERSION)
        chosen = bench or self.settings.value("bench", "sim")
        self.bench_panel.choose(str(chosen))
        snapshots = self.settings.value("snapshot_dir")
        self.camera.snapshot_dir = Path(str(snapshots)) if snapshots else self.runs_dir

    def save_settings(self) -> None:
        self.settings.setValue("geometry", self.saveGeometry())
        self.settings.setValue("window_state", self.saveState(LAYOUT_VERSION))
        self.settings.setValue("bench", self.bench_panel.chosen)
        self.settings.sync()

    # safety --------------------------------------------------------------------------
    def stop_all(self) -> None:
        self.session.stop_all()

    def toggle_pause(self) -> bool:
        """Space: pause a running run, resume a paused one. Returns whether it acted."""
        if self.session.pause_run():
            return True
        return self.session.resume_run()

    def eventFilter(self, obj: QObject, event: QEvent) -> bool:
        if (event.type() == QEvent.KeyPress and event.key() == Qt.Key_Space
                and not event.isAutoRepeat() and self.isActiveWindow()
                and self.session.run is not None):
            focus = QApplication.focusWidget()
            typing = isinstance(focus, QLineEdit | QTextEdit | QPlainTextEdit
                                | QAbstractSpinBox) or (
                isinstance(focus, QComboBox) and focus.isEditable())
            if not typing:
                return self.toggle_pause()
        return super().eventFilter(obj, event)

    # reports -------------------------------------------------------------------------
    def _on_connection(self, status: ConnectionStatus) -> None:
        self.bench_panel.on_connection(status)
        self.statusBar().showMessage(status.message, 8000)
        if status.state in ("connected", "disconnected"):
            self.goniometer.set_profile(status.profile if status.state == "connected"
                                        else None)
            self.goniometer.set_plan(self.plan_editor.plan)
            self.plan_editor.validate_now()
        self._update_start()

    def _on_engine_event(self, ev) -> None:
        ev = event_for_gui(ev)
        self.log_dock.on_event(ev)
        self.run_control.on_event(ev)

    def _on_result(self, result: CommandResult) -> None:
        result = replace(result, message=for_gui(result.message))
        self.bench_panel.on_result(result)
        self.log_dock.on_result(result)
        self.camera.on_result(result)
        if isinstance(result.command, StartRun | ResumeRun) and not result.ok:
            self.run_control.state.setText(f"the run did not start: {result.message}")
            self.statusBar().showMessage(result.message, 15000)

    def _on_run(self, run: RunHandle | None) -> None:
        self.bench_panel.on_run(run)
        self._update_start()
        self.run_label.setText("" if run is None else f"run: {run.path.name}")
        if run is not None:
            self.current_run = run
            self.goniometer.set_plan(run.plan)
            self.live_plot.start(run.plan.kind)
            self.docks["live"].raise_()
            self._last_version = None
            self._run_timer.start()
        else:
            self._tick_run()  # the last points of the run that just ended
            self._run_timer.stop()

    # closing -------------------------------------------------------------------------
    def closeEvent(self, event: QCloseEvent) -> None:
        run = self.session.run
        if run is not None and not self._closing:
            if not self.questions.ask(
                    "close_run", self, "A run is in progress",
                    "A run is in progress. Close anyway?\n\nThe run is aborted: motion "
                    "stopped, light off, the file finalised (it can be resumed later)."):
                event.ignore()
                return
            self._closing = True
            self.session.abort_run()
            self.statusBar().showMessage("aborting the run: making the bench safe …")
            self._wait_for_run_end()
            event.ignore()
            return
        if self.session.run is not None:
            event.ignore()  # still ending; _wait_for_run_end closes when it has
            return
        self.save_settings()
        QApplication.instance().removeEventFilter(self)
        self.log_dock.detach()
        self.shutdown()
        event.accept()

    def confirm_close_during_run(self, yes: bool = True) -> None:
        """Answer the close question in advance (tests, scripted shutdown)."""
        self.questions.answer("close_run", yes)

    def _wait_for_run_end(self) -> None:
        if self.session.run is None:
            self._closing = False
            self.close()
            return
        QTimer.singleShot(50, self._wait_for_run_end)

    def shutdown(self) -> None:
        """Close the bench (axes stopped, light off) and end the device worker."""
        self.session.close(30.0)
        self.background.shutdown(wait=False)
        self.browser.analysis_pool.shutdown(wait=False)
