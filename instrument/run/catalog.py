"""The run catalog: one SQLite file listing every run (id, sample, kind, status, ...).

The catalog is an index, not the data: the run files are authoritative. A run updates
its row when it starts, pauses and ends, so a process killed mid-run leaves a row saying
"running"; :meth:`Catalog.refresh` corrects such a row from the run's journal (committed
points, last status) once no process holds the run file open, marking it "interrupted".
Writes are short transactions in WAL mode, so a GUI can read while a run writes.

Every repair of a run file (``recover``/``salvage``: what was lost, which points, where the
damaged original went) is a row of the ``repairs`` table, so ``scatterlab runs`` shows it
next to the run long after the console message scrolled away.
"""

from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass, replace
from pathlib import Path

import h5py

from instrument.run.health import held_by_this_process, is_lock_refusal
from instrument.run.journal import read_journal

__all__ = ["CATALOG_NAME", "Catalog", "RepairRow", "RunRow"]

CATALOG_NAME = "catalog.sqlite"

#: Statuses a row holds only while a process drives the run.
LIVE_STATUSES = ("created", "running", "paused")

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
CREATE TABLE IF NOT EXISTS repairs (
    run_id      TEXT NOT NULL,
    time        REAL NOT NULL,
    what        TEXT NOT NULL,
    points_lost TEXT NOT NULL,
    original    TEXT
);
CREATE INDEX IF NOT EXISTS repairs_run ON repairs(run_id);
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


@dataclass(frozen=True)
class RepairRow:
    """One repair of a run file: when, what it did (sentences), the points whose frames it
    found lost, and where the damaged original went (``None``: repaired in place)."""

    run_id: str
    time: float
    what: tuple[str, ...]
    points_lost: tuple[int, ...]
    original: str | None


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

    def __exit__(self, *exc: object) -> None:
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

    def add_repair(self, row: RepairRow) -> None:
        with self._db:
            self._db.execute("INSERT INTO repairs VALUES (?,?,?,?,?)",
                             (row.run_id, row.time, json.dumps(list(row.what)),
                              json.dumps(list(row.points_lost)), row.original))

    def repairs(self, run_id: str) -> list[RepairRow]:
        """The repairs of a run, oldest first."""
        cur = self._db.execute("SELECT * FROM repairs WHERE run_id = ? ORDER BY time",
                               (run_id,))
        return [RepairRow(r[0], r[1], tuple(json.loads(r[2])), tuple(json.loads(r[3])), r[4])
                for r in cur.fetchall()]

    def get(self, run_id: str) -> RunRow | None:
        cur = self._db.execute("SELECT * FROM runs WHERE run_id = ?", (run_id,))
        row = cur.fetchone()
        return RunRow(*row) if row else None

    def refresh(self, row: RunRow) -> RunRow:
        """``row`` corrected from its run file when the process that ran it is gone.

        A row in a live status (created/running/paused) whose run file no process holds
        open gets the journal's committed point count and its last recorded status, or
        "interrupted" when the journal ends without one (the process was killed). Rows of
        live runs and of ended runs come back unchanged.
        """
        if row.status not in LIVE_STATUSES or _held_open(Path(row.path)):
            return row
        records, _ = read_journal(Path(row.path + ".journal"))
        if not records or records[0].get("t") != "header":
            return row  # not ours to judge: the file is gone or is not a run
        done = {r["index"] for r in records if r.get("t") == "point"}
        ends = [r["status"] for r in records if r.get("t") == "status"]
        status = ends[-1] if ends and ends[-1] not in ("created", "running") else "interrupted"
        new = replace(row, status=status, n_points=len(done))
        if new != row:
            self.update(row.run_id, status=new.status, n_points=new.n_points)
        return new

    def refresh_live(self) -> None:
        """:meth:`refresh` every row in a live status (before listing or filtering)."""
        marks = ",".join("?" * len(LIVE_STATUSES))
        rows = self._db.execute(f"SELECT * FROM runs WHERE status IN ({marks})",
                                LIVE_STATUSES).fetchall()
        for r in rows:
            self.refresh(RunRow(*r))

    def find(self, *, status: str | None = None, sample: str | None = None,
             kind: str | None = None, since: float | None = None,
             limit: int | None = None) -> list[RunRow]:
        """Runs matching every filter given (``sample`` is a substring), newest first."""
        where: list[str] = []
        args: list[object] = []
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


def _held_open(path: Path) -> bool:
    """True while a process has the HDF5 run file open for writing.

    This process (a GUI listing runs while its engine writes one) is asked through
    h5py's open file ids, since HDF5 lets a process reopen its own file; another process
    is detected by HDF5's file lock refusing the open.
    """
    if held_by_this_process(path):
        return True
    try:
        with h5py.File(path, "r"):
            return False
    except FileNotFoundError:
        return False
    except OSError as err:
        return is_lock_refusal(str(err))

