"""Serve an emulator on a real pseudo-terminal.

A driver in another process opens the printed path with plain ``serial.Serial(path)``:
the whole OS serial stack (termios, blocking reads, select) is then exercised. Limits of
a pty: modem-control ioctls fail (``setRTS`` raises ``OSError`` errno 25), and baud rate
and parity are not enforced.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import tty

from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.link import OutboundQueue

__all__ = ["PtyServer"]


class PtyServer:
    """Run ``emulator`` behind a pseudo-terminal until :meth:`close`.

    Use as a context manager; :attr:`path` is the slave device (``/dev/pts/N``).
    """

    def __init__(self, emulator: FirmwareEmulator, *, poll_s: float = 0.002) -> None:
        import pty

        self.emulator = emulator
        self._master, self._slave = pty.openpty()
        tty.setraw(self._master)
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self._poll_s = poll_s
        self._queue = OutboundQueue()
        self._stop = threading.Event()
        self._queue.push(emulator.on_connect(), emulator)
        self._thread = threading.Thread(target=self._run, name=f"pty-{emulator.name}",
                                        daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], self._poll_s)
            if ready:
                try:
                    data = os.read(self._master, 4096)
                except OSError:
                    data = b""
                if data and not self.emulator.faults.disconnected:
                    self._queue.host_wrote()
                    self._queue.push(self.emulator.receive(data), self.emulator)
            if self.emulator.faults.disconnected:
                continue  # a dead device neither reads nor answers
            with self.emulator.instant():
                frames = self.emulator.poll()
            self._queue.push(frames, self.emulator)
            out = self._queue.take(1 << 16)
            if out:
                # Nobody has the port open: the bytes are lost, as on a wire.
                with contextlib.suppress(OSError):
                    os.write(self._master, out)

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(2.0)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> PtyServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def serve_url(url: str, *, handlers: str = "hw_mocks.urlhandler") -> PtyServer:
    """Serve the emulator named by a ``simapt://``, ``simsmc://``, ``simzaber://``,
    ``simsr830://``, ``simsc10://``, ``simfw102c://``, ``simell://`` or ``simpem://`` URL
    (any scheme with a handler in the package ``handlers``: :mod:`hw_mocks.urlhandler`, or
    a driver plugin's) on a new pty."""
    import importlib

    from hw_mocks import registry

    scheme, name, options = registry.parse_url(url)
    if options.get("clock") == "host":
        # A host on the far side of a pty cannot pace the emulator's time (its waits do
        # not reach this process): such a device runs on the wall clock here.
        del options["clock"]
    handler = importlib.import_module(f"{handlers}.protocol_{scheme}").Serial
    emulator = registry.get_or_create(scheme, name, handler.factory, options)
    return PtyServer(emulator)
