"""The server's SQLite file, ``server.sqlite`` beside the run catalog.

It holds what must outlive the server process: the plan queue and its history
(:mod:`instrument.server.queue`), the API keys (:mod:`instrument.server.keys`) and the
audit log (:mod:`instrument.server.audit`). Every write is one short transaction in WAL
mode, so a ``kill -9`` of the server leaves the last committed state, and the CLI can read
keys and the audit log while the server runs.
"""

from __future__ import annotations

import os
import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["SERVER_DB_NAME", "ServerDB"]

SERVER_DB_NAME = "server.sqlite"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS items (
    id        INTEGER PRIMARY KEY AUTOINCREMENT,
    position  REAL NOT NULL,
    kind      TEXT NOT NULL,          -- 'plan' | 'stop'
    name      TEXT NOT NULL,
    plan_text TEXT,
    state     TEXT NOT NULL,          -- queued | proposed | running | paused | aborted
                                      -- | interrupted | failed
    added_by  TEXT NOT NULL,
    added     REAL NOT NULL,
    run_file  TEXT
);
CREATE TABLE IF NOT EXISTS history (
    item_id   INTEGER NOT NULL,
    name      TEXT NOT NULL,
    kind      TEXT NOT NULL,
    outcome   TEXT NOT NULL,
    run_file  TEXT,
    who       TEXT NOT NULL,
    time      REAL NOT NULL,
    note      TEXT NOT NULL DEFAULT ''
);
CREATE TABLE IF NOT EXISTS keys (
    id        INTEGER PRIMARY KEY AUTOINCREMENT,
    name      TEXT NOT NULL,
    role      TEXT NOT NULL,
    digest    TEXT NOT NULL UNIQUE,
    created   REAL NOT NULL,
    expires   REAL,
    revoked   REAL
);
CREATE TABLE IF NOT EXISTS audit (
    time      REAL NOT NULL,
    who       TEXT NOT NULL,
    role      TEXT NOT NULL,
    what      TEXT NOT NULL,
    status    INTEGER NOT NULL,
    result    TEXT NOT NULL
);
"""


class ServerDB:
    """Open (creating if needed) ``folder/server.sqlite``; usable from any thread."""

    def __init__(self, folder: str | Path) -> None:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self.path = folder / SERVER_DB_NAME
        new = not self.path.exists()
        self._db = sqlite3.connect(self.path, timeout=10.0, check_same_thread=False,
                                   isolation_level=None)
        if new:
            os.chmod(self.path, 0o600)  # key digests: readable by the owner only
        self._lock = threading.RLock()
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.executescript(_SCHEMA)

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """One atomic write (``BEGIN IMMEDIATE`` … ``COMMIT``, rolled back on error)."""
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")

    def query(self, sql: str, args: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
        with self._lock:
            return self._db.execute(sql, args).fetchall()

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def __enter__(self) -> ServerDB:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
