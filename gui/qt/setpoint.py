"""A set-point field that shows the device's setting unless the operator is changing it.

A number field beside a *Set* button (an axis's velocity, the power meter's wavelength,
the camera's exposure) must not show a value the device does not have: a field that kept
its start-up default (1 deg/s while the axis runs at 20) would slow the axis 20× on the
next *Set*. :class:`SetpointField` follows the device's value read back on every poll;
once the operator edits it, the edit is *pending* (amber, "not sent") and the field stops
following until the command's result arrives; then it shows the device's value again —
the new one after a success, the unchanged one after a refusal (a refused exposure does
not stay in the field).
"""

from __future__ import annotations

import math

from PySide6.QtCore import QObject
from PySide6.QtWidgets import QDoubleSpinBox

__all__ = ["SetpointField"]

_PENDING_STYLE = "QDoubleSpinBox { background: #fff3e0 }"


class SetpointField(QObject):
    """Binds one :class:`QDoubleSpinBox` to a device setting (see the module docstring)."""

    def __init__(self, box: QDoubleSpinBox, what: str) -> None:
        super().__init__(box)
        self.box = box
        self.what = what
        self.pending = False
        self.device_value: float | None = None
        self._quiet = False
        self._tip = box.toolTip()
        box.valueChanged.connect(self._edited)

    def follow(self, value: float | None) -> None:
        """The device's setting as just read back: shown unless an edit is pending."""
        if value is None or not math.isfinite(value):
            return
        self.device_value = float(value)
        if not self.pending:
            self._show(self.device_value)

    def settled(self) -> None:
        """The command carrying the edit ended (done or refused): show the device's value."""
        self.pending = False
        self.box.setStyleSheet("")
        self.box.setToolTip(self._tip)
        if self.device_value is not None:
            self._show(self.device_value)

    def _show(self, value: float) -> None:
        if self.box.value() == value:
            return
        self._quiet = True
        try:
            self.box.setValue(value)
        finally:
            self._quiet = False

    def _edited(self, value: float) -> None:
        if self._quiet:
            return
        self.pending = self.device_value is None or value != self.device_value
        self.box.setStyleSheet(_PENDING_STYLE if self.pending else "")
        self.box.setToolTip(f"{self._tip} — not sent: press Set" if self.pending else self._tip)
