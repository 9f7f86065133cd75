"""Table columns an operator can read: no cell cut off."""

from __future__ import annotations

from PySide6.QtWidgets import QHeaderView, QTableWidget

__all__ = ["fit_columns"]


def fit_columns(t: QTableWidget) -> None:
    """Every column but the last as wide as its widest cell and header, kept so as rows
    change: a scroll bar rather than cut-off text; the last column takes the rest."""
    header = t.horizontalHeader()
    for c in range(t.columnCount() - 1):
        header.setSectionResizeMode(c, QHeaderView.ResizeToContents)
