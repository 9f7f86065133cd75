"""Serial transports, injected into drivers.

A driver never constructs ``serial.Serial`` itself. It receives either an already open
port object (any ``serial.SerialBase``: a real port, a pseudo-terminal, an emulator link,
a byte transcript) or a *URL* that :func:`open_serial` hands to
``serial.serial_for_url``. So ``/dev/ttyUSB0``, ``/dev/pts/7``, ``simapt://x`` and
``socket://host:port`` all take the same code path.

:class:`SerialChannel` wraps the port with what every protocol needs: writes and reads
that translate pyserial exceptions into :mod:`drivers.errors`, reads with a hard deadline
(no wait without a timeout), and a tolerant RTS toggle (a pseudo-terminal raises on
modem-control ioctls).
"""

from __future__ import annotations

import contextlib
import time

import serial

from drivers.errors import ConnectionFailed, DeviceTimeout, ProtocolError

__all__ = ["SerialChannel", "add_url_handler_package", "open_serial"]


def add_url_handler_package(package: str) -> None:
    """Let ``serial_for_url`` resolve schemes from ``package`` (``protocol_<scheme>``)."""
    if package not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(package)


def open_serial(
    port: str | serial.SerialBase,
    *,
    device: str,
    baudrate: int,
    rtscts: bool = False,
    xonxoff: bool = False,
    timeout: float = 0.5,
    write_timeout: float = 1.0,
) -> serial.SerialBase:
    """Open ``port`` (a device path or pyserial URL) or adopt an already open port.

    Raises
    ------
    ConnectionFailed
        The port could not be opened; the message names the device and the URL.
    """
    if isinstance(port, serial.SerialBase):
        if not port.is_open:
            raise ConnectionFailed("the port handed to the driver is not open", device=device,
                                   command="open")
        return port
    try:
        return serial.serial_for_url(
            port,
            baudrate=baudrate,
            rtscts=rtscts,
            xonxoff=xonxoff,
            timeout=timeout,
            write_timeout=write_timeout,
        )
    except (serial.SerialException, OSError, ValueError) as err:
        raise ConnectionFailed(
            f"cannot open {port!r}: {err}", device=device, command="open",
            hint="check the cable and the port name, and that no other program holds it",
        ) from err


class SerialChannel:
    """Byte I/O on an open port with deadlines and typed errors.

    Parameters
    ----------
    port
        An open pyserial port.
    device
        Name used in every error.
    """

    #: Longest single blocking read; reads loop until their own deadline.
    READ_SLICE_S = 0.05

    def __init__(self, port: serial.SerialBase, *, device: str) -> None:
        self.port = port
        self.device = device
        self.bytes_written = 0
        self.bytes_read = 0
        self._pending = bytearray()  # read past the end of the last line
        # One short port timeout, set once: changing it per read would reconfigure a real
        # port (a tcsetattr call) every time.
        try:
            port.timeout = self.READ_SLICE_S
        except (serial.SerialException, OSError, ValueError) as err:
            raise ConnectionFailed(f"cannot configure the port: {err}", device=device,
                                   command="open") from err

    def write(self, data: bytes, *, command: str) -> None:
        try:
            self.port.write(data)
            self.port.flush()
        except serial.SerialTimeoutException as err:
            raise DeviceTimeout("write timed out", device=self.device, command=command,
                                hint="is the device powered and the flow control right?",
                                ) from err
        except (serial.SerialException, OSError) as err:
            raise ConnectionFailed(f"write failed: {err}", device=self.device, command=command,
                                   hint="the device was disconnected; reconnect it") from err
        self.bytes_written += len(data)

    def read_exact(self, n: int, *, timeout: float, command: str) -> bytes:
        """Read exactly ``n`` bytes or raise :class:`DeviceTimeout` after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        buf = bytearray(self._pending[:n])
        del self._pending[:n]
        while len(buf) < n:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(
                    f"no complete reply within {timeout:g} s "
                    f"(got {len(buf)} of {n} bytes: {bytes(buf)!r})",
                    device=self.device, command=command,
                    hint="check the connection, baud rate and device power",
                )
            buf += self._read(n - len(buf), remaining, command)
        return bytes(buf)

    def read_line(self, terminator: bytes, *, timeout: float, command: str,
                  max_bytes: int = 4096) -> bytes:
        """Read through ``terminator`` (included) or raise after ``timeout`` s.

        Bytes that arrived after the terminator are kept for the next call (a reply and an
        unsolicited line often arrive in one read). :meth:`discard_input` drops them too.

        Raises
        ------
        DeviceTimeout
            No complete line in time; the message shows the partial line.
        ProtocolError
            More than ``max_bytes`` without a terminator (line noise, wrong baud rate).
        """
        deadline = time.monotonic() + timeout
        while True:
            end = self._pending.find(terminator)
            if end >= 0:
                end += len(terminator)
                line = bytes(self._pending[:end])
                del self._pending[:end]
                return line
            if len(self._pending) > max_bytes:
                junk = bytes(self._pending)
                self._pending.clear()
                raise ProtocolError(f"{len(junk)} bytes without {terminator!r}: {junk[:40]!r}...",
                                    device=self.device, command=command)
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(
                    f"no complete reply line within {timeout:g} s "
                    f"(got {bytes(self._pending)!r})",
                    device=self.device, command=command,
                    hint="check the address, cable, baud rate and device power",
                )
            # Block for one byte, then take whatever else has arrived in the same go.
            self._pending += self._read(1, remaining, command)
            self._pending += self._read_waiting(command)

    def read_line_by(self, terminator: bytes, deadline: float, *, command: str,
                     noise: list[str], max_bytes: int = 4096) -> bytes:
        """:meth:`read_line` until the ``time.monotonic()`` ``deadline``; a timeout after
        lines that were noise (``noise``: why each was refused) is a
        :class:`ProtocolError` naming them, since the noise is then the likely cause."""
        try:
            return self.read_line(terminator, timeout=max(deadline - time.monotonic(), 0.0),
                                  command=command, max_bytes=max_bytes)
        except DeviceTimeout as err:
            if noise:
                raise ProtocolError(f"no valid reply; received {'; '.join(noise[:3])}",
                                    device=self.device, command=command) from err
            raise

    def read_lines_available(self, terminator: bytes, *, command: str = "read") -> list[bytes]:
        """Every complete line received by now, without waiting; a partial line stays
        buffered for the next read (a shared bus sorts what arrived before it writes)."""
        self._pending += self._read_waiting(command)
        lines: list[bytes] = []
        while (end := self._pending.find(terminator)) >= 0:
            end += len(terminator)
            lines.append(bytes(self._pending[:end]))
            del self._pending[:end]
        return lines

    def read_available(self, *, command: str = "read") -> bytes:
        """Whatever is buffered now, without waiting."""
        data = bytes(self._pending) + self._read_waiting(command)
        self._pending.clear()
        return data

    def _read_waiting(self, command: str) -> bytes:
        try:
            # every concrete port (Serial, the URL handlers' classes) has it; the stubs'
            # SerialBase does not declare it
            waiting = self.port.in_waiting  # type: ignore[attr-defined]
            data = self.port.read(waiting) if waiting else b""
        except (serial.SerialException, OSError) as err:
            raise ConnectionFailed(f"read failed: {err}", device=self.device,
                                   command=command) from err
        self.bytes_read += len(data)
        return data

    def discard_input(self) -> int:
        """Drop buffered input (stale replies); return how many bytes were dropped."""
        dropped = len(self.read_available(command="discard_input"))
        try:
            self.port.reset_input_buffer()  # type: ignore[attr-defined]  # as in_waiting
        except (serial.SerialException, OSError) as err:
            raise ConnectionFailed(f"flush failed: {err}", device=self.device,
                                   command="discard_input") from err
        return dropped

    def set_rts(self, level: bool) -> bool:
        """Set RTS; return False (and carry on) where the port cannot (a pty)."""
        try:
            self.port.rts = level
        except (serial.SerialException, OSError, ValueError):
            return False
        return True

    def close(self) -> None:
        # Closing a vanished port must not mask the error that led here.
        with contextlib.suppress(serial.SerialException, OSError):
            self.port.close()

    def _read(self, n: int, remaining: float, command: str) -> bytes:
        del remaining  # each read blocks at most READ_SLICE_S; callers loop to a deadline
        try:
            chunk = self.port.read(n)
        except (serial.SerialException, OSError) as err:
            raise ConnectionFailed(f"read failed: {err}", device=self.device, command=command,
                                   hint="the device was disconnected; reconnect it") from err
        self.bytes_read += len(chunk)
        return chunk
