"""Stanford Research SR830 (and SR810) remote-command message layer: no I/O.

:mod:`drivers.stanford_sr830` does the talking; this module turns requests into bytes and
reply lines into values. Every decoder raises only :class:`~drivers.errors.ProtocolError`
on text that does not follow the protocol, so a driver has one failure channel for "the
wire said something wrong". Source: Stanford Research Systems, *Model SR830 DSP Lock-In
Amplifier* manual, Revision 2.5 (10/2011), chapter 5 "Remote Programming" (pages below).

Wire format
-----------
- A command is a four-character mnemonic (``*`` + three letters for the IEEE-488.2 common
  commands), ``?`` for a query, then parameters separated by commas, then a terminator.
  The SR830 accepts a linefeed or a carriage return as terminator on RS-232 and ignores
  embedded spaces; several commands may share a line separated by ``;`` (p. 5-1, Command
  Syntax). This module sends ``MNEM[?][ p1[,p2…]]\\n``.
- Replies are ASCII, one per query, each terminated by a carriage return on RS-232 (a
  linefeed on GPIB) (p. 5-2). Replies carry no echo of the query: a late reply cannot be
  told from a fresh one by its text alone (the driver resynchronises; see there).
- Numbers in replies are integers (indices, status bytes) or ASCII floats such as
  ``-1.01026`` or ``-1.234567e-009`` (examples on pp. 5-15/5-16); parsers accept any
  decimal or exponent form.

Tables (p. 5-6, Gain and Time Constant commands)
------------------------------------------------
``SENS i``: full scale, i = 0…26 for 2 nV, 5 nV, 10 nV, … 500 mV, 1 V (1-2-5 steps; volts
rms, the µA/nA/pA column of the current inputs is not used here). ``OFLT i``: time
constant, i = 0…19 for 10 µs, 30 µs, 100 µs, … 10 ks, 30 ks (1-3 steps); time constants
above 30 s are refused when the detection frequency exceeds 200 Hz. ``OFSL i``: slope
6, 12, 18, 24 dB/oct for i = 0…3. ``FMOD i``: reference external (0) or internal (1);
``FREQ?`` returns the reference frequency in either mode (p. 5-4).

Status bytes (pp. 5-20 to 5-23)
-------------------------------
Serial poll (``*STB?``): 0 SCN no scan in progress, 1 IFC no command execution in
progress, 2 ERR, 3 LIA, 4 MAV, 5 ESB, 6 SRQ. Standard event (``*ESR?``): 0 INP input queue
overflow, 2 QRY output queue overflow, 4 EXE command cannot execute / parameter out of
range, 5 CMD illegal command, 6 URQ key press or knob, 7 PON power-on. LIA status
(``LIAS?``): 0 INPUT/RESRV input or amplifier overload, 1 FILTR time-constant filter
overload, 2 OUTPT output overload, 3 UNLK reference unlock, 4 RANGE detection frequency
crossed 200 Hz, 5 TC time constant changed indirectly, 6 TRIG data storage triggered.
Error status (``ERRS?``): 1 battery backup failed, 2 RAM, 4 ROM, 5 GPIB fast transfer
aborted, 6 DSP, 7 internal math error. The event, LIA and error bits stay set until they
are read or cleared by ``*CLS``.

Reference, input and storage tables (pp. 5-4 to 5-14)
----------------------------------------------------
``HARM i``: detect at the i-th harmonic, 1 ≤ i ≤ 19999 with i·f ≤ 102 kHz. ``RSLP i``:
reference trigger sine (0), TTL rising (1), TTL falling (2). ``ISRC i``: input A (0),
A−B (1), current 1 MΩ (2), current 100 MΩ (3). ``IGND i``: shield floating (0) or
grounded (1). ``ICPL i``: AC (0) or DC (1). ``ILIN i``: line notch filters none (0),
line (1), 2× line (2), both (3). ``SRAT i``: buffer sample rate 62.5 mHz × 2**i for
i = 0…13, 14 for one point per trigger. ``SPTS?``: points stored. ``TRCB? i,j,k``: k
points of display i from point j, as IEEE single-precision floats, little-endian, four
bytes each and no terminator.

``SNAP? i,j[,k…]`` (p. 5-15) returns 2 to 6 values taken at one instant, in the order
asked, separated by commas; codes 1 X, 2 Y, 3 R, 4 θ, 5–8 Aux In 1–4, 9 reference
frequency, 10/11 CH1/CH2 display.
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass

from drivers.errors import ProtocolError

__all__ = [
    "COMMAND_TERMINATOR",
    "ERROR_STATUS_BITS",
    "EVENT_STATUS_BITS",
    "FILTER_SLOPES_DB",
    "INPUT_SOURCES",
    "LIA_STATUS_BITS",
    "LINE_FILTERS",
    "MAX_DETECTION_HZ",
    "MAX_HARMONIC",
    "REFERENCE_SLOPES",
    "REPLY_TERMINATOR",
    "SAMPLE_RATES_HZ",
    "SENSITIVITIES_V",
    "SERIAL_POLL_BITS",
    "SNAP_CODES",
    "TIME_CONSTANTS_S",
    "EventStatus",
    "LiaStatus",
    "Sr830Identity",
    "command_text",
    "decode_error_status",
    "format_command",
    "index_of",
    "parse_float",
    "parse_floats",
    "parse_identity",
    "parse_int",
    "parse_status_byte",
    "parse_trace_binary",
    "reply_text",
]

COMMAND_TERMINATOR = b"\n"
REPLY_TERMINATOR = b"\r"

#: ``SENS`` full scales in volts rms, by index 0…26.
SENSITIVITIES_V: tuple[float, ...] = tuple(
    float(f"{mantissa}e{exponent}") for exponent in range(-9, 0) for mantissa in (2, 5, 10)
)
#: ``OFLT`` time constants in seconds, by index 0…19.
TIME_CONSTANTS_S: tuple[float, ...] = tuple(
    float(f"{mantissa}e{exponent}") for exponent in range(-5, 5) for mantissa in (1, 3)
)
#: ``OFSL`` slopes in dB/octave, by index 0…3.
FILTER_SLOPES_DB: tuple[int, ...] = (6, 12, 18, 24)
#: ``SNAP?`` parameter codes.
SNAP_CODES: dict[str, int] = {
    "x": 1, "y": 2, "r": 3, "theta": 4, "aux1": 5, "aux2": 6, "aux3": 7, "aux4": 8,
    "frequency": 9, "ch1": 10, "ch2": 11,
}

SERIAL_POLL_BITS: dict[int, str] = {
    0: "SCN", 1: "IFC", 2: "ERR", 3: "LIA", 4: "MAV", 5: "ESB", 6: "SRQ",
}
EVENT_STATUS_BITS: dict[int, str] = {
    0: "input queue overflow",
    2: "output queue overflow",
    4: "command cannot execute or parameter out of range",
    5: "illegal command",
    6: "key press or knob rotation",
    7: "power-on",
}
LIA_STATUS_BITS: dict[int, str] = {
    0: "input or amplifier overload",
    1: "time-constant filter overload",
    2: "output overload",
    3: "reference unlock",
    4: "detection frequency crossed 200 Hz",
    5: "time constant changed indirectly",
    6: "data storage triggered",
}
ERROR_STATUS_BITS: dict[int, str] = {
    1: "battery backup failed",
    2: "RAM memory test error",
    4: "ROM memory test error",
    5: "GPIB fast data transfer aborted",
    6: "DSP test error",
    7: "internal math error",
}

_MNEMONIC_RE = re.compile(r"(?:\*[A-Z]{3}|[A-Z]{4})\??")
_FLOAT_RE = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_INT_RE = re.compile(r"[+-]?\d+", re.ASCII)
_MAX_ARGS = 6

#: ``HARM`` limits: harmonic number and the highest detection frequency i·f.
MAX_HARMONIC = 19999
MAX_DETECTION_HZ = 102_000.0
#: ``RSLP`` index → reference trigger.
REFERENCE_SLOPES = ("sine", "rising", "falling")
#: ``ISRC`` index → input configuration.
INPUT_SOURCES = ("A", "A-B", "I1M", "I100M")
#: ``ILIN`` index → line notch filters in.
LINE_FILTERS = ("none", "line", "2xline", "both")
#: ``SRAT`` 0…13 → sample rate, Hz (14 is "per trigger").
SAMPLE_RATES_HZ = tuple(0.0625 * 2.0**i for i in range(14))


# --------------------------------------------------------------------------- requests


def _format_arg(value: int | float) -> str:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"command arguments are numbers, got {value!r}")
    if isinstance(value, int):
        return str(value)
    if not math.isfinite(value):
        raise ValueError(f"cannot send a non-finite number: {value}")
    return f"{value:.6g}"


def format_command(mnemonic: str, *args: int | float) -> bytes:
    """Bytes of one command line, terminator included.

    >>> format_command("SNAP?", 1, 2, 3, 4)
    b'SNAP? 1,2,3,4\\n'
    >>> format_command("OFLT", 8), format_command("*IDN?")
    (b'OFLT 8\\n', b'*IDN?\\n')
    """
    if not isinstance(mnemonic, str) or not _MNEMONIC_RE.fullmatch(mnemonic):
        raise ValueError(f"mnemonic must be four upper-case letters (or * and three), "
                         f"optionally followed by ?, got {mnemonic!r}")
    if len(args) > _MAX_ARGS:
        raise ValueError(f"at most {_MAX_ARGS} parameters, got {len(args)}")
    text = mnemonic
    if args:
        text += " " + ",".join(_format_arg(a) for a in args)
    return text.encode("ascii") + COMMAND_TERMINATOR


def command_text(mnemonic: str, *args: int | float) -> str:
    """The command as a person would read it in an error message (no terminator)."""
    return format_command(mnemonic, *args).decode("ascii").strip()


# --------------------------------------------------------------------------- replies


def reply_text(line: bytes) -> str:
    """The text of one reply line (terminator stripped, surrounding spaces dropped).

    Raises ProtocolError for a line without the CR terminator or with bytes outside
    printable ASCII (a corrupted or foreign reply).
    """
    if not line.endswith(REPLY_TERMINATOR):
        raise ProtocolError(f"incomplete reply line {line!r} (no CR)")
    body = line[: -len(REPLY_TERMINATOR)]
    if any(not 0x20 <= b < 0x7F for b in body):
        raise ProtocolError(f"reply carries non-ASCII bytes: {line!r}")
    return body.decode("ascii").strip()


def parse_float(text: str) -> float:
    """A finite decimal number (``FREQ?``, ``OUTP?`` values)."""
    stripped = text.strip()
    if not _FLOAT_RE.fullmatch(stripped):
        raise ProtocolError(f"expected a number, got {text!r}")
    value = float(stripped)
    if not math.isfinite(value):
        raise ProtocolError(f"number out of range: {text!r}")
    return value


def parse_floats(text: str, count: int) -> tuple[float, ...]:
    """Exactly ``count`` comma-separated numbers (a ``SNAP?`` reply)."""
    parts = text.split(",")
    if len(parts) != count:
        raise ProtocolError(f"expected {count} comma-separated values, got {text!r}")
    return tuple(parse_float(p) for p in parts)


def parse_int(text: str, low: int, high: int) -> int:
    """An integer in ``low..high`` (an index or a status byte)."""
    stripped = text.strip()
    if not _INT_RE.fullmatch(stripped):
        raise ProtocolError(f"expected an integer, got {text!r}")
    value = int(stripped)
    if not low <= value <= high:
        raise ProtocolError(f"integer {value} outside {low}..{high}")
    return value


def parse_status_byte(text: str) -> int:
    """A status byte 0…255 (``*STB?``, ``*ESR?``, ``LIAS?``, ``ERRS?``)."""
    return parse_int(text, 0, 255)


def index_of(table: tuple[float, ...], value: float, what: str) -> int:
    """Index of ``value`` in an instrument table (exact up to 1 ppm); ValueError if absent."""
    for i, entry in enumerate(table):
        if abs(entry - value) <= 1e-6 * abs(entry):
            return i
    raise ValueError(f"{what} {value!r} is not in the instrument's table")


@dataclass(frozen=True)
class LiaStatus:
    """A decoded ``LIAS?`` byte."""

    byte: int

    @property
    def input_overload(self) -> bool:
        return bool(self.byte & 0x01)

    @property
    def filter_overload(self) -> bool:
        return bool(self.byte & 0x02)

    @property
    def output_overload(self) -> bool:
        return bool(self.byte & 0x04)

    @property
    def unlocked(self) -> bool:
        return bool(self.byte & 0x08)

    @property
    def texts(self) -> tuple[str, ...]:
        return _bit_texts(self.byte, LIA_STATUS_BITS)


@dataclass(frozen=True)
class EventStatus:
    """A decoded ``*ESR?`` byte (standard event status)."""

    byte: int

    @property
    def command_error(self) -> bool:
        """CMD: an illegal command was received."""
        return bool(self.byte & 0x20)

    @property
    def execution_error(self) -> bool:
        """EXE: a command could not execute (parameter out of range, not allowed now)."""
        return bool(self.byte & 0x10)

    @property
    def queue_overflow(self) -> bool:
        """INP or QRY: input or output queue overflowed."""
        return bool(self.byte & 0x05)

    @property
    def power_on(self) -> bool:
        """PON: the instrument was switched on (or reset) since the byte was last read."""
        return bool(self.byte & 0x80)

    @property
    def texts(self) -> tuple[str, ...]:
        return _bit_texts(self.byte, EVENT_STATUS_BITS)


def decode_error_status(byte: int) -> tuple[str, ...]:
    """The ``ERRS?`` bits set, in words."""
    return _bit_texts(byte, ERROR_STATUS_BITS)


def _bit_texts(byte: int, table: dict[int, str]) -> tuple[str, ...]:
    return tuple(table.get(bit, f"undocumented bit {bit}")
                 for bit in range(8) if byte & (1 << bit))


@dataclass(frozen=True)
class Sr830Identity:
    """A decoded ``*IDN?`` reply ``Stanford_Research_Systems,SR830,s/n00111,ver1.000``."""

    vendor: str
    model: str
    serial: str
    firmware: str


def parse_identity(text: str) -> Sr830Identity:
    """Decode ``*IDN?`` (p. 5-19: vendor, model, ``s/n`` serial, ``ver`` firmware)."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 4 or not all(parts):
        raise ProtocolError(f"*IDN? reply must have four comma-separated fields: {text!r}")
    vendor, model, serial, firmware = parts
    if serial.lower().startswith("s/n"):
        serial = serial[3:]
    if firmware.lower().startswith("ver"):
        firmware = firmware[3:]
    return Sr830Identity(vendor, model, serial, firmware)


def parse_trace_binary(data: bytes, count: int) -> tuple[float, ...]:
    """``count`` points of a ``TRCB?`` reply: little-endian IEEE single floats.

    >>> parse_trace_binary(b"\\x00\\x00\\x80\\x3f\\x00\\x00\\x00\\xc0", 2)
    (1.0, -2.0)
    """
    if len(data) != 4 * count:
        raise ProtocolError(f"a trace of {count} points is {4 * count} bytes, got {len(data)}")
    values = struct.unpack(f"<{count}f", data)
    if not all(math.isfinite(v) for v in values):
        raise ProtocolError("non-finite value in a trace")
    return values
