"""The current run's points so far, for a client that connects in the middle of a run.

A GUI opened (or reopened) while a run goes on must draw the run's plot from its first
point, not from the moment it connected. :class:`RunPoints` listens to the event hub (on
its dispatcher thread, :meth:`~instrument.server.hub.EventHub.listen`) and keeps every
``points`` item of the current run, in the order they were published; ``GET
/api/v1/runs/current/points?since=N`` pages through them.

A client connects to the event stream first and then reads the points: everything
published before it attached is already here (the hub calls its listeners before it
hands a message to the clients), and what comes later reaches it on the stream. The two
may overlap by a batch, so a client keeps points by their index.

A resumed run (after a restart of the server, a pause now or an abort) starts with the
points already in its file: the service sends them as ``backfill`` messages right after
its ``run_started`` (:func:`stored_points` reads them), and they are kept here as points
are, so a client that connects later reads them too.

Memory: one small dict per point of the current run (a 10,000-point scan: a few MB); the
list is emptied when the next run starts.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any

from instrument.protocol import Message
from instrument.run.layout import STATUS_OK
from instrument.run.runfile import read_run

__all__ = ["MAX_POINTS_PAGE", "RunPoints", "stored_points"]

#: The most points one answer carries (the client asks again from ``next``).
MAX_POINTS_PAGE = 5000


class RunPoints:
    """Every point of the current (or last) run, published so far."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._run: dict[str, Any] | None = None
        self._items: list[dict[str, Any]] = []

    def on_message(self, message: Message) -> None:
        """Hub listener: a ``run_started`` begins a new list, ``points`` extend it."""
        if message.type == "run_started":
            with self._lock:
                self._run = {k: message.data.get(k) for k in
                             ("run_id", "path", "plan_kind", "n_total", "item_id")}
                self._items = []
        elif message.type in ("points", "backfill"):
            items = message.data.get("items") or []
            with self._lock:
                self._items.extend(items)

    def page(self, since: int = 0, limit: int = MAX_POINTS_PAGE) -> dict[str, Any]:
        """Points ``since`` … ``since + limit`` (ordinals in publication order) and where
        the next page starts; ``run`` is None when no run has started since the server
        did."""
        since = max(0, int(since))
        limit = max(1, min(int(limit), MAX_POINTS_PAGE))
        with self._lock:
            items = self._items[since:since + limit]
            total = len(self._items)
            run = dict(self._run) if self._run is not None else None
        return {"run": run, "since": since, "next": since + len(items), "total": total,
                "items": items}


def _number(value: Any) -> float | None:
    v = float(value)
    return v if math.isfinite(v) else None  # JSON has no NaN: not measured is null


def stored_points(path: str | Path) -> list[dict[str, Any]]:
    """The points stored in the run file ``path``, in the order they were stored, as the
    items of a ``points`` message (index, label, status, positions, angles, exposure_us,
    power_w, signal, retries, nd_slot); retries are not kept in the file's scalars read
    here and are 0."""
    run = read_run(path)
    nd = run.detectors.get("nd_position")
    items = []
    for row in range(run.n_points):
        angles = [_number(a[row]) for a in (run.theta_i, run.phi_i, run.theta_r, run.phi_r)]
        items.append({
            "index": int(run.index[row]), "label": str(run.label[row]),
            "status": "ok" if int(run.point_status[row]) == STATUS_OK else "skipped",
            "positions": {axis: _number(run.positions[row, k])
                          for k, axis in enumerate(run.axes)},
            "angles": None if angles[0] is None else angles,
            "exposure_us": _number(run.exposure_us[row]), "power_w": _number(run.power_w[row]),
            "signal": _number(run.signal[row]), "retries": 0,
            "nd_slot": -1 if nd is None or not math.isfinite(float(nd[row]))
            else int(nd[row])})
    return items
