"""Device panels, one class per device kind, chosen from a kind → panel registry.

A panel shows one device's :class:`gui.model.devices.DeviceState` (identity, state flags,
live values) and turns the operator's clicks into session commands; it never calls a
driver. The panel for a device is looked up by its kind's name (``motion_axis``,
``camera``, ``light_source``, ``power_meter``); a device of a kind without a panel gets
:class:`GenericPanel` (identity and raw values).

**Extension point.** A new kind registered in :mod:`gui.model.devices` gets its panel
with ``register_panel("lock_in", LockInPanel)``, a :class:`DevicePanel` subclass that
implements :meth:`DevicePanel.show_state` and sends :class:`gui.model.session.SetSetting`
or :class:`gui.model.session.Action` commands for its controls.
"""

from __future__ import annotations

import math
from typing import Any

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

from gui.model import format as fmt
from gui.model.devices import DeviceState
from gui.model.session import (
    Action,
    BenchSession,
    Home,
    Jog,
    MoveTo,
    Reconnect,
    SetLight,
    SetSetting,
    Stop,
)

__all__ = ["DevicePanel", "GenericPanel", "panel_for", "register_panel", "spin_box"]

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
        self.status = QLabel("")
        self.status.setObjectName("status")
        self.status.setTextFormat(Qt.RichText)
        self.error = QLabel("")
        self.error.setObjectName("error")
        self.error.setWordWrap(True)
        self.error.setStyleSheet("color: #b71c1c")
        self.error.setTextInteractionFlags(Qt.TextSelectableByMouse)
        self.reconnect = QPushButton("Reconnect")
        self.reconnect.setToolTip("close and open this device again (a cable plugged back in)")
        self.reconnect.clicked.connect(lambda: self.session.submit(Reconnect(self.role)))
        self.reconnect.hide()
        head = QHBoxLayout()
        head.addWidget(self.status, 1)
        head.addWidget(self.reconnect)
        self._outer.addWidget(self.identity)
        self._outer.addLayout(head)
        self.body = QWidget()
        self._outer.addWidget(self.body)
        self._outer.addWidget(self.error)
        self.error.hide()
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
        self.error.setVisible(bool(state.error))
        self.error.setText(state.error or "")
        self.reconnect.setVisible(not state.connected)
        self.show_state(state)

    def set_owned(self, manual: bool) -> None:
        """``manual``: the device worker owns the bench (no run) and commands are taken."""
        usable = manual and (self.state is None or self.state.connected)
        for w in self._controls:
            w.setEnabled(usable)

    def show_state(self, state: DeviceState) -> None:
        """Draw the kind's live values (subclasses)."""


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
        self.on.clicked.connect(lambda: self.session.submit(SetLight(True)))
        self.off.clicked.connect(lambda: self.session.submit(SetLight(False)))
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
        self.status.setText(badge("connected", state.connected))


class LockInPanel(DevicePanel):
    """A lock-in amplifier: R and θ (X, Y), its range and time constant (chosen from the
    instrument's tables, set through the driver), the reference, overload; auto-range."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.reading = QLabel("—")
        self.reading.setObjectName("reading")
        self.reading.setStyleSheet("font-size: 15pt; font-weight: 600")
        self.detail = QLabel("")
        self.detail.setObjectName("detail")
        self.sensitivity = QComboBox()
        self.sensitivity.setObjectName("sensitivity")
        self.time_constant = QComboBox()
        self.time_constant.setObjectName("time_constant")
        self.auto = QPushButton("Auto-range")
        self.auto.setObjectName("auto_range")
        form = QFormLayout(self.body)
        form.setContentsMargins(0, 0, 0, 0)
        form.addRow(self.reading)
        form.addRow(self.detail)
        form.addRow("range", self.sensitivity)
        form.addRow("time constant", self.time_constant)
        form.addRow(self.auto)
        self._tables: tuple[tuple[float, ...], tuple[float, ...]] = ((), ())
        self.sensitivity.activated.connect(lambda k: self.session.submit(SetSetting(
            self.role, "sensitivity_v", self.sensitivity.itemData(k))))
        self.time_constant.activated.connect(lambda k: self.session.submit(SetSetting(
            self.role, "time_constant_s", self.time_constant.itemData(k))))
        self.auto.clicked.connect(lambda: self.session.submit(Action(self.role, "auto_range")))
        self.controls(self.sensitivity, self.time_constant, self.auto)

    def _fill(self, box: QComboBox, values: tuple[float, ...], unit: str) -> None:
        box.clear()
        for v in values:
            box.addItem(fmt.si(v, unit, 3), v)

    def show_state(self, state: DeviceState) -> None:
        v, info = state.values, state.info
        tables = (tuple(info.get("sensitivities_v", ())), tuple(info.get("time_constants_s", ())))
        if tables != self._tables:
            self._tables = tables
            self._fill(self.sensitivity, tables[0], "V")
            self._fill(self.time_constant, tables[1], "s")
        for box, key in ((self.sensitivity, "sensitivity_v"),
                         (self.time_constant, "time_constant_s")):
            k = box.findData(v.get(key))
            if k >= 0:
                box.setCurrentIndex(k)
        self.reading.setText(f"R {fmt.si(v.get('r_v'), 'V')} rms, θ "
                             f"{v.get('theta_deg', math.nan):.1f}°")
        self.detail.setText(f"X {fmt.si(v.get('x_v'), 'V')}, Y {fmt.si(v.get('y_v'), 'V')}; "
                            f"reference {v.get('reference', '?')} "
                            f"{v.get('frequency_hz', math.nan):.4g} Hz")
        over = bool(v.get("overload"))
        self.status.setText(badge("connected", state.connected) + " "
                            + badge("OVERLOAD" if over else "in range", over, good=False))


class ShutterPanel(DevicePanel):
    """A shutter: its blade's state; open and close. *Close* stays available whenever
    the bench is manual (making safe is never refused)."""

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
        self.open.clicked.connect(lambda: self.session.submit(Action(self.role, "open")))
        self.close_button.clicked.connect(
            lambda: self.session.submit(Action(self.role, "close")))
        self.controls(self.open)
        self.controls(self.close_button)

    def show_state(self, state: DeviceState) -> None:
        is_open = state.values.get("state") == "open"
        self.status.setText(badge("connected", state.connected) + " "
                            + badge("OPEN" if is_open else "closed", is_open, good=False))


class FilterWheelPanel(DevicePanel):
    """A filter wheel: the slot in the beam and its band; move to another slot."""

    def __init__(self, role: str, session: BenchSession, parent: QWidget | None = None
                 ) -> None:
        super().__init__(role, session, parent)
        self.position = QLabel("—")
        self.position.setObjectName("position")
        self.slot = QComboBox()
        self.slot.setObjectName("slot")
        self.go = QPushButton("Move")
        self.go.setObjectName("go")
        form = QFormLayout(self.body)
        form.setContentsMargins(0, 0, 0, 0)
        form.addRow("in the beam", self.position)
        row = QHBoxLayout()
        row.addWidget(self.slot, 1)
        row.addWidget(self.go)
        form.addRow("slot", row)
        self._count = 0
        self.go.clicked.connect(lambda: self.session.submit(
            Action(self.role, "move_to", (self.slot.currentData(),))))
        self.controls(self.slot, self.go)

    @staticmethod
    def band(filters: dict, slot: int | None) -> str:
        """``"slot 2: 550 nm ± 5 nm"`` (FWHM/2), or ``"slot 4: empty"``."""
        centre, width, label = filters.get(slot, (None, None, ""))
        what = "empty" if centre is None else f"{centre:g} nm, FWHM {width:g} nm"
        return f"slot {slot}: {what}" + (f" ({label})" if label else "")

    def show_state(self, state: DeviceState) -> None:
        filters = dict(state.info.get("filters", {}))
        count = int(state.info.get("count", 0))
        if count != self._count:
            self._count = count
            self.slot.clear()
            for k in range(1, count + 1):
                self.slot.addItem(self.band(filters, k), k)
        self.position.setText(self.band(filters, state.values.get("position")))
        self.status.setText(badge("connected", state.connected))


register_panel("motion_axis", AxisPanel)
register_panel("camera", CameraPanel)
register_panel("light_source", SourcePanel)
register_panel("power_meter", PowerMeterPanel)
register_panel("lockin", LockInPanel)
register_panel("shutter", ShutterPanel)
register_panel("filter_wheel", FilterWheelPanel)
