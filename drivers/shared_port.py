"""One serial port shared by several devices on one bus (a daisy chain, an addressed bus).

Devices opened with the same port string (or the same ``serial.SerialBase`` object) share
one :class:`SharedPort`: one :class:`~drivers.transport.SerialChannel`, one lock (one
exchange at a time on the wire) and a user count; the port closes with its last user
(ADR 0007 for Zaber chains, ADR 0100 for Elliptec buses). A driver keeps its own
:class:`PortRegistry`, so two protocols never share a port by accident, and may subclass
:class:`SharedPort` for per-bus state (message ids, mailboxes of other addresses).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Generic, TypeVar

import serial

from drivers.errors import StateError
from drivers.transport import SerialChannel, open_serial

__all__ = ["PortRegistry", "SharedPort", "port_channel", "port_lock"]


class SharedPort:
    """One open port and what its users share."""

    def __init__(self, key: str, channel: SerialChannel, owned: bool) -> None:
        self.key = key
        self.channel = channel
        self.owned = owned  # opened here from a path or URL (else the caller's port object)
        # One exchange at a time on the wire: a stop() from another thread, or another
        # device of the bus, must not read the reply a poll is waiting for.
        self.lock = threading.RLock()
        self.users = 0


def port_channel(link: SharedPort | None, device: str, command: str) -> SerialChannel:
    """The channel of a device's shared port; :class:`StateError` once it is closed."""
    if link is None:
        raise StateError("device is closed", device=device, command=command)
    return link.channel


def port_lock(link: SharedPort | None, device: str) -> threading.RLock:
    """The lock of a device's shared port; :class:`StateError` once it is closed."""
    if link is None:
        raise StateError("device is closed", device=device)
    return link.lock


P = TypeVar("P", bound=SharedPort)


class PortRegistry(Generic[P]):
    """The ports a driver has open, by port string; ``factory`` builds a new entry."""

    def __init__(self, factory: Callable[[str, SerialChannel, bool], P]) -> None:
        self._factory = factory
        self._ports: dict[str, P] = {}
        self._lock = threading.Lock()

    def acquire(self, port: str | serial.SerialBase, name: str, *,
                baudrate: int) -> tuple[P, bool]:
        """The shared port for ``port`` (opened if new); True if it was opened just now.

        Raises
        ------
        ConnectionFailed
            The port cannot be opened (from :func:`~drivers.transport.open_serial`).
        """
        is_object = isinstance(port, serial.SerialBase)
        key = f"object:{id(port)}" if is_object else str(port)
        with self._lock:
            link = self._ports.get(key)
            if link is not None:
                link.users += 1
                return link, False
            raw = open_serial(port, device=name, baudrate=baudrate)
            try:
                channel = SerialChannel(raw, device=name)
            except BaseException:
                if not is_object:
                    raw.close()
                raise
            link = self._factory(key, channel, not is_object)
            link.users = 1
            self._ports[key] = link
            return link, True

    def release(self, link: P, *, close_port: bool = True) -> None:
        """Drop one user; the last one closes the port (unless ``close_port`` is False)."""
        with self._lock:
            link.users -= 1
            if link.users > 0:
                return
            if self._ports.get(link.key) is link:
                del self._ports[link.key]
        if close_port:
            link.channel.close()
