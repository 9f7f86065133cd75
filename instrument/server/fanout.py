"""Writing the event stream to every client of an event loop in one pass (ADR 0086).

With 50 clients the per-message path (one asyncio task per client woken per batch, then
Starlette's and uvicorn's ``websocket.send`` for every message: about 100 µs of Python
each) ran in the same interpreter as the engine's worker and cost it half its points per
second. Here a batch of the hub costs one callback on the event loop, whatever the number
of clients: :meth:`LoopFanout.request` (called by the hub's dispatcher thread for each
client it gave messages to) schedules :meth:`LoopFanout.flush` once; the flush takes each
client's waiting messages and writes them as WebSocket frames with one
``transport.write`` per client. A message's frame is built once per flush and the same
bytes go to every client: a server's frames are not masked (RFC 6455 §5.1, §5.2), and the
server does not compress (:data:`instrument.server.main.WS_OPTIONS`).

The frames go straight to the connection's transport, which uvicorn's ``websockets-sansio``
protocol object holds (the ASGI ``send`` callable is its bound method); :class:`RawSink`
finds it and says None for any other server, which then gets the per-message path
(``instrument.server.app``). The handshake, ``hello``, pings and the close stay with
uvicorn and the websockets library; only whole data frames are written here, between
their writes, on the same thread.

A client whose transport holds more than :data:`BACKLOG_BYTES` unsent (a client that
stopped reading) is passed by: its messages wait in its :class:`~instrument.server.hub.
ClientBuffer`, which drops display messages and, past its lifecycle limit, cuts it off
(the connection is closed, saying why), so memory stays bounded and the run goes on.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
import threading
from collections.abc import Callable
from typing import Any, cast

from instrument.server.hub import ClientBuffer

__all__ = ["BACKLOG_BYTES", "LoopFanout", "RawSink", "text_frame"]

#: Bytes a client's connection may hold unsent before the flush passes it by.
BACKLOG_BYTES = 1 << 20
#: Seconds before a flush that passed a client by is tried again.
RETRY_S = 0.1


def text_frame(text: str) -> bytes:
    """One unmasked, unfragmented WebSocket text frame (RFC 6455 §5.2): FIN and opcode 1,
    then the payload length in 7, 7+16 or 7+64 bits, then the UTF-8 payload."""
    payload = text.encode("utf-8")
    n = len(payload)
    if n < 126:
        head = struct.pack("!BB", 0x81, n)
    elif n < 1 << 16:
        head = struct.pack("!BBH", 0x81, 126, n)
    else:
        head = struct.pack("!BBQ", 0x81, 127, n)
    return head + payload


class RawSink:
    """The transport of one WebSocket connection served by uvicorn's ``websockets-sansio``
    protocol, found from the ASGI ``send`` callable it gave the application."""

    def __init__(self, protocol: Any) -> None:
        self._protocol = protocol
        self._transport = protocol.transport

    @classmethod
    def of(cls, send: Any) -> RawSink | None:
        """The sink behind ``send``, or None when it is not a protocol object with a
        transport this module knows how to write to."""
        protocol = getattr(send, "__self__", None)
        transport = getattr(protocol, "transport", None)
        # duck-typed: uvloop's transports are not subclasses of asyncio's
        if protocol is None or not hasattr(protocol, "close_sent") or not all(
                callable(getattr(transport, m, None))
                for m in ("write", "is_closing", "get_write_buffer_size")):
            return None
        return cls(protocol)

    @property
    def open(self) -> bool:
        return not self._protocol.close_sent and not self._transport.is_closing()

    def backlog(self) -> int:
        return cast(int, self._transport.get_write_buffer_size())  # the transport is untyped

    def write(self, data: bytes) -> None:
        self._transport.write(data)


class LoopFanout:
    """The event-stream clients of one event loop, written by one callback per batch."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self._clients: dict[ClientBuffer, tuple[RawSink, Callable[[], None]]] = {}
        self._lock = threading.Lock()
        self._scheduled = False

    def add(self, buf: ClientBuffer, sink: RawSink, on_cut_off: Callable[[], None]) -> None:
        """Serve ``buf`` through ``sink`` (on the loop's thread); ``on_cut_off`` is called
        (once) when the buffer has cut the client off."""
        self._clients[buf] = (sink, on_cut_off)
        self.request()

    def remove(self, buf: ClientBuffer) -> None:
        self._clients.pop(buf, None)

    def __len__(self) -> int:
        return len(self._clients)

    def request(self) -> None:
        """Schedule a flush (any thread); one is enough for any number of requests."""
        with self._lock:
            if self._scheduled:
                return
            self._scheduled = True
        with contextlib.suppress(RuntimeError):  # the loop has closed: the server stops
            self.loop.call_soon_threadsafe(self.flush)

    def flush(self) -> None:
        """Write every client's waiting messages (on the loop's thread)."""
        with self._lock:
            self._scheduled = False  # a request from now on schedules another flush
        frames: dict[str, bytes] = {}  # each message's frame, built once for all clients
        retry = False
        for buf, (sink, on_cut_off) in list(self._clients.items()):
            if buf.cut_off:
                self._clients.pop(buf, None)
                on_cut_off()
                continue
            if not sink.open:
                continue  # going away: its handler detaches it
            if sink.backlog() > BACKLOG_BYTES:
                retry = True  # not reading: its messages wait in its bounded buffer
                continue
            texts = buf.take()
            if texts:
                out = []
                for text in texts:
                    frame = frames.get(text)
                    if frame is None:
                        frame = frames[text] = text_frame(text)
                    out.append(frame)
                sink.write(b"".join(out))
        if retry:
            self.loop.call_later(RETRY_S, self.request)
