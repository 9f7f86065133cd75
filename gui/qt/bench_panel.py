"""The bench panel: choose a bench, connect, and every device's panel with live state."""

from __future__ import annotations

import time
from pathlib import Path

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QComboBox,
    QFileDialog,
    QHBoxLayout,
    QLabel,
    QLayout,
    QPushButton,
    QScrollArea,
    QVBoxLayout,
    QWidget,
)

from gui.model.session import (
    BenchSession,
    CommandResult,
    Connect,
    ConnectionStatus,
    Disconnect,
    Home,
    Jog,
    MoveTo,
    RunHandle,
)
from gui.qt.panels import DevicePanel, panel_for
from gui.qt.wheel import install_wheel_guard
from instrument.bench.device_state import DeviceState
from instrument.bench.profile import (
    BenchProfile,
    ProfileError,
    builtin_profiles,
    canonical_bench_name,
    load_profile,
)

__all__ = ["BenchPanel"]


class BenchPanel(QWidget):
    """Bench chooser, connection, device panels and the last command's outcome."""

    benchChosen = Signal(str)  # name or path, for the settings

    def __init__(self, session: BenchSession, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.session = session
        self.setObjectName("bench_panel")
        install_wheel_guard()
        self.chooser = QComboBox()
        self.chooser.setObjectName("bench_chooser")
        self.chooser.setEditable(False)
        for name in builtin_profiles():
            self.chooser.addItem(name, name)
        self.browse = QPushButton("File…")
        self.browse.setToolTip("a bench profile file (TOML)")
        self.connect_button = QPushButton("Connect")
        self.connect_button.setObjectName("connect")
        self.disconnect_button = QPushButton("Disconnect")
        self.disconnect_button.setObjectName("disconnect")
        self.disconnect_button.setEnabled(False)
        self.connection = QLabel("not connected")
        self.connection.setObjectName("connection")
        self.connection.setWordWrap(True)
        self.message = QLabel("")
        self.message.setObjectName("message")
        self.message.setWordWrap(True)
        self.message.setTextInteractionFlags(Qt.TextSelectableByMouse)
        self.message.setAlignment(Qt.AlignLeft | Qt.AlignTop)
        # Reserved rows: a message or the run's notice appearing never shifts the panels.
        lines = self.fontMetrics().lineSpacing()
        self.message.setFixedHeight(3 * lines + 4)
        self.owner = QLabel("")
        self.owner.setObjectName("owner")
        self.owner.setStyleSheet("color: #0d47a1; font-weight: 600")
        self.owner.setWordWrap(True)
        self.owner.setFixedHeight(2 * lines + 2)
        top = QHBoxLayout()
        top.addWidget(QLabel("Bench"))
        top.addWidget(self.chooser, 1)
        top.addWidget(self.browse)
        buttons = QHBoxLayout()
        buttons.addWidget(self.connect_button)
        buttons.addWidget(self.disconnect_button)
        self._devices = QWidget()
        self._devices_layout = QVBoxLayout(self._devices)
        self._devices_layout.setContentsMargins(0, 0, 0, 0)
        # the panels are never squeezed below their minimum height (the list scrolls)
        self._devices_layout.setSizeConstraint(QLayout.SizeConstraint.SetMinimumSize)
        self._devices_layout.addStretch(1)
        scroll = QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setWidget(self._devices)
        lay = QVBoxLayout(self)
        lay.addLayout(top)
        lay.addLayout(buttons)
        lay.addWidget(self.connection)
        lay.addWidget(self.owner)
        lay.addWidget(scroll, 1)
        lay.addWidget(self.message)
        self.panels: dict[str, DevicePanel] = {}
        self._manual = True
        # What the message says, to clear it when it stops applying: the axis whose move
        # or home it reports (and when that result came), or the bench's pose when a
        # command was refused.
        self._activity: tuple[str, float, str] | None = None
        self._refused_at: tuple[tuple, str] | None = None
        self._ages = QTimer(self)
        self._ages.setInterval(1000)
        self._ages.timeout.connect(self._refresh_ages)
        self._ages.start()
        self.browse.clicked.connect(self._browse)
        self.connect_button.clicked.connect(self.connect_bench)
        self.disconnect_button.clicked.connect(lambda: self.session.submit(Disconnect()))

    # bench choice -----------------------------------------------------------------
    def choose(self, name_or_path: str) -> None:
        """Select a built-in profile by name (a former name too) or add a profile file
        and select it."""
        name_or_path = canonical_bench_name(name_or_path)
        k = self.chooser.findData(name_or_path)
        if k < 0:
            self.chooser.addItem(Path(name_or_path).name, name_or_path)
            k = self.chooser.count() - 1
        self.chooser.setCurrentIndex(k)

    @property
    def chosen(self) -> str:
        return str(self.chooser.currentData())

    def _browse(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Bench profile", "",
                                              "Bench profiles (*.toml)")
        if path:
            self.choose(path)

    def connect_bench(self) -> BenchProfile | None:
        try:
            profile = load_profile(self.chosen)
        except ProfileError as err:
            self.show_message(str(err), error=True)
            return None
        self.benchChosen.emit(self.chosen)
        self.session.submit(Connect(profile))
        return profile

    # reports from the session ------------------------------------------------------
    def on_connection(self, status: ConnectionStatus) -> None:
        self.connection.setText(status.message)
        connected = status.state == "connected"
        self.connect_button.setEnabled(status.state != "connecting")
        self.disconnect_button.setEnabled(connected)
        if status.state == "disconnected" or (
                connected and not set(self.panels) <= set(status.roles)):
            self._rebuild(status.roles if connected else ())
        elif connected:
            self._pending_roles = list(status.roles)
        if status.state == "failed":
            self.show_message(status.message, error=True)

    def _rebuild(self, roles: tuple[str, ...]) -> None:
        for panel in self.panels.values():
            panel.hide()
            panel.setParent(None)
            panel.deleteLater()
        self.panels = {}
        self._pending_roles = list(roles)

    def on_states(self, states: dict[str, DeviceState]) -> None:
        for role, state in states.items():
            panel = self.panels.get(role)
            if panel is None or type(panel) is not panel_for(state.kind):
                if panel is not None:
                    panel.setParent(None)
                    panel.deleteLater()
                panel = panel_for(state.kind)(role, self.session)
                self.panels[role] = panel
                self._devices_layout.insertWidget(self._order(role), panel)
                panel.set_owned(self._manual)
            panel.set_state(state)
            panel.set_owned(self._manual)
        self._clear_stale(states)

    def _clear_stale(self, states: dict[str, DeviceState]) -> None:
        """Clear a message once it stops applying: "moving"/"homing" when the axis is read
        at rest after the command; a refusal when the bench's pose or light changed."""
        if self._activity is not None:
            role, since, text = self._activity
            st = states.get(role)
            if st is not None and st.t >= since and not st.value("moving"):
                self._activity = None
                self._clear_message(text)
        if self._refused_at is not None and pose_key(states) != self._refused_at[0]:
            text = self._refused_at[1]
            self._refused_at = None
            self._clear_message(text)
            for panel in self.panels.values():
                panel.clear_outcome()

    def _clear_message(self, text: str) -> None:
        if self.message.text() == text:  # not a newer message
            self.show_message("", error=False)

    def _refresh_ages(self) -> None:
        now = time.monotonic()
        for panel in self.panels.values():
            panel.refresh_age(now)

    def _order(self, role: str) -> int:
        roles = getattr(self, "_pending_roles", [])
        present = [r for r in roles if r in self.panels and r != role]
        k = roles.index(role) if role in roles else len(present)
        return sum(1 for r in present if roles.index(r) < k)

    def on_result(self, result: CommandResult) -> None:
        panel = self.panels.get(getattr(result.command, "role", None) or "")
        if panel is not None:
            panel.show_result(result)
        if result.refused or not result.ok:
            self.show_message(result.message, error=True)
        else:
            self.show_message(result.message, error=False)
        cmd = result.command
        if result.ok and isinstance(cmd, Home | MoveTo | Jog):
            self._activity = (cmd.role, time.monotonic(), result.message)
        if result.refused:
            self._refused_at = (pose_key(self.session.states()), result.message)

    def on_run(self, run: RunHandle | None) -> None:
        self._manual = run is None
        self.owner.setText("" if run is None else
                           "a run owns the bench: manual control is locked until it ends")
        self.connect_button.setEnabled(run is None)
        self.disconnect_button.setEnabled(run is None and self.session.connected)
        self.chooser.setEnabled(run is None)
        for panel in self.panels.values():
            panel.set_owned(self._manual)

    def show_message(self, text: str, *, error: bool) -> None:
        if text:  # an empty line keeps its style (a restyle re-polishes the label)
            self.message.setStyleSheet("color: #b71c1c" if error else "color: #1b5e20")
        self.message.setText(text)
        self.message.setToolTip(text)


def pose_key(states: dict[str, DeviceState]) -> tuple:
    """What a refusal depends on: each axis's position (to 0.01), homed flag, and which
    lights are on. A change means the refusal may no longer apply."""
    key = []
    for role, st in sorted(states.items()):
        if st.kind == "motion_axis":
            pos = st.value("position")
            key.append((role, None if pos is None else round(float(pos), 2),
                        bool(st.value("homed"))))
        elif "on" in st.values:
            key.append((role, bool(st.value("on"))))
    return tuple(key)
