"""Questions to the operator before an action that loses time or data.

Every such question goes through one :class:`Questions` object, keyed by what it asks
("abort", "resume_connect", "close_run"), so a test or a scripted session can answer it
in advance (:meth:`Questions.answer`) instead of a modal box waiting for a click. An
unanswered question shows a Yes/No box whose default is *No*: Enter never confirms by
accident.
"""

from __future__ import annotations

from PySide6.QtWidgets import QMessageBox, QWidget

__all__ = ["Questions"]


class Questions:
    """Yes/No questions, answerable in advance per key."""

    def __init__(self) -> None:
        self._preset: dict[str, bool] = {}
        self.asked: list[str] = []  # keys asked so far (what a test checks was asked)

    def answer(self, key: str, yes: bool) -> None:
        """Answer every later question ``key`` with ``yes`` without showing a box."""
        self._preset[key] = bool(yes)

    def ask(self, key: str, parent: QWidget | None, title: str, text: str) -> bool:
        self.asked.append(key)
        if key in self._preset:
            return self._preset[key]
        answer = QMessageBox.question(parent, title, text,
                                      QMessageBox.Yes | QMessageBox.No, QMessageBox.No)
        return answer == QMessageBox.Yes
