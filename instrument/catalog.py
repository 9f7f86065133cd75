"""The run catalog: one SQLite file listing every run (id, sample, kind, status, ...).

The catalog is an index, not the data: the run files are authoritative and
:func:`Catalog.refresh` rebuilds a row from its file. Writes are short transactions in
WAL mode, so a GUI can read while a run writes.
"""

from __future__ import annotations

import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CATALOG_NAME", "Catalog", "RunRow"]

CATALOG_NAME = "catalog.sqlite"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    run_id    TEXT PRIMARY KEY,
    sample    TEXT NOT NULL,
    plan_kind TEXT NOT NULL,
    plan_name TEXT NOT NULL,
    bench     TEXT NOT NULL,
    status    TEXT NOT NULL,
    started   REAL NOT NULL,
    ended     REAL,
    n_points  INTEGER NOT NULL,
    n_planned INTEGER NOT NULL,
    path      TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS runs_started ON runs(started);
"""


@dataclass(frozen=True)
class RunRow:
    run_id: str
    sample: str
    plan_kind: str
    plan_name: str
    bench: str
    status: str
    started: float
    ended: float | None
    n_points: int
    n_planned: int
    path: str


class Catalog:
    """Open (creating if needed) the catalog in ``folder``."""

    def __init__(self, folder: str | Path) -> None:
        self.path = Path(folder) / CATALOG_NAME
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(self.path, timeout=10.0, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.executescript(_SCHEMA)
        self._db.commit()

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> Catalog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def add(self, row: RunRow) -> None:
        with self._db:
            self._db.execute(
                "INSERT OR REPLACE INTO runs VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                (row.run_id, row.sample, row.plan_kind, row.plan_name, row.bench, row.status,
                 row.started, row.ended, row.n_points, row.n_planned, row.path))

    def update(self, run_id: str, *, status: str | None = None, n_points: int | None = None,
               ended: float | None = None) -> None:
        sets, args = [], []
        for col, val in (("status", status), ("n_points", n_points), ("ended", ended)):
            if val is not None:
                sets.append(f"{col} = ?")
                args.append(val)
        if not sets:
            return
        with self._db:
            self._db.execute(f"UPDATE runs SET {', '.join(sets)} WHERE run_id = ?",
                             (*args, run_id))

    def get(self, run_id: str) -> RunRow | None:
        cur = self._db.execute("SELECT * FROM runs WHERE run_id = ?", (run_id,))
        row = cur.fetchone()
        return RunRow(*row) if row else None

    def find(self, *, status: str | None = None, sample: str | None = None,
             kind: str | None = None, since: float | None = None,
             limit: int | None = None) -> list[RunRow]:
        """Runs matching every filter given (``sample`` is a substring), newest first."""
        where, args = [], []
        if status:
            where.append("status = ?")
            args.append(status)
        if sample:
            where.append("sample LIKE ?")
            args.append(f"%{sample}%")
        if kind:
            where.append("plan_kind = ?")
            args.append(kind)
        if since is not None:
            where.append("started >= ?")
            args.append(since)
        sql = "SELECT * FROM runs"
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY started DESC"
        if limit:
            sql += f" LIMIT {int(limit)}"
        return [RunRow(*r) for r in self._db.execute(sql, args).fetchall()]


def now() -> float:
    return time.time()
