"""The Help menu's windows: the keyboard shortcuts and *About*, non-modal text dialogs."""

from __future__ import annotations

import html
import platform
from collections.abc import Sequence
from pathlib import Path

from PySide6 import __version__ as pyside_version
from PySide6.QtWidgets import QDialog, QDialogButtonBox, QTextBrowser, QVBoxLayout, QWidget

from instrument.version import package_version

__all__ = ["about_html", "shortcuts_html", "text_dialog"]


def shortcuts_html(shortcuts: Sequence[tuple[str, str]]) -> str:
    rows = "".join(f"<tr><td><b>{html.escape(k)}</b></td><td>{html.escape(what)}</td></tr>"
                   for k, what in shortcuts)
    return ("<table cellpadding='4'>" + rows + "</table><p>The red <b>STOP ALL</b> button "
            "in the toolbar does what Esc does.</p>")


def about_html(runs_dir: Path, settings_file: str) -> str:
    return (f"<h3>scatterlab {html.escape(package_version())}</h3>"
            "<p>Lab software for optical scattering: goniometer, cameras, power meter, "
            "lock-in; runs, recovery and analyses.</p>"
            f"<p>Runs folder: <code>{html.escape(str(runs_dir))}</code><br>"
            f"Settings: <code>{html.escape(settings_file)}</code><br>"
            f"Python {html.escape(platform.python_version())}, PySide6 "
            f"{html.escape(pyside_version)}</p>"
            "<p>The user guide's chapter <i>The operator GUI</i> describes every dock.</p>")


def text_dialog(parent: QWidget, title: str, text: str) -> QDialog:
    """A non-modal dialog showing ``text`` (HTML) with a Close button."""
    dialog = QDialog(parent)
    dialog.setWindowTitle(title)
    dialog.setObjectName(f"dialog:{title}")
    view = QTextBrowser()
    view.setObjectName("dialog_text")
    view.setOpenExternalLinks(False)
    view.setHtml(text)
    buttons = QDialogButtonBox(QDialogButtonBox.Close)
    buttons.rejected.connect(dialog.close)
    lay = QVBoxLayout(dialog)
    lay.addWidget(view)
    lay.addWidget(buttons)
    dialog.resize(520, 360)
    return dialog
