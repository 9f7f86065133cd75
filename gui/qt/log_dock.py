"""The log dock: warnings and errors from the engine, the pipelines and the bench,
filterable by level and text, copyable."""

from __future__ import annotations

import logging

from PySide6.QtCore import QObject, Signal
from PySide6.QtGui import QGuiApplication
from PySide6.QtWidgets import (
    QComboBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPlainTextEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from gui.model.analyses import AnalysisOutcome
from gui.model.logbook import LEVELS, LogBook, LogBookHandler, LogEntry, from_event, from_result

__all__ = ["LogDock"]

COLOURS = {"debug": "#757575", "info": "#212121", "warning": "#e65100", "error": "#b71c1c"}
#: Loggers whose records reach the dock (the project's packages and Python's warnings).
LOGGERS = ("drivers", "instrument", "analysis", "hw_mocks", "gui", "py.warnings")


class _Relay(QObject):
    entry = Signal(object)


class LogDock(QWidget):
    """The log, newest at the bottom."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("log_dock")
        self.book = LogBook()
        self._relay = _Relay(self)
        self._relay.entry.connect(self._append)
        self.level = QComboBox()
        self.level.setObjectName("log_level")
        for lv in LEVELS[1:]:
            self.level.addItem(f"{lv} and above", lv)
        self.filter = QLineEdit()
        self.filter.setObjectName("log_filter")
        self.filter.setPlaceholderText("filter …")
        self.copy = QPushButton("Copy")
        self.copy.setObjectName("log_copy")
        self.clear_button = QPushButton("Clear")
        self.count = QLabel("")
        self.view = QPlainTextEdit()
        self.view.setObjectName("log_view")
        self.view.setReadOnly(True)
        self.view.setMaximumBlockCount(self.book._entries.maxlen or 5000)
        top = QHBoxLayout()
        top.addWidget(self.level)
        top.addWidget(self.filter, 1)
        top.addWidget(self.count)
        top.addWidget(self.copy)
        top.addWidget(self.clear_button)
        lay = QVBoxLayout(self)
        lay.addLayout(top)
        lay.addWidget(self.view, 1)
        self.level.currentIndexChanged.connect(lambda _: self.render())
        self.filter.textChanged.connect(lambda _: self.render())
        self.copy.clicked.connect(self.copy_visible)
        self.clear_button.clicked.connect(self._clear)
        self.handler = LogBookHandler(self.book, on_entry=self._relay.entry.emit)
        logging.captureWarnings(True)
        for name in LOGGERS:
            logging.getLogger(name).addHandler(self.handler)

    def detach(self) -> None:
        """Stop receiving Python log records (the window closes)."""
        for name in LOGGERS:
            logging.getLogger(name).removeHandler(self.handler)

    # sources ------------------------------------------------------------------------
    def log(self, level: str, source: str, message: str) -> None:
        self._append(self.book.log(level, source, message))

    def on_event(self, ev) -> None:
        entry = self.book.add(from_event(ev))
        if entry is not None:
            self._append(entry)

    def on_result(self, result) -> None:
        entry = self.book.add(from_result(result))
        if entry is not None:
            self._append(entry)

    def on_analysis(self, out: AnalysisOutcome) -> None:
        self.log("info", out.name, f"{out.path.name}: {out.summary}")
        for note in out.notes:
            self.log("info", out.name, note)
        for warning in out.warnings:
            self.log("warning", out.name, warning)

    # view ---------------------------------------------------------------------------
    def _visible(self, entry: LogEntry) -> bool:
        return (LEVELS.index(entry.level) >= LEVELS.index(self.level.currentData())
                and self.filter.text().lower() in entry.text().lower())

    def _append(self, entry: LogEntry) -> None:
        if self._visible(entry):
            self.view.appendHtml(self._html(entry))
        self.count.setText(f"{self.book.total} entries")

    @staticmethod
    def _html(entry: LogEntry) -> str:
        text = entry.text().replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
        return f"<span style='color:{COLOURS[entry.level]}'>{text}</span>"

    def render(self) -> None:
        self.view.clear()
        for e in self.book.entries(min_level=self.level.currentData(),
                                   text=self.filter.text()):
            self.view.appendHtml(self._html(e))

    def visible_text(self) -> str:
        return self.book.as_text(min_level=self.level.currentData(), text=self.filter.text())

    def copy_visible(self) -> str:
        text = self.visible_text()
        QGuiApplication.clipboard().setText(text)
        return text

    def _clear(self) -> None:
        self.book.clear()
        self.view.clear()
