"""Device panels, one class per device kind, chosen from a kind → panel registry.

A panel shows one device's :class:`instrument.bench.device_state.DeviceState` (identity,
state flags, live values) and turns the operator's clicks into session commands; it never calls a
driver. The panel for a device is looked up by its kind's name (``motion_axis``,
``camera``, ``light_source``, ``power_meter``); a device of a kind without a panel gets
:class:`GenericPanel` (identity and raw values).

**Extension point.** A new kind registered in :mod:`instrument.bench.device_state` gets its panel
with ``register_panel("lock_in", LockInPanel)``, a :class:`DevicePanel` subclass that
implements :meth:`DevicePanel.show_state` and sends :class:`gui.model.session.SetSetting`
or :class:`gui.model.session.Action` commands for its controls.
"""

from __future__ import annotations

import math
import time
from typing import Any, cast

from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSizePolicy,
    QVBoxLayout,
    QWidget,
)

from gui.model import filters, readouts
from gui.model import format as fmt
from gui.model.session import (
    Action,
    BenchSession,
    CommandResult,
    Home,
    Jog,
    MoveTo,
    Reconnect,
    SetLight,
    SetSetting,
    Stop,
)
from gui.qt.setpoint import SetpointField
from instrument.bench.device_state import AUTO_RANGE_TIMEOUT_S, DeviceState

__all__ = ["DevicePanel", "GenericPanel", "panel_for", "register_panel", "reserve_space",
           "spin_box"]

_PANELS: dict[str, type[DevicePanel]] = {}


def register_panel(kind: str, cls: type[DevicePanel]) -> None:
    """Use ``cls`` for devices of kind ``kind`` (replaces an earlier registration)."""
    _PANELS[kind] = cls


def panel_for(kind: str) -> type[DevicePanel]:
    return _PANELS.get(kind, GenericPanel)


def badge(text: str, on: bool | None, *, good: bool = True) -> str:
    """Rich text of a state badge: green (a good state that holds), amber (a state that
    needs attention that holds), grey (does not hold, or unknown)."""
    color = "#9e9e9e" if not on else ("#2e7d32" if good else "#e65100")
    return (f"<span style='background:{color}; color:white; padding:1px 4px; "
            f"border-radius:3px'>&nbsp;{text}&nbsp;</span>")


class DevicePanel(QGroupBox):
    """Base of the device panels: title, identity line, connection/error line."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, parent)
        self.role = role
        self.session = session
        self.state: DeviceState | None = None
        self.setObjectName(f"panel_{role}")
        self._outer = QVBoxLayout(self)
        self._outer.setContentsMargins(6, 4, 6, 6)
        self.identity = QLabel("…")
        self.identity.setObjectName("identity")
        self.identity.setTextInteractionFlags(Qt.TextSelectableByMouse)
        self.identity.setStyleSheet("color: #555")
        # A long firmware string must not widen the dock: the line is cut at the panel's
        # edge (not wrapped: a wrapped label makes the scrolled panels' heights depend on
        # their width) and the tooltip has it whole.
        self.identity.setSizePolicy(QSizePolicy.Ignored, QSizePolicy.Preferred)
        self.status = QLabel("")
        self.status.setObjectName("status")
        self.status.setTextFormat(Qt.RichText)
        self.age = QLabel("")
        self.age.setObjectName("age")
        self.age.setStyleSheet("color: #e65100")
        self.age.setToolTip("when this device was last read: a run reads only the axes it "
                            "moves, so the others show their state from before the run")
        self.pending = QLabel("")
        self.pending.setObjectName("pending")
        self.pending.setStyleSheet("color: #1565c0")
        self.pending.setToolTip("the bench server applies this change; its outcome shows "
                                "under the panel")
        self.pending.hide()
        self.error = note_label("error")
        self.reconnect = QPushButton("Reconnect")
        self.reconnect.setToolTip("close and open this device again (a cable plugged back in)")
        self.reconnect.clicked.connect(lambda: self.session.submit(Reconnect(self.role)))
        reserve_space(self.reconnect)
        self.reconnect.hide()
        head = QHBoxLayout()
        head.addWidget(self.status, 1)
        head.addWidget(self.pending)
        head.addWidget(self.age)
        head.addWidget(self.reconnect)
        self._outer.addWidget(self.identity)
        self._outer.addLayout(head)
        self.body = QWidget()
        self._outer.addWidget(self.body)
        # The device's error and the last refusal share two reserved lines under the
        # body: a message appearing or going never moves the panels below (a click aimed
        # at one field would land on another).
        self.outcome = note_label("outcome")
        notes = QWidget()
        notes.setObjectName("notes")
        notes_lay = QVBoxLayout(notes)
        notes_lay.setContentsMargins(0, 0, 0, 0)
        notes_lay.setSpacing(0)
        notes_lay.addWidget(self.error)
        notes_lay.addWidget(self.outcome)
        notes.setFixedHeight(2 * self.fontMetrics().lineSpacing() + 2)
        self._outer.addWidget(notes)
        self.error.hide()
        self.outcome.hide()
        self._controls: list[QWidget] = []
        self._editing = False

    def controls(self, *widgets: QWidget) -> None:
        """Widgets disabled while a run owns the bench or the device is unreachable."""
        self._controls.extend(widgets)

    def set_state(self, state: DeviceState) -> None:
        self.state = state
        ident = state.info.get("identity", {})
        if ident:
            text = f"{ident.get('vendor', '')} {ident.get('model', '')} s/n " \
                   f"{ident.get('serial', '')}"
            if ident.get("firmware"):
                text += f" fw {ident['firmware']}"
            self.identity.setText(text)
            self.identity.setToolTip(text)
        show_note(self.error, state.error or "")
        self.reconnect.setVisible(not state.connected)
        self.refresh_age()
        self.show_state(state)

    def refresh_age(self, now: float | None = None) -> None:
        """Show how old the shown state is, when it is old (see ``format.age``)."""
        if self.state is None:
            self.age.setText("")
            return
        now = time.monotonic() if now is None else now
        self.age.setText(fmt.age(now - self.state.t))

    def set_owned(self, manual: bool, why: str = "") -> None:
        """``manual``: the device worker owns the bench (no run) and commands are taken;
        ``why``: the greyed controls' tooltip (the client window says why not)."""
        usable = manual and (self.state is None or self.state.connected)
        for w in self._controls:
            if w.isEnabled() != usable:
                w.setEnabled(usable)
            if why and not usable:
                w.setToolTip(why)

    def set_pending(self, text: str) -> None:
        """A change sent to the bench server and not yet applied: ``text`` ("applying…")
        in the panel's head until its end arrives; "" when it ended."""
        if self.pending.text() != text:
            self.pending.setText(text)
            self.pending.setVisible(bool(text))

    def show_state(self, state: DeviceState) -> None:
        """Draw the kind's live values (subclasses)."""

    def show_result(self, result: CommandResult) -> None:
        """A command of this device ended: a refusal or the driver's error (a setting it
        rejected) stays shown under the panel until a command of this device succeeds."""
        failed = result.refused or not result.ok
        show_note(self.outcome, result.message if failed else "")

    def clear_outcome(self) -> None:
        """The refusal shown no longer applies (the bench moved since)."""
        show_note(self.outcome, "")


def note_label(name: str) -> QLabel:
    """A red line for an error or a refusal; the full text is also its tooltip (the row
    is reserved and may clip a long message; the bench panel's message shows it whole)."""
    label = QLabel("")
    label.setObjectName(name)
    label.setWordWrap(True)
    label.setStyleSheet("color: #b71c1c")
    label.setTextInteractionFlags(Qt.TextSelectableByMouse)
    label.setAlignment(Qt.AlignLeft | Qt.AlignTop)
    return label


def show_note(label: QLabel, text: str) -> None:
    label.setText(text)
    label.setToolTip(text)
    label.setVisible(bool(text))


def reserve_space(widget: QWidget) -> None:
    """Keep ``widget``'s place in its layout while it is hidden (no layout jump)."""
    policy = widget.sizePolicy()
    policy.setRetainSizeWhenHidden(True)
    widget.setSizePolicy(policy)


class GenericPanel(DevicePanel):
    """A device of a kind the GUI has no panel for: identity and raw values."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.values = QLabel("")
        self.values.setWordWrap(True)
        lay = QVBoxLayout(self.body)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.values)

    def show_state(self, state: DeviceState) -> None:
        self.status.setText(badge("connected", state.connected) + f" kind {state.kind}")
        self.values.setText(", ".join(f"{k} = {_short(v)}" for k, v in state.values.items()))


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.5g}"
    return str(v)


def spin_box(low: float, high: float, decimals: int, value: float, suffix: str = "",
             step: float = 1.0) -> QDoubleSpinBox:
    """A number field that reports only finished edits (no command per keystroke)."""
    box = QDoubleSpinBox()
    box.setRange(low, high)
    box.setDecimals(decimals)
    box.setSingleStep(step)
    box.setValue(value)
    if suffix:
        box.setSuffix(f" {suffix}")
    box.setKeyboardTracking(False)
    box.setSizePolicy(QSizePolicy.Expanding, QSizePolicy.Fixed)
    return box


class AxisPanel(DevicePanel):
    """A motion axis: position, homed/moving/error, velocity; home, jog, absolute target."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.position = QLabel("—")
        self.position.setObjectName("position")
        self.position.setStyleSheet("font-size: 15pt; font-weight: 600")
        self.velocity = QLabel("—")
        self.velocity.setObjectName("velocity")
        self.limits = QLabel("—")
        self.home = QPushButton("Home")
        self.home.setObjectName("home")
        self.stop = QPushButton("Stop")
        self.stop.setObjectName("stop")
        self.step = spin_box(0.0001, 360.0, 4, 1.0)
        self.step.setObjectName("step")
        self.step.setToolTip("jog step")
        self.minus = QPushButton("−")
        self.minus.setObjectName("jog_minus")
        self.plus = QPushButton("+")
        self.plus.setObjectName("jog_plus")
        self.target = spin_box(-1e6, 1e6, 4, 0.0)
        self.target.setObjectName("target")
        self.go = QPushButton("Go")
        self.go.setObjectName("go")
        self.new_velocity = spin_box(0.0001, 1e4, 4, 1.0)
        self.new_velocity.setObjectName("new_velocity")
        self.new_velocity.setToolTip("the axis's velocity; type a new one and press Set")
        self.velocity_field = SetpointField(self.new_velocity, "velocity")
        self.set_velocity = QPushButton("Set")
        self.set_velocity.setObjectName("set_velocity")
        for b in (self.minus, self.plus):
            b.setFixedWidth(32)
        grid = QGridLayout(self.body)
        grid.setContentsMargins(0, 0, 0, 0)
        grid.addWidget(self.position, 0, 0, 1, 3)
        grid.addWidget(self.home, 0, 3)
        grid.addWidget(self.stop, 0, 4)
        grid.addWidget(QLabel("jog"), 1, 0)
        grid.addWidget(self.minus, 1, 1)
        grid.addWidget(self.step, 1, 2)
        grid.addWidget(self.plus, 1, 3)
        grid.addWidget(QLabel("target"), 2, 0)
        grid.addWidget(self.target, 2, 1, 1, 3)
        grid.addWidget(self.go, 2, 4)
        grid.addWidget(QLabel("velocity"), 3, 0)
        grid.addWidget(self.velocity, 3, 1)
        grid.addWidget(self.new_velocity, 3, 2, 1, 2)
        grid.addWidget(self.set_velocity, 3, 4)
        grid.addWidget(self.limits, 4, 0, 1, 5)
        self.home.clicked.connect(lambda: self.session.submit(Home(self.role)))
        self.stop.clicked.connect(lambda: self.session.submit(Stop(self.role)))
        self.minus.clicked.connect(lambda: self.session.submit(Jog(self.role,
                                                                   -self.step.value())))
        self.plus.clicked.connect(lambda: self.session.submit(Jog(self.role, self.step.value())))
        self.go.clicked.connect(lambda: self.session.submit(MoveTo(self.role,
                                                                   self.target.value())))
        self.set_velocity.clicked.connect(lambda: self.session.submit(
            SetSetting(self.role, "velocity", self.new_velocity.value())))
        self.controls(self.home, self.minus, self.plus, self.step, self.target, self.go,
                      self.new_velocity, self.set_velocity)
        self._units = ""
        self._ranged = False

    def show_state(self, state: DeviceState) -> None:
        v, info = state.values, state.info
        units = info.get("units", "")
        if units != self._units:
            self._units = units
            for box in (self.step, self.target):
                box.setSuffix(f" {units}")
            self.new_velocity.setSuffix(f" {units}/s")
        limits = info.get("limits")
        if limits is not None and not self._ranged and all(map(math.isfinite, limits)):
            self.target.setRange(limits[0] - 1e3, limits[1] + 1e3)  # the guard decides
            self._ranged = True
        self.position.setText(fmt.position(v.get("position"), units))
        vel = info.get("velocity")
        self.velocity.setText("—" if vel is None else f"{vel:.4g} {units}/s")
        self.velocity_field.follow(vel)
        if limits is not None:
            self.limits.setText(f"soft limits [{limits[0]:g}, {limits[1]:g}] {units}")
        homed = bool(v.get("homed"))
        moving = bool(v.get("moving"))
        flags = [badge("connected", state.connected),
                 badge("homed", True) if homed else badge("not homed", True, good=False),
                 badge("homing" if v.get("homing") else "moving" if moving else "at rest",
                       moving, good=False)]
        if v.get("at_limit"):
            flags.append(badge("at limit", True, good=False))
        if state.error:
            flags.append(badge("error", True, good=False))
        self.status.setText(" ".join(flags))


    def show_result(self, result: CommandResult) -> None:
        super().show_result(result)
        if isinstance(result.command, SetSetting) and result.command.name == "velocity":
            self.velocity_field.settled()


class CameraPanel(DevicePanel):
    """A camera: sensor, exposure, gain, streaming; its picture is the camera view."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.summary = QLabel("—")
        self.summary.setObjectName("summary")
        self.summary.setWordWrap(True)
        lay = QVBoxLayout(self.body)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.summary)

    def show_state(self, state: DeviceState) -> None:
        v, info = state.values, state.info
        h, w = info.get("sensor", (0, 0))
        self.summary.setText(
            f"{w}×{h} px, {info.get('bit_depth', '?')}-bit; exposure "
            f"{fmt.si(v.get('exposure_us', math.nan) * 1e-6, 's')}, gain "
            f"{v.get('gain', math.nan):.3g}; dropped {v.get('dropped', 0)}")
        streaming = bool(v.get("streaming"))
        self.status.setText(badge("connected", state.connected) + " "
                            + badge("streaming" if streaming else "idle", streaming,
                                    good=False))


class GenICamCameraPanel(CameraPanel):
    """A GenICam camera (Basler): besides the camera summary, its exposure, gain, bit depth,
    trigger mode and black level, each shown as read back and set through the driver; a
    value the camera refuses leaves the driver's own words under the panel."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        # The fields' ranges are wide: the driver checks against the camera's node map
        # and its refusal is shown (as an axis target's range leaves it to the guard).
        self.new_exposure = spin_box(0.001, 60e6, 3, 1000.0, "µs")
        self.new_exposure.setObjectName("new_exposure")
        self.new_gain = spin_box(-100.0, 100.0, 2, 0.0, "dB")
        self.new_gain.setObjectName("new_gain")
        self.new_black = spin_box(-1e5, 1e5, 2, 0.0)
        self.new_black.setObjectName("new_black_level")
        self.bit_depth = QComboBox()
        self.bit_depth.setObjectName("bit_depth")
        self.bit_depth.setToolTip("the camera's pixel format: Mono8, Mono10, Mono12, Mono16")
        self.trigger = QComboBox()
        self.trigger.setObjectName("trigger_mode")
        self.trigger.setToolTip("software: one trigger per frame (each exposure starts after "
                                "the call); hardware: the frame waits for a pulse on the "
                                "input line; free run: the camera exposes continuously")
        self.fields: dict[str, tuple[SetpointField, QDoubleSpinBox]] = {}
        form = QFormLayout()
        form.setContentsMargins(0, 0, 0, 0)
        for name, label, box in (("exposure_us", "exposure", self.new_exposure),
                                 ("gain", "gain", self.new_gain),
                                 ("black_level", "black level", self.new_black)):
            field = SetpointField(box, label)
            button = QPushButton("Set")
            button.setObjectName(f"set_{name}")
            button.clicked.connect(lambda _=False, n=name, b=box: self.session.submit(
                SetSetting(self.role, n, b.value())))
            row = QHBoxLayout()
            row.addWidget(box, 1)
            row.addWidget(button)
            form.addRow(label, row)
            self.fields[name] = (field, box)
            self.controls(box, button)
        form.addRow("bit depth", self.bit_depth)
        form.addRow("trigger", self.trigger)
        cast(QVBoxLayout, self.body.layout()).addLayout(form)  # CameraPanel's layout
        self.bit_depth.activated.connect(lambda k: self.session.submit(
            Action(self.role, "set_bit_depth", (self.bit_depth.itemData(k),))))
        self.trigger.activated.connect(lambda k: self.session.submit(
            SetSetting(self.role, "trigger_mode", self.trigger.itemData(k))))
        self.controls(self.bit_depth, self.trigger)
        self._choices: tuple = ()

    def show_state(self, state: DeviceState) -> None:
        super().show_state(state)
        v, info = state.values, state.info
        choices = (tuple(info.get("bit_depths", ())), tuple(info.get("trigger_modes", ())))
        if choices != self._choices:
            self._choices = choices
            fill(self.bit_depth, [(f"{b}-bit (Mono{b})", b) for b in choices[0]])
            line = info.get("hardware_line", "")
            fill(self.trigger, [(_TRIGGER_TEXT.get(m, m).format(line=line), m)
                                for m in choices[1]])
        for box, key in ((self.bit_depth, "bit_depth"), (self.trigger, "trigger_mode")):
            k = box.findData(v.get(key))
            if k >= 0 and not box.view().isVisible():  # not while choosing
                box.setCurrentIndex(k)
        for name, (field, _box) in self.fields.items():
            field.follow(v.get(name))

    def show_result(self, result: CommandResult) -> None:
        super().show_result(result)
        cmd = result.command
        if isinstance(cmd, SetSetting) and cmd.name in self.fields:
            self.fields[cmd.name][0].settled()


_TRIGGER_TEXT = {"software": "software", "hardware": "hardware ({line})",
                 "free_run": "free run"}


class SourcePanel(DevicePanel):
    """A light source (or a shutter in front of one): on/off."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.on = QPushButton("Light on")
        self.on.setObjectName("light_on")
        self.off = QPushButton("Light off")
        self.off.setObjectName("light_off")
        self.power = QLabel("")
        self.power.setObjectName("power")
        lay = QHBoxLayout(self.body)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.on)
        lay.addWidget(self.off)
        lay.addWidget(self.power, 1)
        self.on.clicked.connect(lambda: self.session.submit(SetLight(True, self.role)))
        self.off.clicked.connect(lambda: self.session.submit(SetLight(False, self.role)))
        self.controls(self.on)
        # "Light off" stays available whenever the bench is manual: making safe is
        # never refused.
        self.controls(self.off)

    def show_state(self, state: DeviceState) -> None:
        on = state.values.get("on")
        self.status.setText(badge("connected", state.connected) + " "
                            + badge("light ON" if on else "light off", bool(on), good=False))
        p = state.values.get("power_w")
        self.power.setText("" if p is None else f"setpoint {fmt.si(p, 'W')}")


class PowerMeterPanel(DevicePanel):
    """A power meter: the reading with its wavelength; set the wavelength, dark-zero."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.reading = QLabel("—")
        self.reading.setObjectName("reading")
        self.reading.setStyleSheet("font-size: 15pt; font-weight: 600")
        self.wavelength = QLabel("—")
        self.wavelength.setObjectName("wavelength")
        self.new_wavelength = spin_box(100.0, 25000.0, 1, 633.0, "nm")
        self.new_wavelength.setObjectName("new_wavelength")
        self.new_wavelength.setToolTip("the wavelength the meter corrects its reading for; "
                                       "type a new one and press Set")
        self.wavelength_field = SetpointField(self.new_wavelength, "wavelength")
        self.set_wavelength = QPushButton("Set")
        self.set_wavelength.setObjectName("set_wavelength")
        self.zero = QPushButton("Dark zero")
        self.zero.setToolTip("zero the sensor: block the light first")
        form = QFormLayout(self.body)
        form.setContentsMargins(0, 0, 0, 0)
        form.addRow(self.reading)
        form.addRow("at", self.wavelength)
        row = QHBoxLayout()
        row.addWidget(self.new_wavelength, 1)
        row.addWidget(self.set_wavelength)
        row.addWidget(self.zero)
        form.addRow("wavelength", row)
        self.set_wavelength.clicked.connect(lambda: self.session.submit(
            SetSetting(self.role, "wavelength_nm", self.new_wavelength.value())))
        self.zero.clicked.connect(lambda: self.session.submit(Action(self.role, "zero")))
        self.controls(self.new_wavelength, self.set_wavelength, self.zero)

    def show_state(self, state: DeviceState) -> None:
        v = state.values
        self.reading.setText(fmt.si(v.get("power_w"), "W"))
        wl = v.get("wavelength_nm")
        self.wavelength.setText("—" if wl is None else f"{wl:g} nm")
        self.wavelength_field.follow(wl)
        self.status.setText(badge("connected", state.connected))

    def show_result(self, result: CommandResult) -> None:
        super().show_result(result)
        if isinstance(result.command, SetSetting) and result.command.name == "wavelength_nm":
            self.wavelength_field.settled()


class LockInPanel(DevicePanel):
    """A lock-in amplifier: R and θ (X, Y), the reference and its frequency, the latched
    overload flags with what to do; range, time constant and reference source chosen from
    the instrument's own tables and set through the driver; auto-range."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.reading = QLabel("—")
        self.reading.setObjectName("reading")
        self.reading.setStyleSheet("font-size: 15pt; font-weight: 600")
        self.detail = QLabel("")
        self.detail.setObjectName("detail")
        self.advice = QLabel("")
        self.advice.setObjectName("advice")
        self.advice.setWordWrap(True)
        self.advice.setStyleSheet("color: #e65100")
        self.sensitivity = QComboBox()
        self.sensitivity.setObjectName("sensitivity")
        self.time_constant = QComboBox()
        self.time_constant.setObjectName("time_constant")
        self.reference = QComboBox()
        self.reference.setObjectName("reference")
        self.auto = QPushButton("Auto-range")
        self.auto.setObjectName("auto_range")
        self.auto.setToolTip("let the lock-in choose its range (only while the axes are at "
                             f"rest; at most {AUTO_RANGE_TIMEOUT_S:g} s)")
        form = QFormLayout(self.body)
        form.setContentsMargins(0, 0, 0, 0)
        form.addRow(self.reading)
        form.addRow(self.detail)
        form.addRow(self.advice)
        row = QHBoxLayout()
        row.addWidget(self.sensitivity, 1)
        row.addWidget(self.auto)
        form.addRow("range", row)
        form.addRow("time constant", self.time_constant)
        form.addRow("reference", self.reference)
        self._tables: tuple = ()
        for box, name in ((self.sensitivity, "sensitivity_v"),
                          (self.time_constant, "time_constant_s"),
                          (self.reference, "reference_source")):
            box.activated.connect(lambda k, box=box, name=name: self.session.submit(
                SetSetting(self.role, name, box.itemData(k))))
        self.auto.clicked.connect(lambda: self.session.submit(Action(self.role, "auto_range")))
        self.controls(self.sensitivity, self.time_constant, self.reference, self.auto)

    def show_state(self, state: DeviceState) -> None:
        v, info = state.values, state.info
        tables = (tuple(info.get("sensitivities_v", ())), tuple(info.get("time_constants_s", ())),
                  tuple(info.get("reference_sources", ())))
        if tables != self._tables:
            self._tables = tables
            fill(self.sensitivity, readouts.choices(tables[0], "V"))
            fill(self.time_constant, readouts.choices(tables[1], "s"))
            fill(self.reference, [(s, s) for s in tables[2]])
        for box, table, key in ((self.sensitivity, tables[0], "sensitivity_v"),
                                (self.time_constant, tables[1], "time_constant_s")):
            k = readouts.nearest(table, v.get(key))
            if k is not None and not box.view().isVisible():  # not while choosing
                box.setCurrentIndex(k)
        k = self.reference.findData(v.get("reference"))
        if k >= 0 and not self.reference.view().isVisible():
            self.reference.setCurrentIndex(k)
        self.reading.setText(readouts.lockin_reading(v))
        self.detail.setText(readouts.lockin_detail(v))
        faults = readouts.lockin_faults(v)
        self.advice.setText("; ".join(f.advice for f in faults))
        self.advice.setVisible(bool(faults))
        flags = [badge("connected", state.connected)]
        flags += [badge(f.badge, True, good=False) for f in faults] or [badge("in range", True)]
        self.status.setText(" ".join(flags))


class ShutterPanel(DevicePanel):
    """A shutter (a light source): its blade's state; open and close. Opening passes the
    beam check of *Light on*; *Close* stays available whenever the bench is manual
    (making safe is never refused)."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.open = QPushButton("Open")
        self.open.setObjectName("open")
        self.close_button = QPushButton("Close")
        self.close_button.setObjectName("close")
        lay = QHBoxLayout(self.body)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.open)
        lay.addWidget(self.close_button)
        self.open.clicked.connect(lambda: self.session.submit(SetLight(True, self.role)))
        self.close_button.clicked.connect(
            lambda: self.session.submit(SetLight(False, self.role)))
        self.controls(self.open, self.close_button)

    def show_state(self, state: DeviceState) -> None:
        is_open = readouts.shutter_open(state.values)
        text = "?" if is_open is None else "OPEN" if is_open else "closed"
        self.status.setText(badge("connected", state.connected) + " "
                            + badge(text, bool(is_open), good=False))


class FilterWheelPanel(DevicePanel):
    """A filter wheel: the slot in the beam and its band (from the driver's configuration
    or the profile's ``[[filter_wheel.filters]]``), the slot count and speed; move to a
    slot, change the speed."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.position = QLabel("—")
        self.position.setObjectName("position")
        self.position.setStyleSheet("font-size: 13pt; font-weight: 600")
        self.count = QLabel("—")
        self.count.setObjectName("count")
        self.slot = QComboBox()
        self.slot.setObjectName("slot")
        self.go = QPushButton("Move")
        self.go.setObjectName("go")
        self.go.setToolTip("put this slot in the beam (only while the axes are at rest)")
        self.speed = QComboBox()
        self.speed.setObjectName("speed")
        form = QFormLayout(self.body)
        form.setContentsMargins(0, 0, 0, 0)
        form.addRow("in the beam", self.position)
        form.addRow("slots", self.count)
        row = QHBoxLayout()
        row.addWidget(self.slot, 1)
        row.addWidget(self.go)
        form.addRow("move to", row)
        form.addRow("speed", self.speed)
        self._shown: tuple = ()
        self._profile_bands: tuple[Any, dict] = (None, {})
        self.go.clicked.connect(lambda: self.session.submit(
            Action(self.role, "move_to", (self.slot.currentData(),))))
        self.speed.activated.connect(lambda k: self.session.submit(
            SetSetting(self.role, "speed", self.speed.itemData(k))))
        self.controls(self.slot, self.go, self.speed)

    def bands(self, state: DeviceState) -> dict:
        """The driver's bands, completed from the connected profile's filter list."""
        profile = self.session.profile
        if self._profile_bands[0] is not profile:
            found, _ = filters.bands_from_profile(
                getattr(profile, "source_text", None), self.role)
            self._profile_bands = (profile, found)
        return filters.merge_bands(filters.bands_from_info(state.info.get("filters")),
                                   self._profile_bands[1])

    def show_state(self, state: DeviceState) -> None:
        v, info = state.values, state.info
        bands = self.bands(state)
        count = int(info.get("count", 0))
        shown = (count, tuple(sorted(bands.items())), tuple(info.get("speeds", ())))
        if shown != self._shown:
            self._shown = shown
            fill(self.slot, [(filters.slot_label(bands, k), k) for k in range(1, count + 1)])
            fill(self.speed, [(s, s) for s in shown[2]])
        self.position.setText(filters.slot_label(bands, v.get("position")))
        self.count.setText(str(count) if count else "—")
        k = self.speed.findData(v.get("speed"))
        if k >= 0 and not self.speed.view().isVisible():
            self.speed.setCurrentIndex(k)
        self.status.setText(badge("connected", state.connected))


class ModulatorPanel(DevicePanel):
    """A photoelastic modulator: its peak retardation (waves at the wavelength, and the
    radians the 1f/2f Bessel weights take) and the modulation frequency the lock-in takes
    as its reference; set the amplitude and the wavelength it is expressed at. The
    frequency is the optical head's resonance: read back, never set."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.amplitude = QLabel("—")
        self.amplitude.setObjectName("amplitude")
        self.amplitude.setStyleSheet("font-size: 13pt; font-weight: 600")
        self.frequency = QLabel("—")
        self.frequency.setObjectName("frequency")
        self.frequency.setToolTip("the optical head's resonance: the lock-in's reference "
                                  "(harmonics 1 and 2 carry the polarisation signals)")
        self.new_amplitude = spin_box(0.0, 5.0, 4, 0.383, "waves", step=0.01)
        self.new_amplitude.setObjectName("new_amplitude")
        self.new_amplitude.setToolTip("peak retardation in waves at the wavelength; "
                                      "type a new one and press Set")
        self.amplitude_field = SetpointField(self.new_amplitude, "retardation")
        self.set_amplitude = QPushButton("Set")
        self.set_amplitude.setObjectName("set_amplitude")
        self.new_wavelength = spin_box(100.0, 25000.0, 1, 632.8, "nm")
        self.new_wavelength.setObjectName("new_wavelength")
        self.new_wavelength.setToolTip("the wavelength the amplitude is expressed at (the "
                                       "drive stays: the same nanometres are fewer waves "
                                       "at a longer wavelength)")
        self.wavelength_field = SetpointField(self.new_wavelength, "wavelength")
        self.set_wavelength = QPushButton("Set")
        self.set_wavelength.setObjectName("set_wavelength")
        form = QFormLayout(self.body)
        form.setContentsMargins(0, 0, 0, 0)
        form.addRow("amplitude", self.amplitude)
        form.addRow("frequency", self.frequency)
        for label, box, button in (("set amplitude", self.new_amplitude, self.set_amplitude),
                                   ("at wavelength", self.new_wavelength,
                                    self.set_wavelength)):
            row = QHBoxLayout()
            row.addWidget(box, 1)
            row.addWidget(button)
            form.addRow(label, row)
        self.set_amplitude.clicked.connect(lambda: self.session.submit(
            SetSetting(self.role, "retardation_waves", self.new_amplitude.value())))
        self.set_wavelength.clicked.connect(lambda: self.session.submit(
            SetSetting(self.role, "wavelength_nm", self.new_wavelength.value())))
        self.controls(self.new_amplitude, self.set_amplitude, self.new_wavelength,
                      self.set_wavelength)

    def show_state(self, state: DeviceState) -> None:
        waves = state.values.get("retardation_waves")
        wl = state.info.get("wavelength_nm")
        freq = state.values.get("frequency_hz")
        if waves is None:
            self.amplitude.setText("—")
        else:
            at = "" if wl is None else f" at {wl:g} nm"
            self.amplitude.setText(f"{waves:.4f} waves{at} ({2.0 * math.pi * waves:.3f} rad)")
        self.frequency.setText(fmt.si(freq, "Hz"))
        self.amplitude_field.follow(waves)
        self.wavelength_field.follow(wl)
        self.status.setText(badge("connected", state.connected))

    def show_result(self, result: CommandResult) -> None:
        super().show_result(result)
        if isinstance(result.command, SetSetting):
            if result.command.name == "retardation_waves":
                self.amplitude_field.settled()
            elif result.command.name == "wavelength_nm":
                self.wavelength_field.settled()


def fill(box: QComboBox, items: list[tuple[str, Any]]) -> None:
    """Replace a choice box's items, keeping the selected value where it is still there."""
    current = box.currentData()
    box.clear()
    for text, data in items:
        box.addItem(text, data)
    k = box.findData(current)
    if k >= 0:
        box.setCurrentIndex(k)


register_panel("motion_axis", AxisPanel)
register_panel("camera", CameraPanel)
register_panel("genicam_camera", GenICamCameraPanel)
register_panel("light_source", SourcePanel)
register_panel("power_meter", PowerMeterPanel)
register_panel("lockin", LockInPanel)
register_panel("shutter", ShutterPanel)
register_panel("filter_wheel", FilterWheelPanel)
register_panel("modulator", ModulatorPanel)
