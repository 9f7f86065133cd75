"""The plan queue and its history, persisted in ``server.sqlite``.

An item is a plan (its TOML text, validated when added) or a *stop marker* that halts the
queue when it reaches the head. Items are kept in order by a real-valued ``position``
(reordering rewrites one row). States:

``queued``      waits its turn;
``proposed``    added by an observer key or a script; an operator approves (→ queued) or
                denies it (→ history) before it can run; the runner passes it by;
``running``     its run is going on, or paused at a point boundary (``run_file`` names
                the file);
``paused``      its run was stopped at once by *pause now*: resumable in the same file;
``aborted``     its run was aborted: the item stays at the head, and starting the queue
                again resumes the same run file;
``interrupted`` the server died while it ran: resumable in the same way;
``failed``      its run could not start or failed: it stays at the head for a look;
                starting the queue tries it again (continuing its run file, if it has
                one).

Every end of an item is a history row (outcome, run file, who); an item leaves the queue
when its run finishes, when it is removed, or when its proposal is denied.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any

from instrument.server.db import ServerDB

__all__ = ["HistoryRow", "PlanQueue", "QueueError", "QueueItem"]

#: Item states whose run file (when it has one) holds a run that can be continued.
RESUMABLE = ("paused", "aborted", "interrupted", "failed")
#: Item states of the run the server drives now.
ACTIVE = ("running",)


class QueueError(ValueError):
    """A queue request that cannot be carried out (nothing changed); ``status`` is the
    HTTP status that says why (404 unknown item, 409 conflicting state)."""

    def __init__(self, message: str, status: int = 409) -> None:
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class QueueItem:
    id: int
    position: float
    kind: str
    name: str
    plan_text: str | None
    state: str
    added_by: str
    added: float
    run_file: str | None

    def summary(self) -> dict[str, Any]:
        """The item as clients see it (without the plan text)."""
        d = asdict(self)
        d.pop("plan_text")
        d["resumable"] = self.state in RESUMABLE and self.run_file is not None
        return d


@dataclass(frozen=True)
class HistoryRow:
    item_id: int
    name: str
    kind: str
    outcome: str
    run_file: str | None
    who: str
    time: float
    note: str


_COLS = "id, position, kind, name, plan_text, state, added_by, added, run_file"


class PlanQueue:
    def __init__(self, db: ServerDB) -> None:
        self.db = db

    # reading ------------------------------------------------------------------------
    def items(self) -> list[QueueItem]:
        return [QueueItem(*r) for r in self.db.query(
            f"SELECT {_COLS} FROM items ORDER BY position, id")]

    def get(self, item_id: int) -> QueueItem:
        rows = self.db.query(f"SELECT {_COLS} FROM items WHERE id = ?", (item_id,))
        if not rows:
            raise QueueError(f"no queue item {item_id}", 404)
        return QueueItem(*rows[0])

    def head(self) -> QueueItem | None:
        """The first item that may run (proposals are passed by)."""
        for item in self.items():
            if item.state != "proposed":
                return item
        return None

    def history(self, limit: int = 200) -> list[HistoryRow]:
        rows = self.db.query("SELECT * FROM history ORDER BY rowid DESC LIMIT ?", (limit,))
        return [HistoryRow(*r) for r in reversed(rows)]

    # changing -----------------------------------------------------------------------
    def add(self, kind: str, name: str, plan_text: str | None, who: str, *,
            proposed: bool = False) -> QueueItem:
        if kind not in ("plan", "stop"):
            raise ValueError(f"kind must be 'plan' or 'stop', got {kind!r}")
        with self.db.transaction() as db:
            last = db.execute("SELECT MAX(position) FROM items").fetchone()[0]
            pos = 0.0 if last is None else float(last) + 1.0
            cur = db.execute(
                "INSERT INTO items (position, kind, name, plan_text, state, added_by, added) "
                "VALUES (?,?,?,?,?,?,?)",
                (pos, kind, name, plan_text, "proposed" if proposed else "queued", who,
                 time.time()))
            item_id = int(cur.lastrowid)  # type: ignore[arg-type]  # an INSERT sets it
        return self.get(item_id)

    def move(self, item_id: int, index: int) -> QueueItem:
        """Put the item at ``index`` (0: the head) among the items, in order."""
        item = self.get(item_id)
        if item.state in ACTIVE:
            raise QueueError(f"item {item_id} is running: it stays where it is")
        with self.db.transaction() as db:
            others = [r[0] for r in db.execute(
                "SELECT position FROM items WHERE id != ? ORDER BY position, id", (item_id,))]
            index = max(0, min(int(index), len(others)))
            if not others:
                pos = item.position
            elif index == 0:
                pos = others[0] - 1.0
            elif index == len(others):
                pos = others[-1] + 1.0
            else:
                pos = (others[index - 1] + others[index]) / 2.0
            db.execute("UPDATE items SET position = ? WHERE id = ?", (pos, item_id))
        return self.get(item_id)

    def remove(self, item_id: int, who: str) -> QueueItem:
        item = self.get(item_id)
        if item.state in ACTIVE:
            raise QueueError(f"item {item_id} is running: abort its run first")
        self._end(item, "removed", who, note="removed from the queue")
        return item

    def approve(self, item_id: int) -> QueueItem:
        item = self.get(item_id)
        if item.state != "proposed":
            raise QueueError(f"item {item_id} is not a proposal (it is {item.state})")
        self.set_state(item_id, "queued")
        return self.get(item_id)

    def deny(self, item_id: int, who: str) -> QueueItem:
        item = self.get(item_id)
        if item.state != "proposed":
            raise QueueError(f"item {item_id} is not a proposal (it is {item.state})")
        self._end(item, "denied", who, note="proposal denied")
        return item

    def set_state(self, item_id: int, state: str, run_file: str | None = None) -> None:
        with self.db.transaction() as db:
            if run_file is None:
                db.execute("UPDATE items SET state = ? WHERE id = ?", (state, item_id))
            else:
                db.execute("UPDATE items SET state = ?, run_file = ? WHERE id = ?",
                           (state, run_file, item_id))

    def finish(self, item: QueueItem, outcome: str, who: str, *, note: str = "",
               run_file: str | None = None) -> None:
        """The item is done (its run finished, or the stop marker was reached)."""
        self._end(item, outcome, who, note=note, run_file=run_file)

    def record(self, item: QueueItem, outcome: str, who: str, *, note: str = "",
               run_file: str | None = None, state: str | None = None) -> None:
        """A history row for an item that stays in the queue (aborted, failed, paused),
        and its new state, in one transaction."""
        with self.db.transaction() as db:
            db.execute("INSERT INTO history VALUES (?,?,?,?,?,?,?,?)",
                       (item.id, item.name, item.kind, outcome, run_file or item.run_file,
                        who, time.time(), note))
            if state is not None:
                db.execute("UPDATE items SET state = ?, run_file = COALESCE(?, run_file) "
                           "WHERE id = ?", (state, run_file, item.id))

    def _end(self, item: QueueItem, outcome: str, who: str, *, note: str = "",
             run_file: str | None = None) -> None:
        with self.db.transaction() as db:
            db.execute("INSERT INTO history VALUES (?,?,?,?,?,?,?,?)",
                       (item.id, item.name, item.kind, outcome, run_file or item.run_file,
                        who, time.time(), note))
            db.execute("DELETE FROM items WHERE id = ?", (item.id,))

    def after_restart(self) -> list[QueueItem]:
        """Mark the items whose run the last server left behind as ``interrupted``
        (resumable); return them."""
        hit = [i for i in self.items() if i.state in ACTIVE]
        for item in hit:
            self.record(item, "interrupted", "server",
                        note="the server stopped while this run was going on; start the "
                        "queue to resume it", state="interrupted")
        return hit
