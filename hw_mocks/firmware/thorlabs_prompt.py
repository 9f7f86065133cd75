"""The device side of the Thorlabs keyword terminal shared by the SC10 and the FW102C.

Written from the manuals' keyword tables (SC10 8654-D02; FW102C rev H §5.2.3) and from what
open-source drivers record of the real units, independently of ``drivers/``:

- the unit collects characters up to a carriage return; LF bytes are ignored;
- it echoes the line it received, CR included, then its answer (if any) ended by a CR,
  then the prompt ``"> "`` (no terminator after the prompt);
- a line it cannot take is answered, after the echo, by ``Command error CMD_NOT_DEFINED``
  (unknown keyword, bad format, upper case, an empty line) or ``Command error
  CMD_ARG_INVALID`` (argument out of range), each followed by LF CR as Odemis records it;
- a line longer than :attr:`PromptFirmware.max_line` characters overflows the input buffer
  and is answered as undefined;
- ``?`` answers the list of keywords (both manuals' tables start with it). With it, every
  keyword of the SC10's and the FW102C's tables is implemented; anything else is answered
  ``CMD_NOT_DEFINED``, as the units answer an unknown keyword.

A subclass declares its keywords in :meth:`PromptFirmware._handlers` and may hold the
prompt back (a filter-wheel move answers only when the wheel has arrived): while
:meth:`PromptFirmware.busy` is true, input stays queued, unread, as in the unit's UART
buffer, and is processed once the unit is free again (in :meth:`poll`).

Backdoor for tests: :meth:`power_off`/:meth:`power_on` (a unit that answers nothing),
:attr:`lines` (every line the unit processed).
"""

from __future__ import annotations

from collections.abc import Callable

from hw_mocks.clock import Clock
from hw_mocks.emulator import FirmwareEmulator

__all__ = ["CmdError", "PromptFirmware"]

PROMPT = b"> "
CR = b"\r"


class CmdError(Exception):
    """Raised by a handler to answer ``Command error <code>``."""

    def __init__(self, code: str = "CMD_NOT_DEFINED") -> None:
        super().__init__(code)
        self.code = code


#: A handler gets the argument text (``None`` for a bare keyword or a query) and returns the
#: answer line (``None``: no answer line).
Handler = Callable[[str | None], str | None]


class PromptFirmware(FirmwareEmulator):
    """Line assembly, echo, prompt and error answers; subclasses supply the keywords."""

    #: Longest line the unit buffers (characters before the CR).
    max_line = 64

    def __init__(self, name: str, *, clock: Clock | None = None, seed: int = 0) -> None:
        super().__init__(name, clock=clock, seed=seed)
        self.powered = True
        #: Every complete line processed, decoded (for tests).
        self.lines: list[str] = []

    # backdoor -----------------------------------------------------------------
    def power_off(self) -> None:
        """Cut the power: the unit hears and answers nothing until :meth:`power_on`."""
        with self.lock:
            self.powered = False
            self._rx.clear()

    def power_on(self) -> None:
        """Power up again with the stored settings."""
        with self.lock:
            self.powered = True
            self._rx.clear()
            self._power_up()

    def _power_up(self) -> None:
        """Restore power-up state; subclasses override."""

    # the prompt ---------------------------------------------------------------
    def busy(self) -> bool:
        """Whether the unit is still executing a command (input waits, unread)."""
        return False

    def _handle_input(self, buf: bytearray) -> list[bytes]:
        if not self.powered:
            buf.clear()
            return []
        return self._drain(buf)

    def poll(self) -> list[bytes]:
        with self.lock:
            if not self.powered:
                return []
            frames = self._finished()
            if self._rx and not self.busy():
                frames += self._drain(self._rx)
            return frames

    def _finished(self) -> list[bytes]:
        """Frames due because a running command finished (default: none)."""
        return []

    def _drain(self, buf: bytearray) -> list[bytes]:
        frames: list[bytes] = []
        while not self.busy():
            end = buf.find(CR)
            if end < 0:
                if len(buf) > 4 * self.max_line:  # noise with no CR: the UART drops it
                    buf.clear()
                return frames
            raw = bytes(buf[:end]).replace(b"\n", b"")
            del buf[: end + 1]
            frames.append(raw + CR)  # the echo
            body = self._answer(raw)
            if body is not None:  # None: the prompt comes later (see busy())
                frames.append(body + PROMPT)
        return frames

    def _answer(self, raw: bytes) -> bytes | None:
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            return self._error("CMD_NOT_DEFINED")
        self.lines.append(text)
        if len(text) > self.max_line:
            return self._error("CMD_NOT_DEFINED")
        if text.endswith("?"):
            keyword, arg = text[:-1] + "?", None
        elif "=" in text:
            keyword, _, arg = text.partition("=")
        else:
            keyword, arg = text, None
        handlers = self._handlers()
        handlers.setdefault("?", lambda arg: self._command_list(handlers))
        handler = handlers.get(keyword)
        if handler is None or (arg is not None and not arg):
            return self._error("CMD_NOT_DEFINED")
        try:
            value = handler(arg)
        except CmdError as err:
            return self._error(err.code)
        if self.busy():
            return None
        return b"" if value is None else value.encode("ascii") + CR

    @staticmethod
    def _error(code: str) -> bytes:
        return f"Command error {code}".encode("ascii") + b"\n" + CR

    @staticmethod
    def _command_list(handlers: dict[str, Handler]) -> str:
        """``?``: the keywords the unit takes, setters written ``name=n``, on one line
        (the manuals list ``?`` as "returns a list of available commands"; the layout of
        that list is not documented and is this emulator's choice)."""
        return " ".join(k if k.endswith("?") or k in ("ens", "save", "savp", "resp")
                        else f"{k}=n" for k in handlers if k != "?")

    def _handlers(self) -> dict[str, Handler]:
        """Keyword (``"pos?"``, ``"pos"`` for ``pos=n``, ``"ens"``) → handler."""
        raise NotImplementedError

    # helpers for subclasses -----------------------------------------------------
    @staticmethod
    def _int_arg(arg: str | None, low: int, high: int) -> int:
        """A decimal argument in ``[low, high]`` (``CMD_ARG_INVALID`` otherwise)."""
        if arg is None:
            raise CmdError("CMD_NOT_DEFINED")
        if not arg.isdigit() or len(arg) > 9:
            raise CmdError("CMD_ARG_INVALID")
        value = int(arg)
        if not low <= value <= high:
            raise CmdError("CMD_ARG_INVALID")
        return value

    @staticmethod
    def _no_arg(arg: str | None) -> None:
        if arg is not None:
            raise CmdError("CMD_NOT_DEFINED")
