"""Fan-out of event messages to the clients of the event stream, each with a bounded buffer.

The engine's worker thread drives the hardware, so publishing an event costs it one
``queue.put`` (:meth:`EventHub.publish`); a dispatcher thread numbers the message,
serialises it once and hands the text to every client's :class:`ClientBuffer`.

A client's buffer holds at most ``capacity`` *display* messages (progress, point, device
states, frames: each is superseded by the next of its type): a display message that
finds the buffer full is dropped and counted. *Lifecycle* messages (run started, fault,
paused, finished, queue, …) are always queued. Before the next message the client
receives, it is sent a ``missed`` message with the counts by type and the range of
sequence numbers lost. A client whose backlog of lifecycle messages passes
``lifecycle_limit`` (one that stopped reading altogether) is cut off — told why when it
reads again — and has to reconnect; memory stays bounded and the run is unaffected.
"""

from __future__ import annotations

import collections
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from instrument.protocol import MESSAGE_TYPES, Message, encode

__all__ = ["ClientBuffer", "EventHub"]


class ClientBuffer:
    """What one client has yet to receive. Thread-safe; ``wake`` is called (from the
    dispatcher thread) after each message is added, to wake the client's sender."""

    def __init__(self, capacity: int = 256, lifecycle_limit: int = 10_000,
                 wake: Callable[[], object] | None = None) -> None:
        # ``wake`` is called by the hub's dispatcher (never under this buffer's lock)
        self.capacity = int(capacity)
        self.lifecycle_limit = int(lifecycle_limit)
        self.wake = wake or (lambda: None)
        self._lock = threading.Lock()
        self._items: collections.deque[tuple[bool, str]] = collections.deque()
        self._n_display = 0
        self._missed: collections.Counter[str] = collections.Counter()
        self._missed_seq: list[int] = []
        self.cut_off = False
        self.delivered = 0
        self._woken = False

    def put(self, message: Message, text: str) -> bool:
        """Queue (or drop, or count) one message; True when the client's sender must be
        woken: the first message since its last :meth:`take` (one wake per batch, not
        per message: each wake costs the event loop, and so the engine, some time)."""
        with self._lock:
            if self.cut_off:
                return False
            if not message.lifecycle:
                if self._n_display >= self.capacity:
                    self._missed[message.type] += 1
                    if not self._missed_seq:
                        self._missed_seq = [message.seq, message.seq]
                    self._missed_seq[1] = message.seq
                    return False
                self._n_display += 1
                self._items.append((False, text))
            elif len(self._items) - self._n_display >= self.lifecycle_limit:
                self.cut_off = True  # the sender closes the connection, saying why
                self._items.clear()
                self._n_display = 0
            else:
                self._items.append((True, text))
            wake, self._woken = not self._woken, True
            return wake

    def take(self, now: float | None = None) -> list[str]:
        """Everything waiting, oldest first, a ``missed`` message in front when display
        messages were dropped since the last take."""
        with self._lock:
            out: list[str] = []
            if self._missed:
                out.append(encode(Message(0, "missed", now or time.time(), {
                    "counts": dict(self._missed), "first_seq": self._missed_seq[0],
                    "last_seq": self._missed_seq[1]})))
                self._missed.clear()
                self._missed_seq = []
            out.extend(text for _, text in self._items)
            self._items.clear()
            self._n_display = 0
            self._woken = False
            self.delivered += len(out)
            return out

    def __len__(self) -> int:
        with self._lock:
            return len(self._items)


class EventHub:
    """Numbers, serialises and fans out messages; :meth:`publish` from any thread."""

    def __init__(self) -> None:
        self._in: queue.SimpleQueue[tuple[str, dict[str, Any], float] | None] = \
            queue.SimpleQueue()
        self._clients: list[ClientBuffer] = []
        self._lock = threading.Lock()
        self._seq = 0
        self._listeners: list[Callable[[Message], None]] = []
        self._thread = threading.Thread(target=self._loop, name="event-hub", daemon=True)
        self._thread.start()

    def publish(self, kind: str, data: dict[str, Any]) -> None:
        if kind not in MESSAGE_TYPES:
            raise ValueError(f"unknown message type {kind!r}")
        self._in.put((kind, data, time.time()))

    def attach(self, buffer: ClientBuffer) -> None:
        with self._lock:
            self._clients.append(buffer)

    def detach(self, buffer: ClientBuffer) -> None:
        with self._lock:
            if buffer in self._clients:
                self._clients.remove(buffer)

    def listen(self, fn: Callable[[Message], None]) -> None:
        """Call ``fn(message)`` on the dispatcher thread for every message (in-process
        observers: the server's own bookkeeping, tests)."""
        self._listeners.append(fn)

    @property
    def n_clients(self) -> int:
        with self._lock:
            return len(self._clients)

    def flush(self, timeout: float = 10.0) -> bool:
        """Wait until every message published so far has been handed to the clients."""
        marker = threading.Event()
        self._in.put(("__flush__", {"event": marker}, 0.0))
        return marker.wait(timeout)

    def close(self) -> None:
        self._in.put(None)
        self._thread.join(5.0)

    def _loop(self) -> None:
        while True:
            batch = [self._in.get()]
            while len(batch) < 512:  # what else is waiting goes out with it: one wake each
                try:
                    batch.append(self._in.get_nowait())
                except queue.Empty:
                    break
            with self._lock:
                clients = list(self._clients)
            to_wake: set[int] = set()
            for got in batch:
                if got is None:
                    return
                kind, data, t = got
                if kind == "__flush__":
                    self._wake(clients, to_wake)
                    to_wake.clear()
                    data["event"].set()
                    continue
                self._seq += 1
                message = Message(self._seq, kind, t, data)
                try:
                    text = encode(message)
                except (TypeError, ValueError) as err:  # a converter's bug: say so, go on
                    text = encode(Message(self._seq, kind, t, {"error": str(err)}))
                for fn in list(self._listeners):
                    try:
                        fn(message)
                    except Exception:  # an observer must not stop the stream
                        self._listeners.remove(fn)
                for k, c in enumerate(clients):
                    if c.put(message, text):
                        to_wake.add(k)
            self._wake(clients, to_wake)

    @staticmethod
    def _wake(clients: list[ClientBuffer], which: set[int]) -> None:
        for k in which:
            clients[k].wake()
