"""The operator's window on a bench server: the GUI as a client (docs/decisions/0084).

Everything the operator does goes through :class:`gui.qt.server_link.ServerLink` to the
server, which owns the bench and runs the engine: queue a plan, approve or deny a
proposed one, start and stop the queue, pause, resume, abort, answer a fault (retry,
skip, abort), home, jog, move, light, Stop all, take and release control. What the
window shows is what the server's event stream says: the queue, the current run with its
live plot (from its first point, also when the window opens mid-run), device states and
the goniometer drawing from their read-back positions, the latest camera frame and its
exposure and gain (set here between runs), the lock-in's, filter wheel's and power
meter's panels (set here between runs: each change shows "applying…" until the server's
``device_settings`` event says it is done or why not), faults and the control lease. Controls the
server would refuse are greyed, with the reason in their tooltip and in the banner (an
observer key; another operator's lease).

Closing the window leaves the server and its run going.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
from PySide6.QtCore import Qt, QTimer
from PySide6.QtGui import QColor, QImage, QKeySequence, QPixmap, QShortcut
from PySide6.QtWidgets import (
    QDoubleSpinBox,
    QFileDialog,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QListWidget,
    QListWidgetItem,
    QMainWindow,
    QPlainTextEdit,
    QProgressBar,
    QPushButton,
    QScrollArea,
    QSizePolicy,
    QSplitter,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from gui.model.session import Action, CommandResult, SetSetting
from gui.qt.background import Background
from gui.qt.goniometer_view import GoniometerView
from gui.qt.live_plot import LivePlot
from gui.qt.panels import DevicePanel, panel_for, spin_box
from gui.qt.plan_editor import PlanEditor
from gui.qt.run_browser import RunBrowser
from gui.qt.server_link import ServerLink
from gui.qt.setpoint import SetpointField

__all__ = ["ClientWindow"]

#: Redraws per second of the readouts (the state is applied as it arrives); the plot is
#: redrawn every PLOT_EVERY-th tick (10 Hz: each redraw repaints its axes).
REDRAW_HZ = 20
PLOT_EVERY = 2
#: A panel's actions as the server's device-settings fields (``instrument.server.
#: device_settings``): the wheel's move is its ``position``; the others are set to true.
PANEL_ACTIONS = {"move_to": "position", "auto_range": "auto_range", "zero": "zero"}


def panel_changes(command) -> dict | None:
    """A panel's command (:class:`SetSetting` or :class:`Action`) as the fields of a
    device-settings request; None for a command the server does not take from a panel."""
    if isinstance(command, SetSetting):
        return {command.name: command.value}
    if isinstance(command, Action) and command.name in PANEL_ACTIONS:
        value = command.args[0] if command.args else True
        return {PANEL_ACTIONS[command.name]: value}
    return None


def steady_label(label: QLabel, *, lines: int, chars: str = "") -> None:
    """A label whose text changes at every redraw (a run's progress, an axis's position)
    without moving the widgets around it: its size no longer follows its text (a fixed
    height of ``lines`` lines; at least as wide as ``chars``), so a new text repaints the
    label alone instead of re-laying out and repainting its column (BENCHMARKS.md gui)."""
    label.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Fixed)
    metrics = label.fontMetrics()
    label.setFixedHeight(lines * metrics.lineSpacing() + 2 * label.margin() + 2)
    if chars:
        label.setMinimumWidth(metrics.horizontalAdvance(chars))


class _PanelSession:
    """What a device panel (:mod:`gui.qt.panels`) asks of its session, in this window: the
    bench profile (the filter wheel's bands named in it), and its commands, sent to the
    server as device-settings requests (:meth:`ClientWindow.set_device`)."""

    def __init__(self, window: ClientWindow) -> None:
        self._window = window

    @property
    def profile(self):
        return self._window._validation_profile()

    def submit(self, command) -> None:
        role = getattr(command, "role", None)
        changes = panel_changes(command)
        if role is None or changes is None:
            self._window.log_view.appendPlainText(f"{command}: not available through the "
                                                  "server")
            return
        self._window.set_device(role, changes, command)


class ClientWindow(QMainWindow):
    """A window on the server at ``url`` (``key``: the API key, or None on an open
    loopback server). ``note``: a sentence shown in the status bar (who started the
    server)."""

    def __init__(self, url: str, key: str | None = None, *, note: str = "",
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle(f"scatterlab: {url}")
        self.link = ServerLink(url, key, self)
        self.state = self.link.state
        self.note = note
        self.results: list[tuple[str, bool, str, list[str]]] = []
        self._plot_version = -1
        self._plot_run: object | None = None
        self._ticks = 0
        self._operator_controls: list[QWidget] = []
        self._dirty: set[str] = set()
        self._access: tuple | None = None
        self._profile = None
        self._sent: dict[str, object] = {}  # role -> the panel command awaiting its end
        self._build()
        self.link.changed.connect(self._on_changed)
        self.link.result.connect(self._on_result)
        self._timer = QTimer(self)
        self._timer.setInterval(int(1000 / REDRAW_HZ))
        self._timer.timeout.connect(self._redraw)
        self._timer.start()
        QShortcut(QKeySequence(Qt.Key.Key_Escape), self, activated=self.stop_all)
        self._refresh_all()

    # layout -----------------------------------------------------------------------------
    def _button(self, text: str, slot, *, operator: bool = True) -> QPushButton:
        b = QPushButton(text)
        b.clicked.connect(slot)
        if operator:
            self._operator_controls.append(b)
        return b

    def _build(self) -> None:
        self.banner = QLabel()
        self.banner.setWordWrap(True)
        self.control_label = QLabel()
        self.take_button = self._button("Take control", self.take_control, operator=False)
        self.release_button = self._button("Release control", self.release_control,
                                           operator=False)
        self.stop_all_button = self._button("Stop all (Esc)", self.stop_all, operator=False)
        self.stop_all_button.setStyleSheet("background: #c62828; color: white; "
                                           "font-weight: bold;")
        top = QHBoxLayout()
        top.addWidget(self.banner, 1)
        top.addWidget(self.control_label)
        for b in (self.take_button, self.release_button, self.stop_all_button):
            top.addWidget(b)

        # queue
        self.queue_list = QListWidget()
        self.add_button = self._button("Add plan…", self.add_plan_dialog)
        self.add_stop_button = self._button("Add stop marker", lambda: self.link.call(
            "add stop marker", lambda c: c.add_stop()))
        self.remove_button = self._button("Remove", self.remove_selected)
        self.up_button = self._button("Up", lambda: self.move_selected(-1))
        self.start_queue_button = self._button("Start queue", lambda: self.link.call(
            "start queue", lambda c: c.start_queue()))
        self.stop_queue_button = self._button("Stop queue", lambda: self.link.call(
            "stop queue", lambda c: c.stop_queue()))
        self.approve_button = self._button("Approve", self.approve_selected)
        self.deny_button = self._button("Deny", self.deny_selected)
        for b in (self.approve_button, self.deny_button):
            b.setStatusTip("a proposal (a plan added by an observer or a script): select "
                           "it, then approve it into the queue or deny it")
        qbox = QGroupBox("Queue")
        ql = QVBoxLayout(qbox)
        self.queue_label = QLabel()
        ql.addWidget(self.queue_label)
        ql.addWidget(self.queue_list, 1)
        grid = QGridLayout()
        for k, b in enumerate((self.add_button, self.add_stop_button, self.remove_button,
                               self.up_button, self.start_queue_button,
                               self.stop_queue_button, self.approve_button,
                               self.deny_button)):
            grid.addWidget(b, k // 2, k % 2)
        ql.addLayout(grid)

        # run
        rbox = QGroupBox("Run")
        rl = QVBoxLayout(rbox)
        self.run_label = QLabel("no run")
        self.run_label.setWordWrap(True)
        steady_label(self.run_label, lines=3)
        self.progress = QProgressBar()
        # no text: a changed percentage makes QProgressBar repaint at once, not on the
        # next paint (the run label says n of N)
        self.progress.setTextVisible(False)
        self.pause_button = self._button("Pause", lambda: self.link.call(
            "pause", lambda c: c.pause()))
        self.resume_button = self._button("Resume", lambda: self.answer("resume"))
        self.abort_button = self._button("Abort", lambda: self.answer("abort"))
        self.fault_box = QGroupBox("The run waits for an answer")
        fl = QVBoxLayout(self.fault_box)
        self.fault_label = QLabel()
        self.fault_label.setWordWrap(True)
        fl.addWidget(self.fault_label)
        row = QHBoxLayout()
        self.retry_button = self._button("Retry", lambda: self.answer("retry"))
        self.skip_button = self._button("Skip point", lambda: self.answer("skip"))
        self.fault_abort_button = self._button("Abort run", lambda: self.answer("abort"))
        for b in (self.retry_button, self.skip_button, self.fault_abort_button):
            row.addWidget(b)
        fl.addLayout(row)
        self.fault_box.hide()
        rl.addWidget(self.run_label)
        rl.addWidget(self.progress)
        row = QHBoxLayout()
        for b in (self.pause_button, self.resume_button, self.abort_button):
            row.addWidget(b)
        rl.addLayout(row)
        rl.addWidget(self.fault_box)

        # manual
        mbox = QGroupBox("Bench (manual)")
        self.manual_grid = QGridLayout(mbox)
        self.axis_rows: dict[str, tuple[QLabel, QDoubleSpinBox]] = {}
        self.light_button = self._button("Light on", self.toggle_light)
        self.manual_grid.addWidget(self.light_button, 0, 0, 1, 2)
        self.light_label = QLabel("light: ?")
        self.manual_grid.addWidget(self.light_label, 0, 2, 1, 3)

        left = QWidget()
        ll = QVBoxLayout(left)
        ll.addWidget(qbox, 2)
        ll.addWidget(rbox)
        ll.addWidget(mbox)

        # live views and log
        self.plot = LivePlot()
        self.camera = QLabel("no frame yet")
        self.camera.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.camera.setMinimumSize(160, 120)
        self.log_view = QPlainTextEdit()
        self.log_view.setReadOnly(True)
        self.log_view.setMaximumBlockCount(1000)
        right = QSplitter(Qt.Orientation.Vertical)
        views = QSplitter(Qt.Orientation.Horizontal)
        views.addWidget(self.plot)
        views.addWidget(self._camera_box())
        self.tabs = QTabWidget()
        self.tabs.addTab(views, "Live")
        self.goniometer = GoniometerView()
        self.tabs.addTab(self.goniometer, "Goniometer")
        self.tabs.addTab(self._devices_tab(), "Devices")
        self.background = Background(parent=self)
        self.plan_editor = PlanEditor(self.background, self._validation_profile)
        self.plan_editor.start.setText("Queue plan")
        self.plan_editor.startRequested.connect(self._queue_edited_plan)
        self.tabs.addTab(self.plan_editor, "Plan")
        self.browser: RunBrowser | None = None
        right.addWidget(self.tabs)
        right.addWidget(self.log_view)

        body = QSplitter(Qt.Orientation.Horizontal)
        body.addWidget(left)
        body.addWidget(right)
        body.setStretchFactor(1, 1)
        central = QWidget()
        cl = QVBoxLayout(central)
        cl.addLayout(top)
        cl.addWidget(body, 1)
        self.setCentralWidget(central)
        self.resize(1280, 800)

    def _devices_tab(self) -> QWidget:
        """The lock-in's, filter wheel's and power meter's panels (the in-process window's
        panels, fed the server's ``devices`` messages), one added per device the server
        names."""
        self.panels: dict[str, DevicePanel] = {}
        self._panel_session = _PanelSession(self)
        inner = QWidget()
        self.panel_layout = QVBoxLayout(inner)
        self.no_panels = QLabel("the server has named no lock-in, filter wheel or power "
                                "meter")
        self.panel_layout.addWidget(self.no_panels)
        self.panel_layout.addStretch(1)
        scroll = QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setWidget(inner)
        return scroll

    def _camera_box(self) -> QWidget:
        """The latest frame with the camera's exposure and gain: fields that follow the
        server's values, each sent with its *Set* button (between runs: a run sets the
        camera from its plan)."""
        box = QWidget()
        lay = QVBoxLayout(box)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.camera, 1)
        grid = QGridLayout()
        self.exposure_box = spin_box(0.01, 1e8, 2, 1000.0, "µs")
        self.gain_box = spin_box(-100.0, 1000.0, 2, 0.0)
        self.camera_fields = {"exposure_us": SetpointField(self.exposure_box, "exposure"),
                              "gain": SetpointField(self.gain_box, "gain")}
        self.set_exposure_button = QPushButton("Set")
        self.set_exposure_button.clicked.connect(
            lambda: self.set_camera("exposure_us", self.exposure_box.value()))
        self.set_gain_button = QPushButton("Set")
        self.set_gain_button.clicked.connect(
            lambda: self.set_camera("gain", self.gain_box.value()))
        for r, (name, field, button) in enumerate((
                ("exposure", self.exposure_box, self.set_exposure_button),
                ("gain", self.gain_box, self.set_gain_button))):
            grid.addWidget(QLabel(name), r, 0)
            grid.addWidget(field, r, 1)
            grid.addWidget(button, r, 2)
        self.camera_controls = (self.exposure_box, self.gain_box, self.set_exposure_button,
                                self.set_gain_button)
        lay.addLayout(grid)
        return box

    # operator actions (all through the server) ------------------------------------------
    def set_camera(self, name: str, value: float) -> None:
        """Set the camera's ``exposure_us`` or ``gain`` on the server (between runs)."""
        self.link.call(f"camera {name}", lambda c: c.camera_settings(**{name: value}))

    def set_device(self, role: str, changes: dict, command=None) -> None:
        """Ask the server to set the device ``role``'s ``changes``; its panel shows
        "applying…" (controls greyed) until the request's end arrives on the stream."""
        self._sent[role] = command
        panel = self.panels.get(role)
        if panel is not None:
            panel.set_pending("applying…")
        self.link.call(f"device {role}", lambda c: c.device_settings(role, **changes))

    def add_plan_text(self, text: str, name: str | None = None) -> None:
        self.link.call(f"add plan {name or ''}".strip(), lambda c: c.add_plan(text, name))

    def add_plan_file(self, path: str | Path) -> None:
        p = Path(path)
        self.add_plan_text(p.read_text(encoding="utf-8"), p.stem)

    def add_plan_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Queue a plan", "", "Plans (*.toml)")
        if path:
            self.add_plan_file(path)

    def _queue_edited_plan(self, plan) -> None:
        """The plan editor's plan, queued on the server as its TOML text."""
        self.add_plan_text(self.plan_editor.form.to_toml(), plan.name or None)

    def _validation_profile(self):
        """The server's bench, for checking plans as they are edited (built-in profiles
        and files reachable from here; the server checks every plan again)."""
        from instrument.bench.profile import ProfileError, load_profile

        if self._profile is None and self.state.bench:
            try:
                self._profile = load_profile(self.state.bench)
            except (ProfileError, OSError):
                return None
        return self._profile

    def _show_runs(self, runs_dir: str) -> None:
        """The run browser, when the server's runs folder is on this PC (a local server)."""
        if self.browser is not None or not runs_dir or not Path(runs_dir).is_dir():
            return
        self.browser = RunBrowser(self.background, Path(runs_dir))
        self.browser.resumeRequested.connect(lambda details: self.log_view.appendPlainText(
            "resume through the server: an interrupted queue item continues its run file "
            "when the queue starts"))
        self.tabs.addTab(self.browser, "Runs")

    def _selected_id(self) -> int | None:
        item = self.queue_list.currentItem()
        return None if item is None else int(item.data(Qt.ItemDataRole.UserRole))

    def remove_selected(self) -> None:
        item_id = self._selected_id()
        if item_id is not None:
            self.link.call(f"remove item {item_id}", lambda c: c.remove(item_id))

    def approve_selected(self) -> None:
        """Approve the selected proposal: it joins the queue where it stands."""
        item_id = self._selected_id()
        if item_id is not None:
            self.link.call(f"approve item {item_id}", lambda c: c.approve(item_id))

    def deny_selected(self) -> None:
        """Deny the selected proposal: it goes to the history, never run."""
        item_id = self._selected_id()
        if item_id is not None:
            self.link.call(f"deny item {item_id}", lambda c: c.deny(item_id))

    def select_item(self, item_id: int) -> bool:
        """Select the queue row of ``item_id``; False when the queue has no such item."""
        for row in range(self.queue_list.count()):
            if int(self.queue_list.item(row).data(Qt.ItemDataRole.UserRole)) == item_id:
                self.queue_list.setCurrentRow(row)
                return True
        return False

    def move_selected(self, by: int) -> None:
        item_id = self._selected_id()
        if item_id is not None:
            index = max(0, self.queue_list.currentRow() + by)
            self.link.call(f"move item {item_id}", lambda c: c.move(item_id, index))

    def answer(self, what: str) -> None:
        """Resume, or answer a fault: ``resume``, ``retry``, ``skip`` or ``abort``."""
        if what == "abort":
            self.link.call("abort", lambda c: c.abort())
        else:
            self.link.call(what, lambda c: c.resume(what))

    def home(self, role: str) -> None:
        self.link.call(f"home {role}", lambda c: c.home(role))

    def jog(self, role: str, step: float) -> None:
        self.link.call(f"jog {role}", lambda c: c.jog(role, step))

    def move_to(self, role: str, target: float) -> None:
        self.link.call(f"move {role}", lambda c: c.move_to(**{role: target}))

    def toggle_light(self) -> None:
        on = not bool(self.state.light)
        self.link.call("light on" if on else "light off", lambda c: c.light(on))

    def stop_all(self) -> None:
        self.link.call("stop all", lambda c: c.stop_all(), urgent=True)

    def take_control(self) -> None:
        self.link.call("take control", lambda c: c.take_control())

    def release_control(self) -> None:
        self.link.call("release control", lambda c: c.release_control())

    # state to widgets -------------------------------------------------------------------
    def _on_result(self, what: str, ok: bool, message: str, reasons) -> None:
        self.results.append((what, ok, message, list(reasons or [])))
        role = what.removeprefix("device ")
        if what.startswith("device ") and not ok and role in self.panels:
            # refused before anything was sent: the panel says why, at once
            self.panels[role].set_pending("")
            self.panels[role].show_result(CommandResult(self._sent.pop(role, None), False,
                                                        message, refused=True))
        field = self.camera_fields.get(what.removeprefix("camera "))
        if what.startswith("camera ") and field is not None:
            field.settled()  # done or refused: the field shows the camera's value again
        text = f"{what}: {message}" if ok else f"{what} refused: {message}"
        if reasons:
            text += "".join(f"\n    - {r}" for r in reasons)
        self.log_view.appendPlainText(text)
        self.statusBar().showMessage(text.splitlines()[0], 10_000)

    def _on_changed(self, parts: set[str]) -> None:
        """Note what changed; the redraw timer puts it on screen, at most
        :data:`REDRAW_HZ` times a second however fast the messages come."""
        self._dirty |= parts

    def _refresh_dirty(self) -> None:
        parts, self._dirty = self._dirty, set()
        if not parts:
            return
        self._flush_log()
        if parts & {"queue", "bench"}:
            self._refresh_queue()
        if parts & {"run", "bench", "control", "queue"}:
            self._refresh_run()
            self._refresh_access()
        if "bench" in parts:
            self._refresh_goniometer_profile()
        if "devices" in parts or "device_settings" in parts:
            self._refresh_devices()
        if "device_settings" in parts:
            self._refresh_settings()
        if "frame" in parts:
            self._refresh_frame()

    def _flush_log(self) -> None:
        log = self.state.log
        while log:
            self.log_view.appendPlainText(log.popleft())

    def _refresh_all(self) -> None:
        self._flush_log()
        self._refresh_queue()
        self._refresh_run()
        self._refresh_goniometer_profile()
        self._refresh_devices()
        self._refresh_access()

    def _refresh_goniometer_profile(self) -> None:
        """The drawing needs the server's bench profile: a built-in one or a file
        reachable from this PC (a local server's), else it says why it is empty."""
        profile = self._validation_profile()
        if profile is not self.goniometer.profile:
            self.goniometer.set_profile(profile)
            if profile is not None:
                self.goniometer.set_positions(self.state.homed_positions())
        if profile is None and self.state.bench:
            self.goniometer.caption.setText(
                f"the server's bench {self.state.bench!r} is not a built-in profile nor "
                "a file readable from this PC: no drawing (the other tabs work)")

    def _refresh_queue(self) -> None:
        s = self.state
        selected = self._selected_id()
        self.queue_list.clear()
        proposals = 0
        for it in s.queue_items:
            text = f"{it.get('id')}  {it.get('name')}  [{it.get('state')}]"
            proposed = it.get("state") == "proposed"
            if proposed:
                proposals += 1
                text += f"  proposed by {it.get('added_by') or '?'}: approve or deny"
            row = QListWidgetItem(text)
            if proposed:
                row.setForeground(QColor("#ef6c00"))
            row.setData(Qt.ItemDataRole.UserRole, int(it.get("id")))
            self.queue_list.addItem(row)
            if it.get("id") == selected:
                self.queue_list.setCurrentItem(row)
        waiting = f"; {proposals} proposed, waiting for an operator" if proposals else ""
        self.queue_label.setText(f"{len(s.queue_items)} items; the queue "
                                 f"{'runs' if s.queue_running else 'is stopped'}{waiting}")

    def _refresh_run(self) -> None:
        run = self.state.run
        if run is None:
            self.run_label.setText("no run")
            self._set_progress(0, 1)
            self.fault_box.hide()
            return
        eta = "" if not math.isfinite(run.eta_s) else f", about {run.eta_s:.0f} s left"
        self.run_label.setText(f"run {run.run_id or Path(run.path).stem} ({run.plan_kind}): "
                               f"{run.state}, {run.n_done} of {run.n_total} points{eta}")
        self._set_progress(run.n_done, run.n_total)
        fault = run.state == "paused" and "retry" in run.answers
        self.fault_box.setVisible(run.state == "paused")
        self.fault_box.setTitle("A device fault: the run waits for an answer" if fault
                                else "The run is paused")
        self.fault_label.setText(run.pause_reason)
        for b in (self.retry_button, self.skip_button):
            b.setVisible(fault)

    def _set_progress(self, done: int, total: int) -> None:
        """The progress bar at ``done`` of ``total``, painted with the window's next paint:
        QProgressBar.setValue repaints at once (synchronously, the window's backing store
        included) whenever the bar grows by a pixel, which during a fast scan is at every
        redraw (BENCHMARKS.md gui)."""
        total = max(total, 1)
        bar = self.progress
        if bar.maximum() == total and bar.value() == min(done, total):
            return
        bar.setUpdatesEnabled(False)  # repaint() does nothing; update() below is queued
        bar.setMaximum(total)
        bar.setValue(min(done, total))
        bar.setUpdatesEnabled(True)
        bar.update()

    def _refresh_devices(self) -> None:
        s = self.state
        for role, ax in sorted(s.axes.items()):
            if role not in self.axis_rows:
                self._add_axis_row(role)
            label, _ = self.axis_rows[role]
            pos = ax.get("position")
            label.setText(f"{role}: {'?' if pos is None else f'{pos:.3f}'}"
                          f"{' moving' if ax.get('moving') else ''}"
                          f"{'' if ax.get('homed') else ' (not homed)'}")
        light = "?" if s.light is None else ("on" if s.light else "off")
        self.light_label.setText(f"light: {light}; bench {s.owner or '?'}")
        if self.goniometer.profile is not None:  # else its caption says why it is empty
            self.goniometer.set_positions(s.homed_positions())
        self.light_button.setText("Light off" if s.light else "Light on")
        for name, field in self.camera_fields.items():
            field.follow(None if s.camera is None else s.camera.get(name))
        self._refresh_camera_controls()
        self._refresh_panels()

    def _refresh_panels(self) -> None:
        """Each panel redraws when its device's state changed; the age of every shown
        state is kept current (during a run they are the states read before it)."""
        for role, state in self.state.device_states.items():
            panel = self.panels.get(role)
            if panel is None:
                panel = panel_for(state.kind)(role, self._panel_session)
                panel.reconnect.setEnabled(False)  # the server's bench, not this window's
                panel.reconnect.setToolTip("an admin reconnects the server's bench "
                                           "(scatterlab serve: bench disconnect, connect)")
                self.panel_layout.insertWidget(self.panel_layout.count() - 1, panel)
                self.panels[role] = panel
                self.no_panels.hide()
            if panel.state is not state:
                panel.set_state(state)
            else:
                panel.refresh_age()
        self._refresh_panel_access()

    def _refresh_settings(self) -> None:
        """Device-settings requests: "applying…" on the panel of each pending one (this
        window's or another client's); an ended one's outcome under its panel."""
        s = self.state
        for d in s.settings_ended:
            panel = self.panels.get(str(d.get("device")))
            if panel is None:
                continue
            ok = d.get("state") == "done"
            panel.show_result(CommandResult(self._sent.pop(panel.role, None), ok,
                                            str(d.get("message") or "")))
        s.settings_ended.clear()
        for role, panel in self.panels.items():
            pending = s.settings_pending.get(role)
            panel.set_pending("" if pending is None else
                              f"applying… (request {pending.get('request_id')}, "
                              f"{pending.get('who')})")
        self._refresh_panel_access()

    def _refresh_panel_access(self) -> None:
        """A panel's controls work between runs, for an operator who may act, while no
        change of that device is pending."""
        may, why = self.state.may_operate()
        if may and self.state.owner == "run":
            may, why = False, "a run owns the bench: change device settings between runs"
        for role, panel in self.panels.items():
            panel.set_owned(may and role not in self.state.settings_pending, why)

    def _refresh_camera_controls(self) -> None:
        """The camera's settings may change between runs only, by an operator who may
        act; greyed with the reason otherwise."""
        may, why = self.state.may_operate()
        if may and self.state.camera is None:
            may, why = False, ("a run sets the camera from its plan: change it between runs"
                               if self.state.owner == "run" else "the server's bench has "
                               "no camera, or it has not said its settings yet")
        for w in self.camera_controls:
            if w.isEnabled() != may:
                w.setEnabled(may)
            if w.toolTip() != why:
                w.setToolTip(why)

    def _add_axis_row(self, role: str) -> None:
        r = len(self.axis_rows) + 1
        label = QLabel(role)
        steady_label(label, lines=1, chars=f"{role}: -0000.000 moving (not homed)")
        spin = QDoubleSpinBox()
        spin.setRange(-1e6, 1e6)
        spin.setDecimals(3)
        step = QDoubleSpinBox()
        step.setRange(0.001, 1e4)
        step.setValue(1.0)
        buttons = (self._button("Home", lambda: self.home(role)),
                   self._button("−", lambda: self.jog(role, -step.value())),
                   self._button("+", lambda: self.jog(role, step.value())),
                   self._button("Go", lambda: self.move_to(role, spin.value())))
        self.manual_grid.addWidget(label, r, 0)
        for k, w in enumerate((buttons[0], buttons[1], step, buttons[2], spin, buttons[3])):
            self.manual_grid.addWidget(w, r, k + 1)
        self._operator_controls.extend((step, spin))
        self.axis_rows[role] = (label, spin)
        self._refresh_access()

    def _refresh_frame(self) -> None:
        frame = self.state.frame
        if frame is None:
            return
        index, img, scale = frame
        img = np.ascontiguousarray(img)
        h, w = img.shape
        qimg = QImage(img.data, w, h, w, QImage.Format.Format_Grayscale8).copy()
        self.camera.setPixmap(QPixmap.fromImage(qimg).scaled(
            self.camera.size(), Qt.AspectRatioMode.KeepAspectRatio))
        self.camera.setToolTip(f"point {index}; {scale:.3g} DN per grey level")

    def _refresh_access(self) -> None:
        """Grey what the server would refuse, saying why."""
        s = self.state
        may, why = s.may_operate()
        key = (may, why, s.lease_holder(), s.control.get("until"), len(self._operator_controls),
               s.you.get("name"), s.you.get("role"), s.bench, s.stream_up)
        if key == self._access:
            return  # nothing to change: no relayout
        self._access = key
        self.plan_editor.set_can_start(may)
        self._show_runs(s.runs_dir)
        for w in self._operator_controls:
            w.setEnabled(may)
            w.setToolTip(why)
        self._refresh_camera_controls()
        self._refresh_panel_access()
        stop_ok, stop_why = s.may_stop_all()
        self.stop_all_button.setEnabled(stop_ok)
        self.stop_all_button.setToolTip(stop_why or "stop every axis now; a run is aborted "
                                        "(resumable)")
        mine = s.holds_control()
        self.take_button.setEnabled(stop_ok and not mine)
        self.release_button.setEnabled(stop_ok and mine)
        holder = s.lease_holder()
        until = s.control.get("until")
        self.control_label.setText("control: free" if holder is None else
                                   f"control: {holder} until "
                                   f"{time.strftime('%H:%M:%S', time.localtime(until))}")
        who = f"{s.you.get('name') or '?'} ({s.you.get('role') or '?'})"
        head = f"<b>{s.url}</b>, bench {s.bench or '?'}, you: {who}"
        if self.note:
            head += f"<br>{self.note}"
        self.banner.setText(head if may else f"{head}<br><i>View only: {why}</i>")

    def _redraw(self) -> None:
        """What changed since the last tick; the plot, from the live arrays, when
        something new arrived."""
        self._refresh_dirty()
        run = self.state.run
        live = None if run is None else run.live
        if live is None:
            return
        if self._plot_run is not live:
            self._plot_run = live
            self._plot_version = -1
            self.plot.start(live.plan_kind)
        self._ticks += 1
        if live.version != self._plot_version and self._ticks % PLOT_EVERY == 0:
            snap = live.snapshot()
            self._plot_version = snap.version
            self.plot.update_from(snap)
        if self.state.lease_holder() is None and self.state.control.get("holder"):
            self._refresh_access()  # a lease that ran out

    def closeEvent(self, event) -> None:
        """Close the connection; the server and its run go on."""
        self._timer.stop()
        self.link.close()
        self.background.shutdown(wait=False)
        if self.browser is not None:
            self.browser.analysis_pool.shutdown(wait=False)
        super().closeEvent(event)
