"""The audit log: every state-changing request, who made it, when, and what came of it."""

from __future__ import annotations

import time
from dataclasses import dataclass

from instrument.server.db import ServerDB

__all__ = ["AuditLog", "AuditRow"]

#: At most this many characters of a request's description are kept.
WHAT_MAX = 500


@dataclass(frozen=True)
class AuditRow:
    time: float
    who: str
    role: str
    what: str
    status: int
    result: str


class AuditLog:
    def __init__(self, db: ServerDB) -> None:
        self.db = db

    def write(self, who: str, role: str, what: str, status: int, result: str) -> None:
        with self.db.transaction() as db:
            db.execute("INSERT INTO audit VALUES (?,?,?,?,?,?)",
                       (time.time(), who, role, what[:WHAT_MAX], int(status),
                        result[:WHAT_MAX]))

    def rows(self, *, since: float | None = None, limit: int = 200) -> list[AuditRow]:
        """The newest ``limit`` rows (since ``since``), oldest first."""
        rows = self.db.query(
            "SELECT * FROM audit WHERE time >= ? ORDER BY rowid DESC LIMIT ?",
            (since if since is not None else 0.0, int(limit)))
        return [AuditRow(*r) for r in reversed(rows)]
