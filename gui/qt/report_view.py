"""An analysis's HTML report inside the application: its text, tables and figures in a
QTextBrowser (images resolved next to the report), and a web browser only on request.

``QDesktopServices.openUrl`` fails silently where no desktop launcher exists (a bench PC
without a desktop session, a kiosk): it returns ``False`` and Qt prints a line on stderr.
The viewer checks that result and says so in the window, with the report's path.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from PySide6.QtCore import QUrl
from PySide6.QtGui import QDesktopServices
from PySide6.QtWidgets import (
    QDialog,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QTextBrowser,
    QVBoxLayout,
    QWidget,
)

__all__ = ["ReportView"]


def _open_url(url: QUrl) -> bool:
    return bool(QDesktopServices.openUrl(url))


class ReportView(QDialog):
    """The report of one analysis; *Open in web browser* asks the desktop for one."""

    def __init__(self, parent: QWidget | None = None, *,
                 opener: Callable[[QUrl], bool] = _open_url) -> None:
        super().__init__(parent)
        self.setObjectName("report_view")
        self.setWindowTitle("Analysis report")
        self.opener = opener
        self.path: Path | None = None
        self.view = QTextBrowser()
        self.view.setObjectName("report_text")
        self.view.setOpenLinks(True)
        self.message = QLabel("")
        self.message.setObjectName("report_message")
        self.message.setWordWrap(True)
        self.external = QPushButton("Open in web browser")
        self.external.setObjectName("report_external")
        self.external.clicked.connect(self.open_external)
        close = QPushButton("Close")
        close.clicked.connect(self.close)
        row = QHBoxLayout()
        row.addWidget(self.message, 1)
        row.addWidget(self.external)
        row.addWidget(close)
        lay = QVBoxLayout(self)
        lay.addWidget(self.view, 1)
        lay.addLayout(row)
        self.resize(900, 700)

    def show_report(self, path: str | Path) -> None:
        """Show the report at ``path`` (its figures are found next to it)."""
        self.path = Path(path)
        self.setWindowTitle(f"Analysis report — {self.path.parent.name}")
        self.view.setSearchPaths([str(self.path.parent)])
        self.view.setSource(QUrl.fromLocalFile(str(self.path)))
        self.message.setText(f"report: {self.path}")
        self.show()
        self.raise_()

    def open_external(self) -> bool:
        """Open the report in the desktop's web browser; say so when none opens."""
        if self.path is None:
            return False
        if self.opener(QUrl.fromLocalFile(str(self.path))):
            self.message.setText(f"opened in the web browser: {self.path}")
            return True
        self.message.setText(f"<b>No web browser could be opened</b> on this computer (no "
                             f"desktop launcher). The report is shown here; its file is "
                             f"{self.path}")
        return False
