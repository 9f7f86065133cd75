"""The mouse wheel changes a number or a choice only in the field the operator is editing.

A spin box or a choice box takes wheel events by default, so scrolling a long panel with
the pointer passing over a *target* field changes the set-point under it (typed 200,
scrolled, got 197). :func:`install_wheel_guard` puts one event filter on the application,
so it holds for every such field, also those a panel creates later: while a field does
not have keyboard focus, a wheel event is left to its parent (the panel scrolls) and the
value stays; once the operator has clicked or tabbed into the field, the wheel steps it
as usual. The fields also lose ``WheelFocus`` when they are shown, so a wheel turn never
gives them focus either.
"""

from __future__ import annotations

from PySide6.QtCore import QEvent, QObject, Qt
from PySide6.QtWidgets import QAbstractSpinBox, QApplication, QComboBox

__all__ = ["install_wheel_guard"]

_FIELDS = (QAbstractSpinBox, QComboBox)


class _WheelGuard(QObject):
    """Application event filter (see the module docstring).

    Returning ``True`` with the event *ignored* skips the field, and Qt's propagation of
    wheel events offers it to the parent widgets (the scroll area) instead.
    """

    def eventFilter(self, obj: QObject, event: QEvent) -> bool:
        kind = event.type()
        if kind == QEvent.Type.Wheel:
            if isinstance(obj, _FIELDS) and not obj.hasFocus():
                event.ignore()
                return True
        elif kind in _BEFORE_WHEEL and isinstance(obj, _FIELDS) \
                and obj.focusPolicy() == Qt.FocusPolicy.WheelFocus:
            obj.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        return False


#: Events a field receives before any wheel event can reach it (shown, then the pointer
#: enters it): the place to take away its wheel focus, whenever it was made.
_BEFORE_WHEEL = (QEvent.Type.Polish, QEvent.Type.Show, QEvent.Type.Enter)


def install_wheel_guard() -> None:
    """Install the guard on the running application (once; later calls do nothing)."""
    app = QApplication.instance()
    if app is None or app.property("wheel_guard_installed"):
        return
    guard = _WheelGuard(app)
    app.installEventFilter(guard)
    for w in app.allWidgets():  # fields polished before the guard came
        if isinstance(w, _FIELDS) and w.focusPolicy() == Qt.FocusPolicy.WheelFocus:
            w.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
    app.setProperty("wheel_guard_installed", True)
