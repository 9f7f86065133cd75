"""Byte-exact transcripts: a serial port that expects exact requests and plays replies.

A :class:`TranscriptSerial` is given the conversation as ``(request, reply)`` pairs of
bytes. Every byte the driver writes must continue the expected request stream exactly
(a mismatch raises at once, showing both); when a request is complete its reply becomes
readable. :meth:`TranscriptSerial.assert_complete` checks the end state: every request
sent, every reply byte read, nothing extra written. A pair with an empty request puts its
reply on the wire as soon as the previous request is complete (unsolicited bytes).

Reads do not wait: with no reply pending they return what there is at once, so a driver
that reads too much fails fast instead of timing out slowly.
"""

from __future__ import annotations

from collections.abc import Iterable

from serial.serialutil import PortNotOpenError, SerialBase

__all__ = ["TranscriptMismatch", "TranscriptSerial"]


class TranscriptMismatch(AssertionError):
    """The driver wrote bytes the transcript did not expect."""


class TranscriptSerial(SerialBase):
    def __init__(self, steps: Iterable[tuple[bytes, bytes]], **kwargs) -> None:
        self._steps = [(bytes(req), bytes(rep)) for req, rep in steps]
        self._index = 0
        self._pending = bytearray()  # written bytes of the current request
        self._readable = bytearray()
        self.written = bytearray()
        super().__init__(**kwargs)
        self.is_open = True
        self._release_unsolicited()

    # SerialBase plumbing ------------------------------------------------------
    def open(self) -> None:
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def _reconfigure_port(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass

    def flush(self) -> None:
        pass

    def reset_output_buffer(self) -> None:
        pass

    def reset_input_buffer(self) -> None:
        self._readable.clear()

    @property
    def in_waiting(self) -> int:
        return len(self._readable)

    # I/O ----------------------------------------------------------------------
    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        for byte in bytes(data):
            self.written.append(byte)
            if self._index >= len(self._steps):
                raise TranscriptMismatch(
                    f"extra byte {bytes([byte])!r} written after the transcript ended "
                    f"(all written: {bytes(self.written)!r})"
                )
            expected = self._steps[self._index][0]
            position = len(self._pending)
            if expected[position] != byte:
                raise TranscriptMismatch(
                    f"step {self._index}: expected request {expected!r}, but got "
                    f"{bytes(self._pending) + bytes([byte])!r}..."
                )
            self._pending.append(byte)
            if len(self._pending) == len(expected):
                self._readable += self._steps[self._index][1]
                self._pending.clear()
                self._index += 1
                self._release_unsolicited()
        return len(data)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        out = bytes(self._readable[:size])
        del self._readable[:size]
        return out

    def _release_unsolicited(self) -> None:
        while self._index < len(self._steps) and not self._steps[self._index][0]:
            self._readable += self._steps[self._index][1]
            self._index += 1

    def assert_complete(self) -> None:
        """Every request was sent and every reply byte was read."""
        if self._index < len(self._steps) or self._pending:
            missing = self._steps[self._index][0] if self._index < len(self._steps) else b""
            raise TranscriptMismatch(
                f"transcript stopped at step {self._index} of {len(self._steps)}; "
                f"next expected request {missing!r}, partial {bytes(self._pending)!r}"
            )
        if self._readable:
            raise TranscriptMismatch(f"reply bytes left unread: {bytes(self._readable)!r}")
