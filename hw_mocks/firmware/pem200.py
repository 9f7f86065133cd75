"""Firmware emulator of a Hinds Instruments PEM200 controller with a fused-silica head.

Written from the *PEM200 User Manual* (chapter 7, "Communication Protocol"),
independently of ``drivers/``: it imports nothing from there.

The device side:

- Host → controller: text commands, case sensitive, ended by ``\\n`` or ``;``; ``\\r`` is
  ignored. Set commands carry one argument after a space; get commands end in ``?``.
- Controller → host: ``[COMMAND](args)\\n`` after a command it applied,
  ``<IDENTIFIER>(message)\\n`` for an error; an unknown command answers
  ``<SCPINOP>(command)``.

Commands: ``*IDN?``; ``*RST`` (drive 0, fault cleared); ``:MOD:DRV x`` / ``:MOD:DRV?``
(drive 0..1, outside → ``<RANGE>(:MOD:DRV x)``); ``:MOD:FREQ?`` (Hz). The long forms
(``:MODulator:DRiVe``) are accepted too.

Default behaviour, declared once:

- The head resonates at ``frequency_hz`` (50 kHz for a fused-silica head, the ``FS50``
  class) with a slow deterministic drift of a few hertz over minutes (the head warming);
  ``:MOD:FREQ?`` reads it **[assumed command]**.
- A fault (:meth:`Pem200Emulator.enter_error_state`, e.g. the head unplugged) makes every
  command but ``*RST`` answer ``<HWERR>(command: modulator not resonating)``; ``*RST``
  clears it. The unsolicited frame of fault injection is ``<TEMP>(head temperature
  high)``, an error sent on its own, as the manual says errors may be.
- A host reconnecting finds the tail of an old answer in the pipe.
"""

from __future__ import annotations

import math

from hw_mocks.clock import Clock
from hw_mocks.emulator import FirmwareEmulator

__all__ = ["Pem200Emulator"]

_SHORT = {":MODulator:DRiVe": ":MOD:DRV", ":MODulator:DRiVe?": ":MOD:DRV?",
          ":MODulator:FREQuency?": ":MOD:FREQ?"}
_MAX_LINE = 256


class Pem200Emulator(FirmwareEmulator):
    """A PEM200 and its head.

    Parameters
    ----------
    frequency_hz
        The head's resonance at power-up.
    """

    scheme = "simpem"
    baudrate = 250000

    def __init__(self, name: str, *, frequency_hz: float = 50_000.0, clock: Clock | None = None,
                 seed: int = 0) -> None:
        super().__init__(name, clock=clock, seed=seed)
        if not (math.isfinite(frequency_hz) and frequency_hz > 0):
            raise ValueError(f"frequency_hz must be > 0, got {frequency_hz}")
        self.frequency_hz = float(frequency_hz)
        self.drive = 0.0
        self.faulted = False
        self.serial_number = f"{1000 + seed % 9000:04d}"
        self._t0 = self.clock.now()

    # backdoor -----------------------------------------------------------------
    def resonance_hz(self) -> float:
        """The frequency now: a drift of at most 5 Hz, settling over ~10 min of warm-up."""
        with self.lock:
            warm = 1.0 - math.exp(-(self.clock.now() - self._t0) / 600.0)
            return self.frequency_hz - 5.0 * warm * self.drive

    # FirmwareEmulator ---------------------------------------------------------
    def _handle_input(self, buf: bytearray) -> list[bytes]:
        out: list[bytes] = []
        while True:
            ends = [i for i in (buf.find(b"\n"), buf.find(b";")) if i >= 0]
            if not ends:
                if len(buf) > _MAX_LINE:
                    buf.clear()  # line noise without an end: dropped
                return out
            end = min(ends)
            raw = bytes(buf[:end]).replace(b"\r", b"")
            del buf[:end + 1]
            if raw:
                out.append(self._execute(raw.decode("ascii", "replace").strip()))

    def on_connect(self) -> list[bytes]:
        super().on_connect()
        with self.lock:
            return [] if self.connections <= 1 else [b"V?](0.000000)\n"]

    def unsolicited_frame(self) -> bytes:
        return b"<TEMP>(head temperature high)\n"

    def enter_error_state(self, code: str | None = None) -> None:
        """The head stops resonating (unplugged, detuned) until ``*RST``."""
        with self.lock:
            self.faulted = True

    # commands -----------------------------------------------------------------
    def _execute(self, line: str) -> bytes:
        head, _, arg = line.partition(" ")
        head = _SHORT.get(head, head)
        if head == "*RST" and not arg:
            self.faulted = False
            self.drive = 0.0
            return self._ok(head, "")
        if head not in ("*IDN?", ":MOD:DRV", ":MOD:DRV?", ":MOD:FREQ?") or \
                (arg and head != ":MOD:DRV"):
            return self._err("SCPINOP", line)
        if self.faulted:
            return self._err("HWERR", f"{line}: modulator not resonating")
        if head == "*IDN?":
            return self._ok(head, f"Hinds Instruments,PEM200,{self.serial_number},2.1.0")
        if head == ":MOD:DRV?":
            return self._ok(head, f"{self.drive:.6f}")
        if head == ":MOD:FREQ?":
            return self._ok(head, f"{self.resonance_hz():.3f}")
        try:
            value = float(arg)
        except ValueError:
            return self._err("SCPINOP", line)
        if not (math.isfinite(value) and 0.0 <= value <= 1.0):
            return self._err("RANGE", line)
        self.drive = value
        return self._ok(head, f"{value:.6f}")

    @staticmethod
    def _ok(identifier: str, args: str) -> bytes:
        return f"[{identifier}]({args})\n".encode("ascii")

    @staticmethod
    def _err(identifier: str, message: str) -> bytes:
        return f"<{identifier}>({message})\n".encode("ascii", "replace")
