"""Hinds Instruments PEM200 photoelastic modulator controller over its serial port.

Source
------
Hinds Instruments, *PEM200 User Manual*, chapter 7 "Communication Protocol" (pp. 32-33):

* The controller is a serial COM device (USB); any rate from 9600 to 250000 baud works,
  250000 is its own.
* Commands are SCPI-like text, case sensitive, ended by a newline (``\\n``) or ``;``;
  carriage returns are ignored. Set commands carry their argument after a space
  (``:MOD:DRV 0.25``), get commands end in ``?``. Abbreviations are the capitals of the
  long form (``:MODulator:DRiVe`` → ``:MOD:DRV``).
* Every answer ends in a newline and is either a command return ``[IDENTIFIER](args)``
  or an error ``<IDENTIFIER>(message)``; an unknown command answers
  ``<SCPINOP>(the command)``. Errors "may be transmitted by the unit at any time".
  Allow 300 ms for an answer.
* ``*IDN?`` identifies the unit; ``:MOD:DRV`` sets the modulator drive as a fraction
  0..1, ``:MOD:DRV?`` reads it.

What is assumed (not in the pages readable here)
------------------------------------------------
* The ``IDENTIFIER`` of a command return is the command as sent (``[:MOD:DRV?](0.25)``),
  and the message of an error caused by a command names that command.
* ``:MOD:FREQ?`` reads the modulation frequency in Hz.
* Drive outside 0..1 answers ``<RANGE>(...)``; a head that does not resonate answers
  ``<HWERR>(...)`` to every command until ``*RST``.
* The PEM-100's own RS-232 command set could not be found; this driver speaks the
  PEM200's. The physics (amplitude, frequency) is the same for both controllers.

Retardation
-----------
A modulator's peak retardation in nanometres is proportional to its drive. The factor
(``nm_per_drive``: nm of peak retardation at drive 1.0) is the head's calibration, from
its data sheet or from a calibration with crossed polarisers (the manual's appendix: the
half-wave waveform, or V₂f/V_DC between parallel polarisers). The driver converts:
``waves = drive × nm_per_drive / wavelength_nm``; the wavelength is the host's setting.
"""

from __future__ import annotations

import collections
import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import serial

from drivers.base import DeviceIdentity, Modulator, check_settings, retry_count
from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceError,
    DeviceTimeout,
    LimitError,
    ProtocolError,
    StateError,
    attempts_exhausted,
)
from drivers.transport import SerialChannel, open_serial

__all__ = [
    "NOTICES_KEPT",
    "Pem200",
    "PemAnswer",
    "PemCommandError",
    "PemFault",
    "PemOutOfRange",
    "parse_answer",
    "parse_drive",
    "parse_frequency",
]

T = TypeVar("T")
_TERMINATOR = b"\n"
_ANSWER_RE = re.compile(r"([\[<])([^\[\]<>()]+)([\]>])\(([^()]*)\)")
_MAX_LINE = 256
#: Unsolicited controller errors kept in :attr:`Pem200.notices`.
NOTICES_KEPT = 200


@dataclass(frozen=True)
class PemAnswer:
    """One answer line: a command return (``error`` False) or an error."""

    identifier: str
    text: str
    error: bool


def parse_answer(line: bytes) -> PemAnswer:
    """Decode ``[ID](args)`` or ``<ID>(message)`` plus newline (CR ignored).

    Raises
    ------
    ProtocolError
        Anything else; the message shows the line.
    """
    if not isinstance(line, bytes | bytearray):
        raise TypeError(f"line must be bytes, got {type(line).__name__}")
    if not line.endswith(_TERMINATOR):
        raise ProtocolError(f"incomplete answer {bytes(line[:60])!r} (no newline)")
    try:
        text = bytes(line).decode("ascii").replace("\r", "").rstrip("\n")
    except UnicodeDecodeError:
        raise ProtocolError(f"answer is not ASCII: {bytes(line[:60])!r}") from None
    match = _ANSWER_RE.fullmatch(text)
    if match is None or {match[1], match[3]} not in ({"[", "]"}, {"<", ">"}):
        raise ProtocolError(f"malformed answer {text[:60]!r}: expected [ID](args) or "
                            f"<ID>(message)")
    return PemAnswer(match[2], match[4], match[1] == "<")


def parse_drive(text: str) -> float:
    """``:MOD:DRV?`` data: the drive, a fraction 0..1 of the controller's full scale.

    Raises
    ------
    ValueError
        Not a number, or outside 0..1 (a retardation computed from it would be wrong).
    """
    value = float(text)
    if not (math.isfinite(value) and 0.0 <= value <= 1.0):
        raise ValueError(f"drive {value:g} is outside the controller's 0..1")
    return value


def parse_frequency(text: str) -> float:
    """``:MOD:FREQ?`` data: the modulation frequency in Hz, a finite number > 0 (the
    lock-in takes it as its reference).

    Raises
    ------
    ValueError
        Not a number, or not finite and > 0.
    """
    value = float(text)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"frequency {value:g} Hz is not a finite number > 0")
    return value


class PemCommandError(ControllerError):
    """The controller answered an error (``code`` is its identifier, e.g. ``SCPINOP``)."""


class PemOutOfRange(PemCommandError, LimitError):
    """A value outside what the controller takes (``RANGE``)."""


class PemFault(PemCommandError, StateError):
    """The modulator does not run (``HWERR``): ``reset()`` clears it once the cause is gone."""


class Pem200(Modulator):
    """A Hinds PEM200 controller with its optical head.

    Parameters
    ----------
    port
        A device path, a pyserial URL (``simpem://pem``) or an open ``serial.SerialBase``.
    name
        Role name used in every error.
    nm_per_drive
        Peak retardation in nm at drive 1.0 (the head's calibration).
    wavelength_nm
        The wavelength the amplitude is set and read at (the light source's).
    baudrate, reply_timeout, retries
        Link settings: rate, seconds to wait for an answer (the manual: allow 300 ms),
        extra attempts of an idempotent command after a lost or garbled answer.

    Raises
    ------
    ConnectionFailed
        The port cannot be opened or no PEM200 answers ``*IDN?``.
    """

    def __init__(self, port: str | serial.SerialBase, *, name: str, nm_per_drive: float,
                 wavelength_nm: float = 632.8, baudrate: int = 250000,
                 reply_timeout: float = 1.0, retries: int = 2) -> None:
        check_settings(nm_per_drive=nm_per_drive, wavelength_nm=wavelength_nm,
                       reply_timeout=reply_timeout)
        self.retries = retry_count(retries)
        super().__init__(name)
        self.nm_per_drive = float(nm_per_drive)
        self._wavelength_nm = float(wavelength_nm)
        self.reply_timeout = float(reply_timeout)
        #: Errors the controller sent on its own (not answers to a command), newest last;
        #: the latest ``NOTICES_KEPT`` (a controller warning every few seconds of a long
        #: session must not grow the driver without bound).
        self.notices: collections.deque[PemAnswer] = collections.deque(maxlen=NOTICES_KEPT)
        self._owned = not isinstance(port, serial.SerialBase)
        raw = open_serial(port, device=name, baudrate=baudrate)
        try:
            self._channel: SerialChannel | None = SerialChannel(raw, device=name)
            self._channel.discard_input()
            try:
                self._idn = self._ask("*IDN?", str)
            except (DeviceTimeout, ProtocolError) as err:
                raise ConnectionFailed(
                    "no PEM200 answers *IDN?", device=name, command="*IDN?",
                    hint="check the port, the USB cable and that the controller is on") from err
        except BaseException:
            self._channel = None
            if self._owned:
                raw.close()
            raise

    # wire ---------------------------------------------------------------------
    def _chan(self, command: str) -> SerialChannel:
        if self._channel is None:
            raise StateError("device is closed", device=self.name, command=command)
        return self._channel

    def _read_answer(self, command: str) -> PemAnswer:
        deadline = time.monotonic() + self.reply_timeout
        noise: list[str] = []
        while True:
            line = self._chan(command).read_line_by(_TERMINATOR, deadline, command=command,
                                                    noise=noise, max_bytes=_MAX_LINE)
            try:
                answer = parse_answer(line)
            except ProtocolError as err:
                noise.append(err.message)
                continue
            if answer.error and command.split(" ")[0] not in answer.text:
                self.notices.append(answer)  # sent on its own, not about this command
                continue
            if not answer.error and answer.identifier != command.split(" ")[0]:
                continue  # a late answer to an earlier command
            return answer

    def _exchange(self, command: str, *, retry: bool) -> PemAnswer:
        attempts = self.retries + 1 if retry else 1
        last: DeviceError | None = None
        for _ in range(attempts):
            try:
                channel = self._chan(command)
                channel.discard_input()  # one device, no ids: stale input is dropped
                channel.write(command.encode("ascii") + _TERMINATOR, command=command)
                answer = self._read_answer(command)
            except ProtocolError as err:
                last = ProtocolError(err.message, device=self.name, command=command)
                continue
            except DeviceTimeout as err:
                last = err
                continue
            if answer.error:
                raise self._error(answer, command)
            return answer
        assert last is not None
        raise attempts_exhausted(last, attempts, device=self.name, command=command) from last

    def _error(self, answer: PemAnswer, command: str) -> PemCommandError:
        message = f"controller refused the command: <{answer.identifier}>({answer.text})"
        if answer.identifier == "RANGE":
            return PemOutOfRange(message, code="RANGE", device=self.name, command=command,
                                 hint="the drive must be 0..1; lower the retardation")
        if answer.identifier == "HWERR":
            return PemFault(message, code="HWERR", device=self.name, command=command,
                            hint="check the head's cable and that it is the head the "
                            "controller is tuned to; reset() once the cause is fixed")
        return PemCommandError(message, code=answer.identifier, device=self.name,
                               command=command, hint="check the command for this controller")

    def _ask(self, command: str, parse: Callable[[str], T]) -> T:
        answer = self._exchange(command, retry=True)
        try:
            return parse(answer.text)
        except ValueError as err:
            raise ProtocolError(f"cannot read {answer.text!r} from {command!r}: {err}",
                                device=self.name, command=command) from err

    # public extras ------------------------------------------------------------
    @property
    def drive(self) -> float:
        """The modulator drive, 0..1 (``:MOD:DRV?``)."""
        self._check_open("drive")
        return self._ask(":MOD:DRV?", parse_drive)

    def reset(self) -> None:
        """``*RST``: clear a fault; the drive returns to 0."""
        self._check_open("reset")
        self._exchange("*RST", retry=True)

    # Modulator hooks -----------------------------------------------------------
    def _do_identity(self) -> DeviceIdentity:
        fields = [f.strip() for f in self._idn.split(",")]
        fields += [""] * (4 - len(fields))
        return DeviceIdentity(vendor=fields[0] or "Hinds Instruments",
                              model=fields[1] or "PEM200", serial=fields[2],
                              firmware=fields[3],
                              extra={"nm_per_drive": f"{self.nm_per_drive:g}"})

    def _do_get_wavelength_nm(self) -> float:
        return self._wavelength_nm

    def _do_set_wavelength_nm(self, value: float) -> None:
        self._wavelength_nm = value

    def _do_get_retardation_waves(self) -> float:
        return self.drive * self.nm_per_drive / self._wavelength_nm

    def _do_set_retardation_waves(self, value: float) -> None:
        drive = value * self._wavelength_nm / self.nm_per_drive
        if drive > 1.0:
            raise ValueError(
                f"{self.name}: {value:g} waves at {self._wavelength_nm:g} nm needs drive "
                f"{drive:.3g}, above the controller's 1.0 (at most "
                f"{self.nm_per_drive / self._wavelength_nm:.4g} waves)")
        self._exchange(f":MOD:DRV {drive:.6f}", retry=True)

    def _do_get_frequency_hz(self) -> float:
        return self._ask(":MOD:FREQ?", parse_frequency)

    def _do_close(self) -> None:
        channel, self._channel = self._channel, None
        if channel is not None and self._owned:
            channel.close()
