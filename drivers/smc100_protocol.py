"""Newport SMC100 (CC/PP) ASCII protocol: request formatting and reply decoding.

No I/O happens here; :mod:`drivers.newport_smc100` does the talking. Every decoder raises
only :class:`~drivers.errors.ProtocolError` on bytes that do not follow the protocol, so
a driver has exactly one failure channel for "the wire said something wrong".

Wire format (Newport *SMC100CC & SMC100PP Single-Axis Motion Controller/Driver User's
Manual*; MagAO-X ``smc100ccCtrl_test.cpp`` transcripts; QMI
``single_axis_motion_controller.py``):

- A request is ``<address><CMD>[<value>|?]\\r\\n``: address 1..31 in decimal, a
  two-letter upper-case command, an optional value (a number, or ``?`` to query a
  setting). Example: ``1PA45.5\\r\\n``.
- A reply echoes the address and the command, then the value: ``1TP\\r\\n`` is
  answered by ``1TP10.500000\\r\\n``; two-digit addresses echo both digits
  (``12TS00000A\\r\\n``). Motion and set commands (``PA``, ``PR``, ``OR``, ``RS``,
  ``PW``, ``VA``...) are *not* answered; their success is learnt from ``TE``.
- ``TS`` answers six hex digits: four of positioner error bits, two of controller
  state. ``TE`` answers one character, ``@`` for "no error"; reading it clears it.

Garbage before a reply on the same line (a noisy line, a controller waking up) is
skipped: :func:`match_reply` looks for the expected echo inside the line. A line that
answers another command or another address (a stale reply after a timeout, another
controller on the RS-485 chain) is recognised and reported as not ours (``None``).
"""

from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass

from drivers.errors import ProtocolError

__all__ = [
    "COMMAND_ERRORS",
    "END_OF_RUN_BITS",
    "POSITIONER_ERRORS",
    "STATE_TABLE",
    "TERMINATOR",
    "CommandErrorCode",
    "Phase",
    "Smc100Status",
    "StateInfo",
    "format_command",
    "format_number",
    "match_reply",
    "parse_error_code",
    "parse_number",
    "parse_status",
]

TERMINATOR = b"\r\n"
#: RS-485 addresses a controller can take.
ADDRESS_RANGE = (1, 31)

_COMMAND_RE = re.compile(r"[A-Z]{2}")
_NUMBER_RE = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_HEX6_RE = re.compile(r"[0-9A-Fa-f]{6}")
#: Decimals sent in numeric arguments: 1e-6 units is below every stage's resolution.
_DECIMALS = 6


# --------------------------------------------------------------------------- tables


class Phase(enum.Enum):
    """The controller state families of the SMC100 state diagram."""

    NOT_REFERENCED = "NOT REFERENCED"
    CONFIGURATION = "CONFIGURATION"
    HOMING = "HOMING"
    MOVING = "MOVING"
    READY = "READY"
    DISABLE = "DISABLE"
    TRACKING = "TRACKING"


@dataclass(frozen=True)
class StateInfo:
    """One controller state code (second field of ``TS``)."""

    code: int
    name: str
    phase: Phase


def _states() -> dict[int, StateInfo]:
    nr, rd, ds = Phase.NOT_REFERENCED, Phase.READY, Phase.DISABLE
    rows = [
        (0x0A, "NOT REFERENCED from RESET", nr),
        (0x0B, "NOT REFERENCED from HOMING", nr),
        (0x0C, "NOT REFERENCED from CONFIGURATION", nr),
        (0x0D, "NOT REFERENCED from DISABLE", nr),
        (0x0E, "NOT REFERENCED from READY", nr),
        (0x0F, "NOT REFERENCED from MOVING", nr),
        (0x10, "NOT REFERENCED, no parameters (stage error)", nr),
        (0x14, "CONFIGURATION", Phase.CONFIGURATION),
        (0x1E, "HOMING", Phase.HOMING),
        (0x28, "MOVING", Phase.MOVING),
        (0x32, "READY from HOMING", rd),
        (0x33, "READY from MOVING", rd),
        (0x34, "READY from DISABLE", rd),
        (0x36, "READY T from READY", rd),
        (0x37, "READY T from TRACKING", rd),
        (0x38, "READY T from DISABLE T", rd),
        (0x3C, "DISABLE from READY", ds),
        (0x3D, "DISABLE from MOVING", ds),
        (0x3E, "DISABLE from TRACKING", ds),
        (0x3F, "DISABLE from READY T", ds),
        (0x46, "TRACKING from READY", Phase.TRACKING),
        (0x47, "TRACKING from TRACKING", Phase.TRACKING),
    ]
    return {code: StateInfo(code, name, phase) for code, name, phase in rows}


#: Controller states by code (QMI ``STATE_TABLE``, bliss ``HWSTATES``; the SMC100 user's
#: manual).
STATE_TABLE: dict[int, StateInfo] = _states()

#: Positioner error bits (first field of ``TS``; QMI ``POSITIONER_ERROR_TABLE``).
POSITIONER_ERRORS: dict[int, str] = {
    0x0200: "80 W output power exceeded",
    0x0100: "DC voltage too low",
    0x0080: "wrong ESP stage",
    0x0040: "homing time-out",
    0x0020: "following error",
    0x0010: "short circuit detection",
    0x0008: "RMS current limit",
    0x0004: "peak current limit",
    0x0002: "positive end of run",
    0x0001: "negative end of run",
}
#: The limit-switch bits: a position fact, not a fault.
END_OF_RUN_BITS = 0x0003

#: ``TE`` command error letters (MagAO-X test table; yaqd-newport error_dict).
COMMAND_ERRORS: dict[str, str] = {
    "A": "unknown message code or floating point controller address",
    "B": "controller address not correct",
    "C": "parameter missing or out of range",
    "D": "command not allowed",
    "E": "home sequence already started",
    "F": "ESP stage name unknown",
    "G": "displacement out of limits",
    "H": "command not allowed in NOT REFERENCED state",
    "I": "command not allowed in CONFIGURATION state",
    "J": "command not allowed in DISABLE state",
    "K": "command not allowed in READY state",
    "L": "command not allowed in HOMING state",
    "M": "command not allowed in MOVING state",
    "N": "current position out of software limit",
    "S": "communication time-out",
    "U": "error during EEPROM access",
    "V": "error during command execution",
    "W": "command not allowed for PP version",
    "X": "command not allowed for CC version",
}


# --------------------------------------------------------------------------- requests


def format_number(value: float) -> str:
    """A number as the controller reads it: fixed point, at most 6 decimals, no exponent.

    >>> format_number(45.0), format_number(-1.5), format_number(1e-7)
    ('45', '-1.5', '0')
    """
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"cannot send a non-finite number: {value}")
    text = f"{value:.{_DECIMALS}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def format_command(address: int, command: str, value: float | str | None = None) -> bytes:
    """Bytes of one request, terminator included.

    ``value`` is ``None`` (no argument), ``"?"`` (query a setting), a number, or a raw
    printable string.
    """
    if isinstance(address, bool) or not isinstance(address, int):
        raise TypeError(f"address must be an int, got {address!r}")
    low, high = ADDRESS_RANGE
    if not low <= address <= high:
        raise ValueError(f"address must be in {low}..{high}, got {address}")
    if not _COMMAND_RE.fullmatch(command):
        raise ValueError(f"command must be two upper-case letters, got {command!r}")
    if value is None:
        arg = ""
    elif isinstance(value, str):
        if not all(0x20 < ord(c) < 0x7F for c in value):
            raise ValueError(f"argument must be printable ASCII without spaces: {value!r}")
        arg = value
    else:
        arg = format_number(value)
    return f"{address}{command}{arg}".encode("ascii") + TERMINATOR


def echo(address: int, command: str) -> bytes:
    """What a reply to ``command`` from ``address`` starts with."""
    return f"{address}{command}".encode("ascii")


# --------------------------------------------------------------------------- replies


def match_reply(line: bytes, address: int, command: str) -> str | None:
    """The value part of ``line`` if it answers ``command`` from ``address``.

    Returns ``None`` for a complete line that answers something else (another
    command: a stale reply; another address: a neighbour on the chain; or no echo at
    all: line noise). Bytes before the echo are skipped.

    Raises
    ------
    ProtocolError
        ``line`` is not a complete line, or it carries our echo but its value is not
        printable ASCII (a corrupted reply to our command).
    """
    if not line.endswith(TERMINATOR):
        raise ProtocolError(f"incomplete reply line {line!r} (no CR LF)")
    body = line[: -len(TERMINATOR)]
    expected = echo(address, command)
    # The rightmost echo wins: noise before a reply may itself contain the echo, while
    # no reply value (a number, hex digits, one letter, a stage or version text)
    # contains its own address and command.
    end = len(body)
    while True:
        at = body.rfind(expected, 0, end)
        if at < 0:
            return None
        # A digit just before the echo means another address ("12TS" is not "2TS").
        if at == 0 or not 0x30 <= body[at - 1] <= 0x39:  # ASCII digits only
            break
        end = at + len(expected) - 1
    raw = body[at + len(expected):]
    if any(not 0x20 <= b < 0x7F for b in raw):
        raise ProtocolError(f"reply to {expected.decode()} carries non-ASCII bytes: {line!r}")
    return raw.decode("ascii").strip()


def parse_number(value: str) -> float:
    """A finite decimal number (``TP``, ``TH``, ``VA?`` ... values)."""
    text = value.strip()
    if not _NUMBER_RE.fullmatch(text):
        raise ProtocolError(f"expected a number, got {value!r}")
    number = float(text)
    if not math.isfinite(number):
        raise ProtocolError(f"number out of range: {value!r}")
    return number


@dataclass(frozen=True)
class Smc100Status:
    """A decoded ``TS`` reply: positioner error bits and controller state."""

    error_bits: int
    state: int

    @property
    def info(self) -> StateInfo:
        return STATE_TABLE[self.state]

    @property
    def phase(self) -> Phase:
        return self.info.phase

    @property
    def errors(self) -> tuple[str, ...]:
        """Every positioner error bit set, in words (end-of-run included)."""
        return _bit_texts(self.error_bits)

    @property
    def fault_errors(self) -> tuple[str, ...]:
        """Error bits that are faults (everything but the end-of-run switches)."""
        return _bit_texts(self.error_bits & ~END_OF_RUN_BITS)

    @property
    def at_positive_limit(self) -> bool:
        return bool(self.error_bits & 0x0002)

    @property
    def at_negative_limit(self) -> bool:
        return bool(self.error_bits & 0x0001)

    @property
    def is_referenced(self) -> bool:
        return self.phase in (Phase.READY, Phase.MOVING, Phase.DISABLE, Phase.TRACKING)

    @property
    def is_enabled(self) -> bool:
        return self.phase is not Phase.DISABLE

    @property
    def is_moving(self) -> bool:
        """Moving under its own control: a move, a homing run or analog tracking."""
        return self.phase in (Phase.MOVING, Phase.HOMING, Phase.TRACKING)

    @property
    def is_homing(self) -> bool:
        return self.phase is Phase.HOMING


def _bit_texts(bits: int) -> tuple[str, ...]:
    texts = []
    for bit in range(16):
        mask = 1 << bit
        if bits & mask:
            texts.append(POSITIONER_ERRORS.get(mask, f"undocumented error bit 0x{mask:04X}"))
    return tuple(texts)


def parse_status(value: str) -> Smc100Status:
    """Decode a ``TS`` value such as ``"000033"``."""
    text = value.strip()
    if not _HEX6_RE.fullmatch(text):
        raise ProtocolError(f"TS value must be 6 hex digits, got {value!r}")
    bits, state = int(text[:4], 16), int(text[4:], 16)
    if state not in STATE_TABLE:
        raise ProtocolError(f"unknown controller state 0x{state:02X} in TS {value!r}")
    return Smc100Status(bits, state)


@dataclass(frozen=True)
class CommandErrorCode:
    """A ``TE`` error letter and what it means."""

    letter: str
    meaning: str


def parse_error_code(value: str) -> CommandErrorCode | None:
    """Decode a ``TE`` value: ``None`` for ``@`` (no error), else the letter's meaning."""
    text = value.strip()
    if text == "@":
        return None
    if len(text) != 1 or text not in COMMAND_ERRORS:
        raise ProtocolError(f"unknown TE error code {value!r}")
    return CommandErrorCode(text, COMMAND_ERRORS[text])
