"""Thorlabs Elliptec (ELLx) ASCII protocol: command encoding and reply decoding.

No I/O happens here; :mod:`drivers.thorlabs_elliptec` does the talking. Every decoder
raises only :class:`~drivers.errors.ProtocolError` on bytes that do not follow the
protocol, and the message says which part is wrong.

Source
------
Thorlabs, *Elliptec ELLx modules protocol manual* ("ELLx Resonant Piezo Motor
Communication Protocol", Issue 5, Dec 2020), introduction and the message pages
``_DEVGET_INFORMATION "IN"``, ``_HOSTREQ_STATUS "gs"``, ``_DEVGET_STATUS "GS"``,
``_HOSTREQ_HOME "ho"``, ``_HOSTREQ_MOVEABSOLUTE "ma"``, ``_HOSTREQ_MOVERELATIVE "mr"``,
``_DEVGET_POSITION "PO"``, velocity ``sv``/``gv`` and jog ``sj``/``gj``/``fw``/``bw``:

* 9600 baud, 8 data bits, 1 stop bit, no parity, no handshake.
* Every packet starts with the module's address, one character ``0``-``9``/``A``-``F``;
  then a two-letter mnemonic, lower case from the host (``gs``), upper case from the
  module (``GS``); then the data, fixed-length upper-case hex. Module replies end in
  CR LF. A host command is a fixed-length packet; this driver sends none of the optional
  terminators.
* Positions and jog steps are 32-bit two's complement integers of encoder pulses as eight
  hex digits (``0ma00004600``); ``in`` reports the pulses per measurement unit (ELL14:
  143360 pulses per 360°, i.e. 398.2 pulses per degree).
* ``IN`` data (30 characters): module type (2 hex), serial number (8), year (4),
  firmware release (2), hardware release (2; its top bit is the thread type), travel
  (4 hex: 360 for a rotation mount), pulses per measurement unit (8 hex; a rotation
  mount counts one revolution: ELL14 ``00023000``).
* ``GS`` data: one status byte (2 hex), :data:`STATUS_CODES`.

What is not from the manual (not readable in the copy available here)
-------------------------------------------------------------------
* The ``sv``/``gv`` velocity byte is read as a percentage of the module's maximum speed,
  0x01..0x64 (1..100 %) **[range unverified]**.
* A module that cannot carry out a move answers ``GS`` with the reason instead of ``PO``
  when the move ends (see :mod:`drivers.thorlabs_elliptec`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from drivers.errors import ProtocolError

__all__ = [
    "ADDRESSES",
    "BAUDRATE",
    "STATUS_BUSY",
    "STATUS_CODES",
    "STATUS_OK",
    "TERMINATOR",
    "Info",
    "Reply",
    "encode_command",
    "parse_info",
    "parse_position",
    "parse_reply",
    "parse_status",
    "parse_velocity",
    "pulses_to_hex",
    "scan_reply",
    "status_text",
]

BAUDRATE = 9600
TERMINATOR = b"\r\n"
#: The sixteen module addresses of one bus.
ADDRESSES = "0123456789ABCDEF"
STATUS_OK = 0
STATUS_BUSY = 9

#: ``GS`` status codes and what they mean (the manual's ``_DEVGET_STATUS`` table).
STATUS_CODES: dict[int, str] = {
    0: "ok",
    1: "communication time out",
    2: "mechanical time out",
    3: "command error or not supported",
    4: "value out of range",
    5: "module isolated",
    6: "module out of isolation",
    7: "initializing error",
    8: "thermal error",
    9: "busy",
    10: "sensor error",
    11: "motor error",
    12: "out of range",
    13: "over current error",
}

#: Commands this driver sends and the length of their data (hex characters, or the
#: home direction's single character).
COMMAND_DATA = {"in": 0, "gs": 0, "gp": 0, "gv": 0, "gj": 0, "st": 0, "fw": 0, "bw": 0,
                "ho": 1, "ma": 8, "mr": 8, "sj": 8, "sv": 2}

_REPLY_RE = re.compile(rb"([0-9A-F])([A-Z]{2})([0-9A-Za-z]*)")
_HEX = re.compile(r"[0-9A-F]+")
_INT32 = (-(2**31), 2**31 - 1)
#: Where a reply could start inside a line (after garbage): address + upper-case mnemonic.
_START_RE = re.compile(rb"[0-9A-F](?:IN|GS|PO|GV|GJ|HO)")


def status_text(code: int) -> str:
    """The manual's meaning of a ``GS`` code (``"undocumented status"`` beyond 0x0D)."""
    return STATUS_CODES.get(code, "undocumented status")


# --------------------------------------------------------------------------- commands


def pulses_to_hex(pulses: int) -> str:
    """Eight upper-case hex digits of a 32-bit two's complement count.

    >>> pulses_to_hex(17920), pulses_to_hex(-1)
    ('00004600', 'FFFFFFFF')
    """
    if isinstance(pulses, bool) or not isinstance(pulses, int):
        raise TypeError(f"pulses must be an int, got {pulses!r}")
    if not _INT32[0] <= pulses <= _INT32[1]:
        raise ValueError(f"{pulses} pulses do not fit 32 bits")
    return f"{pulses & 0xFFFFFFFF:08X}"


def encode_command(address: str, command: str, data: str = "") -> bytes:
    """Bytes of one host packet.

    >>> encode_command("0", "ma", "00004600")
    b'0ma00004600'
    >>> encode_command("A", "gs")
    b'Ags'
    """
    if not isinstance(address, str) or len(address) != 1 or address not in ADDRESSES:
        raise ValueError(f"address must be one character 0-9 or A-F, got {address!r}")
    length = COMMAND_DATA.get(command)
    if length is None:
        raise ValueError(f"unknown Elliptec command {command!r}")
    if len(data) != length or (data and not _HEX.fullmatch(data)):
        raise ValueError(f"{command!r} takes {length} upper-case hex character(s), "
                         f"got {data!r}")
    return f"{address}{command}{data}".encode("ascii")


# --------------------------------------------------------------------------- replies


@dataclass(frozen=True)
class Reply:
    """One module reply: its address, mnemonic (``PO``, ``GS`` ...) and data text."""

    address: str
    code: str
    data: str

    def encode(self) -> bytes:
        return f"{self.address}{self.code}{self.data}".encode("ascii") + TERMINATOR


@dataclass(frozen=True)
class Info:
    """The decoded ``IN`` reply."""

    module_type: int
    serial: str
    year: str
    firmware: str
    hardware: str
    travel: int
    pulses_per_unit: int

    @property
    def is_rotary(self) -> bool:
        """A rotation mount reports a travel of 360 (degrees)."""
        return self.travel == 360

    @property
    def degrees_per_pulse(self) -> float:
        """Degrees per encoder pulse of a rotation mount, whose pulses field counts one
        revolution (ELL14: 360 / 143360)."""
        if not self.is_rotary:
            raise ValueError(f"travel {self.travel} is not a rotation mount's 360")
        return 360.0 / self.pulses_per_unit


def parse_reply(line: bytes) -> Reply:
    """Decode one complete reply line, CR LF included.

    Raises
    ------
    ProtocolError
        The line is not ``<address><MNEMONIC><data>`` CR LF.
    """
    if not isinstance(line, bytes | bytearray):
        raise TypeError(f"line must be bytes, got {type(line).__name__}")
    if not line.endswith(TERMINATOR):
        raise ProtocolError(f"incomplete reply {bytes(line[:60])!r} (no CR LF)")
    body = bytes(line[: -len(TERMINATOR)])
    match = _REPLY_RE.fullmatch(body)
    if match is None:
        raise ProtocolError(f"malformed reply {body[:60]!r}: expected an address 0-F, a "
                            f"two-letter upper-case mnemonic and hex data")
    address, code, data = (g.decode("ascii") for g in match.groups())
    return Reply(address, code, data)


def scan_reply(line: bytes) -> Reply:
    """Like :func:`parse_reply`, but skips garbage before the reply (resynchronisation)."""
    try:
        return parse_reply(line)
    except ProtocolError as first:
        for match in _START_RE.finditer(line, 1):
            try:
                return parse_reply(line[match.start():])
            except ProtocolError:
                continue
        raise first from None


def _hex(data: str, digits: int, what: str) -> int:
    if len(data) != digits or not _HEX.fullmatch(data):
        raise ProtocolError(f"{what} must be {digits} upper-case hex digits, got {data!r}")
    return int(data, 16)


def parse_position(data: str) -> int:
    """``PO``/``GJ`` data: eight hex digits, 32-bit two's complement pulses.

    >>> parse_position("FFFFB9FF")
    -17921
    """
    value = _hex(data, 8, "a position")
    return value - 2**32 if value >= 2**31 else value


def parse_status(data: str) -> int:
    """``GS`` data: the status byte."""
    return _hex(data, 2, "a status code")


def parse_velocity(data: str) -> int:
    """``GV`` data: the velocity as a percentage of the maximum (1..100)."""
    value = _hex(data, 2, "a velocity")
    if not 1 <= value <= 100:
        raise ProtocolError(f"velocity {value} % is outside the module's 1..100 %")
    return value


def parse_info(data: str) -> Info:
    """``IN`` data: type, serial, year, firmware, hardware, travel, pulses per unit."""
    if len(data) != 30:
        raise ProtocolError(f"an IN reply carries 30 characters, got {len(data)}: {data!r}")
    fields = (data[0:2], data[2:10], data[10:14], data[14:16], data[16:18], data[18:22],
              data[22:30])
    module_type = _hex(fields[0], 2, "the module type")
    if not fields[1].isdigit() or not fields[2].isdigit():
        raise ProtocolError(f"serial number and year must be decimal digits: {data!r}")
    _hex(fields[3], 2, "the firmware release")
    _hex(fields[4], 2, "the hardware release")
    travel = _hex(fields[5], 4, "the travel")
    pulses = _hex(fields[6], 8, "the pulses per unit")
    if travel == 0 or pulses == 0:
        raise ProtocolError(f"travel and pulses per unit must be non-zero: {data!r}")
    return Info(module_type, fields[1], fields[2], fields[3], fields[4], travel, pulses)
