"""One conversation at a time with a Thorlabs keyword-protocol unit (SC10, FW102C).

:class:`PromptLink` sends a request and reads through the ``"> "`` prompt that closes its
answer (see :mod:`drivers.thorlabs_ascii_protocol`), with a deadline on every read:

- Stale input is discarded before every request; answers to other requests (a late
  answer after a timeout) and line noise are skipped while waiting for ours.
- Queries (``keyword?``) are idempotent and retried ``retries`` times after a timeout or a
  garbled answer. Commands (``keyword`` or ``keyword=value``) are sent once: ``ens`` on an
  SC10 *toggles*, and a repeated ``pos=`` would restart a move, so their outcome is
  learnt from a query afterwards.
- A ``Command error`` answer becomes :class:`CommandRejected` (a
  :class:`~drivers.errors.ControllerError` whose ``code`` is the unit's error code).
- :meth:`PromptLink.resync` ends a half-typed line on the unit's side with a bare CR and
  drops whatever comes back, so a connection starts on a clean line;
  :meth:`PromptLink.identify` does that and checks that the unit is the model expected.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable
from typing import TypeVar

import serial

from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceTimeout,
    ProtocolError,
    StateError,
)
from drivers.thorlabs_ascii_protocol import (
    PROMPT,
    TERMINATOR,
    Reply,
    format_request,
    looks_like_reply,
    split_reply,
)
from drivers.transport import SerialChannel, open_serial

__all__ = ["CommandRejected", "PromptLink"]

T = TypeVar("T")

#: Longest answer we accept before declaring the stream garbage (the longest real one,
#: the ``?`` command list, is a few hundred bytes; we never ask for it).
_MAX_ANSWER = 512


class CommandRejected(ControllerError):
    """The unit answered ``Command error <code>``; ``code`` is that code."""


class PromptLink:
    """Request/answer exchanges with typed errors over an open port.

    Parameters
    ----------
    port
        An open pyserial port.
    device
        Name used in every error.
    reply_timeout
        Seconds to wait for one complete answer (through the prompt).
    retries
        Extra attempts for a query after a timeout or a garbled answer.
    owns_port
        Whether the link opened ``port`` itself (see :meth:`abandon`).
    """

    def __init__(self, port: serial.SerialBase, *, device: str, reply_timeout: float,
                 retries: int, owns_port: bool = False) -> None:
        if not reply_timeout > 0:
            raise ValueError("reply_timeout must be > 0")
        if int(retries) != retries or retries < 0:
            raise ValueError(f"retries must be a non-negative integer, got {retries}")
        self.device = device
        self.reply_timeout = float(reply_timeout)
        self.retries = int(retries)
        self._owns_port = bool(owns_port)
        self._channel: SerialChannel | None = SerialChannel(port, device=device)
        # One exchange at a time: a turn_off() from another thread must not read the
        # answer a poll is waiting for.
        self._lock = threading.RLock()
        #: Answers skipped while waiting for ours (stale, foreign or noise), for diagnosis.
        self.skipped = 0

    @classmethod
    def open(cls, port: str | serial.SerialBase, *, device: str, baudrate: int,
             reply_timeout: float, retries: int) -> PromptLink:
        """Open ``port`` (a path or URL; an open ``SerialBase`` is adopted) as a link.

        Raises
        ------
        ConnectionFailed
            The port cannot be opened.
        """
        raw = open_serial(port, device=device, baudrate=baudrate)
        owns = not isinstance(port, serial.SerialBase)
        try:
            return cls(raw, device=device, reply_timeout=reply_timeout, retries=retries,
                       owns_port=owns)
        except BaseException:
            if owns:
                raw.close()
            raise

    def abandon(self) -> None:
        """Give up after a failed connection: close the port only if the link opened it
        (a port handed in stays the caller's)."""
        if self._channel is not None and self._owns_port:
            self._channel.close()
        self._channel = None

    def identify(self, keyword: str, model: str, pattern: str, *, baudrate: int) -> str:
        """Start on a clean line, ask ``keyword?`` and check the answer names ``model``
        (``pattern``, a regular expression, searched case-insensitively); return the answer.

        Raises
        ------
        ConnectionFailed
            Nothing answers, or the unit is another model.
        """
        self.resync()
        command = f"{keyword}?"
        try:
            answer: str = self.query(keyword)
        except (DeviceTimeout, ProtocolError, CommandRejected) as err:
            raise ConnectionFailed(
                f"no {model} answers", device=self.device, command=command,
                hint=f"check the cable, the baud rate ({baudrate} unless changed) and the "
                "power",
            ) from err
        if not re.search(pattern, answer, re.IGNORECASE):
            raise ConnectionFailed(f"the unit is not an {model} (it says {answer!r})",
                                   device=self.device, command=command,
                                   hint="check the port name in the bench profile")
        return answer

    # public -------------------------------------------------------------------
    def query(self, keyword: str,
              parse: Callable[[str], T] = str,  # type: ignore[assignment]  # T is str when parse is left out; mypy cannot tie a default to a type variable
              *,
              attempts: int | None = None, timeout: float | None = None) -> T:
        """Ask ``keyword?`` and return ``parse(answer line)``; retried (it changes nothing).

        ``parse`` raises :class:`~drivers.errors.ProtocolError` on a value it cannot read;
        that counts as a garbled answer and is retried too.
        """
        request = format_request(keyword, query=True)
        attempts = self.retries + 1 if attempts is None else attempts
        last: DeviceTimeout | ProtocolError | None = None
        for _ in range(attempts):
            try:
                reply = self._exchange(request, timeout)
                return parse(self._value(reply, request))
            except (DeviceTimeout, ProtocolError) as err:
                last = err
        assert last is not None
        suffix = f" (after {attempts} attempts)" if attempts > 1 else ""
        raise type(last)(last.message + suffix, device=self.device, command=_text(request),
                         hint=last.hint or "check the cable, the baud rate and the power",
                         ) from last

    def command(self, keyword: str, value: int | None = None, *,
                timeout: float | None = None) -> None:
        """Send ``keyword`` or ``keyword=value`` once and wait for its prompt."""
        request = format_request(keyword, value)
        reply = self._exchange(request, timeout)
        if reply.lines:
            raise ProtocolError(f"unexpected answer {list(reply.lines)!r}", device=self.device,
                                command=_text(request))

    def resync(self, timeout: float | None = None) -> bytes:
        """End any half-typed line on the unit's side; return what it answered (or b"")."""
        with self._lock:
            channel = self._chan("resync")
            channel.discard_input()
            channel.write(TERMINATOR, command="resync")
            try:
                return channel.read_line(PROMPT, timeout=timeout or self.reply_timeout,
                                         command="resync", max_bytes=_MAX_ANSWER)
            except (DeviceTimeout, ProtocolError):
                return b""
            finally:
                channel.discard_input()

    def close(self) -> None:
        if self._channel is not None:
            self._channel.close()
            self._channel = None

    # wire ---------------------------------------------------------------------
    def _chan(self, command: str) -> SerialChannel:
        if self._channel is None:
            raise StateError("device is closed", device=self.device, command=command)
        return self._channel

    def _exchange(self, request: bytes, timeout: float | None) -> Reply:
        text = _text(request)
        timeout = self.reply_timeout if timeout is None else timeout
        with self._lock:
            channel = self._chan(text)
            channel.discard_input()
            channel.write(request, command=text)
            deadline = time.monotonic() + timeout
            noise: list[bytes] = []
            while True:
                try:
                    chunk = channel.read_line(
                        PROMPT, timeout=max(deadline - time.monotonic(), 0.0), command=text,
                        max_bytes=_MAX_ANSWER)
                except DeviceTimeout as err:
                    if noise:  # silence after noise: name the noise as the cause
                        raise ProtocolError(f"no valid answer; received noise {noise[:3]!r}",
                                            device=self.device, command=text) from err
                    raise DeviceTimeout(err.message, device=self.device, command=text,
                                        hint=err.hint) from err
                except ProtocolError as err:
                    raise ProtocolError(err.message, device=self.device, command=text) from err
                try:
                    reply = split_reply(chunk, request)
                except ProtocolError as err:
                    raise ProtocolError(err.message, device=self.device, command=text) from err
                if reply is None:
                    self.skipped += 1
                    if not looks_like_reply(chunk):
                        noise.append(chunk)
                    continue
                error = reply.error
                if error is not None:
                    raise CommandRejected(
                        f"the unit refused the request: {error.meaning} ({error.code})",
                        code=error.code, device=self.device, command=text,
                        hint="check the keyword and the argument's range in the manual",
                    )
                return reply

    def _value(self, reply: Reply, request: bytes) -> str:
        try:
            return reply.value
        except ProtocolError as err:
            raise ProtocolError(err.message, device=self.device, command=_text(request)) from err


def _text(request: bytes) -> str:
    return request.decode("ascii").strip()
