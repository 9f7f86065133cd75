"""The GUI's connection to a bench server, off the GUI thread.

Two worker threads, so that neither the network nor the server's pace ever blocks Qt's
event loop (docs/decisions/0084):

* the **event reader** holds the WebSocket event stream (:meth:`BenchClient.open_events`),
  decodes each message and puts it in an inbox; when the inbox goes from empty to not
  empty it emits one queued signal, and the GUI thread then applies everything waiting
  in one go (:meth:`ServerLink.drain`) — superseded display messages (device states,
  frames, progress) are skipped, points and lifecycle messages never. After ``hello`` it
  reads the current run's points so far (``GET /runs/current/points``), so a GUI opened
  mid-run draws the plot from the first point; a resumed run's points from before its
  resumption come as ``backfill`` messages and are drawn as points are. A stream that
  ends (the server restarted) is opened again after a second.
* the **command worker** carries out the operator's requests (queue, run control, manual
  moves, control lease) one at a time, Stop all ahead of anything waiting, and reports
  each result as a signal.
"""

from __future__ import annotations

import collections
import itertools
import queue
import threading
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QObject, Signal

from gui.model.remote import RemoteState, point_event
from instrument.client import BenchClient, ClientError
from instrument.protocol import Message

__all__ = ["ServerLink"]

#: Display messages of which only the newest matters (older ones are skipped on a drain).
SUPERSEDED = frozenset({"devices", "frame", "progress"})
#: Seconds between attempts to open the event stream again.
RECONNECT_S = 1.0


class ServerLink(QObject):
    """The state of the server at ``url`` (:attr:`state`, GUI thread) and its commands."""

    changed = Signal(object)        # set[str]: the parts of the state that changed
    result = Signal(str, bool, str, object)  # what, ok, message, reasons
    _kick = Signal()

    def __init__(self, url: str, key: str | None = None,
                 parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.url = url
        self.key = key
        self.state = RemoteState(url)
        self._inbox: collections.deque[tuple[str, Any]] = collections.deque()
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._stream = None
        self.n_drains = 0
        self._kick.connect(self.drain)  # queued: emitted on the reader thread
        self._commands: queue.PriorityQueue = queue.PriorityQueue()
        self._seq = itertools.count()
        self._reader = threading.Thread(target=self._read_events, name="server-events",
                                        daemon=True)
        self._worker = threading.Thread(target=self._run_commands, name="server-commands",
                                        daemon=True)
        self._reader.start()
        self._worker.start()

    # commands (any thread) --------------------------------------------------------------
    def call(self, what: str, fn: Callable[[BenchClient], str | dict | None], *,
             urgent: bool = False) -> None:
        """Queue ``fn(client)``; its result (or refusal) comes back as :attr:`result`."""
        self._commands.put((0 if urgent else 1, next(self._seq), what, fn))

    def close(self, timeout_s: float = 10.0) -> None:
        """End both threads (the server and its run are not touched)."""
        self._closing.set()
        stream = self._stream
        if stream is not None:
            stream.close()
        self._commands.put((2, next(self._seq), "", None))
        self._reader.join(timeout_s)
        self._worker.join(timeout_s)

    def _run_commands(self) -> None:
        with BenchClient(self.url, self.key) as client:
            while True:
                _, _, what, fn = self._commands.get()
                if fn is None:
                    return
                try:
                    out = fn(client)
                except ClientError as err:
                    self.result.emit(what, False, err.message, err.reasons)
                    continue
                message = out.get("message", "") if isinstance(out, dict) else str(out or "")
                self.result.emit(what, True, message, [])

    # events (reader thread) -------------------------------------------------------------
    def _put(self, kind: str, payload: Any) -> None:
        with self._lock:
            was_empty = not self._inbox
            self._inbox.append((kind, payload))
        if was_empty:
            self._kick.emit()

    def _read_events(self) -> None:
        with BenchClient(self.url, self.key) as client:
            while not self._closing.is_set():
                try:
                    self._stream = client.open_events(open_timeout_s=10.0)
                except ClientError as err:
                    self._put("down", err.message)
                    if err.status in (401, 403):
                        return  # a key the server refuses: trying again changes nothing
                    self._closing.wait(RECONNECT_S)
                    continue
                try:
                    self._follow(client, self._stream)
                except (EOFError, ClientError) as err:
                    if not self._closing.is_set():
                        self._put("down", f"the event stream ended: {err}")
                finally:
                    self._stream.close()
                self._closing.wait(RECONNECT_S)

    def _follow(self, client: BenchClient, stream) -> None:
        while not self._closing.is_set():
            msg = stream.recv(timeout_s=0.5)
            if msg is None:
                continue
            if msg.type in ("points", "backfill"):  # parsed here, off the GUI thread
                self._put("points", _parsed(msg.data.get("items") or []))
                continue
            self._put("message", msg)
            if msg.type == "hello":
                run, items = client.all_run_points()
                self._put("prefill", (run, _parsed(items)))

    # GUI thread ---------------------------------------------------------------------------
    def drain(self) -> set[str]:
        """Apply everything the reader has queued; emit :attr:`changed` once."""
        with self._lock:
            batch = list(self._inbox)
            self._inbox.clear()
        if not batch:
            return set()
        self.n_drains += 1
        newest = {p.type: k for k, (kind, p) in enumerate(batch)
                  if kind == "message" and p.type in SUPERSEDED}
        parts: set[str] = set()
        for k, (kind, payload) in enumerate(batch):
            if kind == "message":
                msg: Message = payload
                if msg.type in SUPERSEDED and newest[msg.type] != k:
                    continue
                parts.add(self.state.apply(msg))
            elif kind == "points":
                if self.state.add_points(payload):
                    parts.add("points")
            elif kind == "prefill":
                if self.state.prefill(*payload):
                    parts.add("points")
            else:  # "down"
                self.state.stream_up = False
                self.state.log.append(f"disconnected: {payload}")
                parts.update({"bench", "log"})
        self.changed.emit(parts)
        return parts


def _parsed(items: list[dict[str, Any]]) -> list[tuple[int, Any]]:
    """``points`` items as (index, :class:`PointCompleted`), parsed on the reader thread."""
    return [(int(i["index"]), point_event(i)) for i in items]
