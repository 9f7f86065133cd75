"""Zaber ASCII protocol: command encoding and message decoding.

No I/O happens here; :mod:`drivers.zaber_ascii` does the talking. Every decoder raises only
:class:`~drivers.errors.ProtocolError` on bytes that do not follow the protocol, and the
message says what is wrong (bad checksum, unknown reply flag, missing field ...), so a
driver has one failure channel for "the wire said something wrong".

Sources
-------
* Zaber Technologies, *ASCII Protocol Manual* (Zaber wiki ``Manuals/ASCII_Protocol_Manual``,
  firmware 6.06 and up), section "Conventions Used Throughout this Document": a command
  may end in any combination of CR and LF, a device's messages always end in CR LF;
  positions are in microsteps. Only the opening sections of the manual could be read in
  the stored copy available to us; see "What is not from the manual" below.
* Zaber Technologies, *A-Series ASCII Protocol (alpha)*, Zaber wiki ``ASCII`` (firmware
  6.02), "Protocol Specifications": every command starts with ``/``; the device does not
  echo; commands use printable ASCII (32–126).
* S. Hunt (Zaber firmware team), *Zaber's ASCII Protocol*, zaber.com/articles/ascii-protocol
  (13 July 2022): the four message types (``/`` command, ``@`` reply, ``#`` info, ``!``
  alert; alerts are off by default) and the reply fields ``@01 0 OK IDLE -- 0``: device
  address, axis (0 = the whole device), ``OK``/``RJ``, ``BUSY``/``IDLE``, the
  highest-priority warning flag (``--`` for none) and the data (``0`` if nothing to say).

What is not from the manual (its later sections could not be read here)
----------------------------------------------------------------------
* The optional message id (a number between the axis and the command, echoed in the reply)
  and the checksum: ``:`` plus two upper-case hex digits, the two's complement of the low
  byte of the sum of every byte *after the leading type character* (``/``, ``@``, ``#``,
  ``!``) up to the ``:``. Both follow Zaber's own Python library ``zaber.serial``
  (``AsciiCommand.encode``, ``AsciiReply.__init__``: "XOR + 1, as per the LRC"). Message
  ids are kept to 0–99 here (two digits) **[range unverified against the manual]**.
* The alert layout ``!01 1 IDLE --`` (``zaber.serial`` ``AsciiReply``): device, axis,
  status, warning flag, optional data; no reply flag and no message id.
* The warning flags and their meanings: Zaber Motion Library ``WarningFlags``; the
  rejection reasons: the project's hardware reference §1d plus ``DRIVERDISABLED`` (the
  Zaber Motion Library's ``DriverDisabledException``, "a device cannot carry out a movement
  command because the motor driver is disabled").
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass

from drivers.errors import ProtocolError

__all__ = [
    "ALERT",
    "INFO",
    "MESSAGE_ID_RANGE",
    "REJECTION_REASONS",
    "REPLY",
    "TERMINATOR",
    "WARNING_FLAGS",
    "Alert",
    "FlagLevel",
    "Info",
    "Message",
    "Reply",
    "checksum",
    "encode_command",
    "flag_level",
    "parse_int",
    "parse_message",
    "parse_warnings",
    "scan_message",
]

#: What every device message ends with (the manual's conventions).
TERMINATOR = b"\r\n"
#: What this driver ends its commands with (CR, LF or both are accepted by devices).
COMMAND_END = b"\n"
REPLY, INFO, ALERT = "@", "#", "!"
#: Device addresses on a daisy chain (0 addresses every device), axes (0 = whole device).
DEVICE_RANGE = (0, 99)
AXIS_RANGE = (0, 9)
MESSAGE_ID_RANGE = (0, 99)


class FlagLevel(enum.Enum):
    """What the first letter of a warning flag says (Zaber Motion Library ``WarningFlags``)."""

    FAULT = "F"
    WARNING = "W"
    NOTICE = "N"
    NONE = "-"


#: Warning flags (Zaber Motion Library ``WarningFlags``; hardware reference §1d).
WARNING_FLAGS: dict[str, str] = {
    # faults
    "FF": "critical system error",
    "FN": "peripheral not supported",
    "FZ": "peripheral inactive",
    "FH": "hardware emergency stop, driver disabled",
    "FV": "overvoltage or undervoltage, driver disabled",
    "FO": "driver disabled on startup or by command",
    "FC": "current inrush error",
    "FM": "motor temperature error",
    "FD": "driver disabled",
    "FQ": "encoder error",
    "FI": "index error",
    "FA": "analog encoder sync error",
    "FR": "overdrive limit exceeded",
    "FS": "stalled and stopped",
    "FB": "stream bounds error",
    "FP": "interpolated path deviation",
    "FE": "limit error",
    "FT": "excessive twist",
    # warnings
    "WL": "unexpected limit trigger",
    "WV": "voltage out of range",
    "WT": "controller temperature high",
    "WS": "stalled with recovery",
    "WM": "displaced when stationary",
    "WP": "invalid calibration type",
    "WR": "no reference position",
    "WH": "device not homed",
    # notices
    "NC": "manual control",
    "NI": "movement interrupted",
    "ND": "stream discontinuity",
    "NR": "value rounded",
    "NT": "value truncated",
    "NU": "setting update pending",
    "NJ": "joystick calibrating",
    "NB": "device in firmware update mode",
}

#: Reasons in the data field of an ``RJ`` reply (hardware reference §1d; ``DRIVERDISABLED``
#: from the Zaber Motion Library's exceptions).
REJECTION_REASONS: dict[str, str] = {
    "AGAIN": "the device cannot take the command now; send it again",
    "BADAXIS": "the command went to an axis that does not exist or cannot take it",
    "BADCOMMAND": "the device does not know the command (or it is not allowed here)",
    "BADDATA": "a value is out of range or malformed",
    "BADMESSAGEID": "the message id is not valid",
    "DEVICEONLY": "the command applies to the whole device; send it to axis 0",
    "DRIVERDISABLED": "the motor driver is disabled",
    "FULL": "the device's buffer is full",
    "LOCKSTEP": "the axis is part of a lockstep group",
    "NOACCESS": "the command needs a higher access level",
    "PARKED": "the axis is parked",
    "STATUSBUSY": "the device is busy",
}

_COMMAND_TEXT_RE = re.compile(r"[\x20-\x7e]*")
_HEX2 = re.compile(rb"[0-9A-F]{2}")
_REPLY_RE = re.compile(
    r"@(\d{2}) (\d) (?:(\d{1,3}) )?(OK|RJ) (BUSY|IDLE) (--|[A-Z]{2}) ([\x21-\x7e][\x20-\x7e]*)")
_ALERT_RE = re.compile(r"!(\d{2}) (\d) (BUSY|IDLE) (--|[A-Z]{2})(?: ([\x20-\x7e]*))?")
_INFO_RE = re.compile(r"#(\d{2}) (\d) (?:(\d{1,3}) )?([\x20-\x7e]*)")
_INT_RE = re.compile(r"[+-]?\d{1,18}")
#: Where a message could start inside a line (after garbage): type char + two digits.
_START_RE = re.compile(rb"[@!#]\d\d ")


def flag_level(flag: str) -> FlagLevel:
    """Fault, warning, notice or none (``--``), from the flag's first letter."""
    if flag == "--":
        return FlagLevel.NONE
    try:
        return FlagLevel(flag[:1])
    except ValueError:
        raise ProtocolError(f"warning flag {flag!r} is neither F*, W*, N* nor --") from None


# --------------------------------------------------------------------------- commands


def checksum(body: bytes) -> str:
    """The two hex digits that follow ``:``: two's complement of the low byte of the sum.

    ``body`` is the message without its leading type character and without the ``:``.

    >>> checksum(b"1 1 move abs 10000")
    '40'
    """
    return f"{(-sum(body)) & 0xFF:02X}"


def _check_int(value: int, name: str, bounds: tuple[int, int]) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name} must be an int, got {value!r}")
    low, high = bounds
    if not low <= value <= high:
        raise ValueError(f"{name} must be in {low}..{high}, got {value}")
    return value


def encode_command(device: int, axis: int, command: str = "", *,
                   message_id: int | None = None, with_checksum: bool = False) -> bytes:
    """Bytes of one command, terminator included.

    ``command`` is the text after the address (``"move abs 10000"``, ``"get pos"``; empty
    for a status poll). With ``with_checksum`` the body is followed by ``:`` and its checksum.

    >>> encode_command(1, 1, "move abs 10000")
    b'/1 1 move abs 10000\\n'
    >>> encode_command(2, 0, "get pos", message_id=7, with_checksum=True)
    b'/2 0 7 get pos:55\\n'
    """
    _check_int(device, "device", DEVICE_RANGE)
    _check_int(axis, "axis", AXIS_RANGE)
    if not isinstance(command, str) or not _COMMAND_TEXT_RE.fullmatch(command):
        raise ValueError(f"command must be printable ASCII, got {command!r}")
    if ":" in command or "/" in command:
        raise ValueError(f"command must not contain ':' or '/': {command!r}")
    if command != command.strip() or "  " in command:
        raise ValueError(f"command words must be separated by single spaces: {command!r}")
    words = [str(device), str(axis)]
    if message_id is not None:
        words.append(str(_check_int(message_id, "message_id", MESSAGE_ID_RANGE)))
    if command:
        words.append(command)
    body = " ".join(words).encode("ascii")
    if with_checksum:
        body += b":" + checksum(body).encode("ascii")
    return b"/" + body + COMMAND_END


# --------------------------------------------------------------------------- messages


@dataclass(frozen=True)
class Reply:
    """An ``@`` reply: the answer to one command."""

    device: int
    axis: int
    message_id: int | None
    flag: str      # "OK" or "RJ"
    status: str    # "BUSY" or "IDLE"
    warning: str   # highest-priority warning flag, "--" for none
    data: str
    checksummed: bool = False

    @property
    def rejected(self) -> bool:
        return self.flag == "RJ"

    @property
    def busy(self) -> bool:
        return self.status == "BUSY"

    @property
    def reason(self) -> str | None:
        """Why the command was rejected (``RJ``), else ``None``."""
        return self.data if self.rejected else None

    def encode(self, *, with_checksum: bool = False) -> bytes:
        words = [f"{self.device:02d}", str(self.axis)]
        if self.message_id is not None:
            words.append(f"{self.message_id:02d}")
        words += [self.flag, self.status, self.warning, self.data]
        return _frame(REPLY, " ".join(words), with_checksum)


@dataclass(frozen=True)
class Alert:
    """A ``!`` alert: sent unprompted (when ``comm.alert`` is on), e.g. when a move ends."""

    device: int
    axis: int
    status: str
    warning: str
    data: str = ""
    checksummed: bool = False

    def encode(self, *, with_checksum: bool = False) -> bytes:
        text = f"{self.device:02d} {self.axis} {self.status} {self.warning}"
        if self.data:
            text += f" {self.data}"
        return _frame(ALERT, text, with_checksum)


@dataclass(frozen=True)
class Info:
    """A ``#`` info message: extra lines some commands send after their reply."""

    device: int
    axis: int
    message_id: int | None
    data: str
    checksummed: bool = False

    def encode(self, *, with_checksum: bool = False) -> bytes:
        words = [f"{self.device:02d}", str(self.axis)]
        if self.message_id is not None:
            words.append(f"{self.message_id:02d}")
        return _frame(INFO, " ".join([*words, self.data]) if self.data else " ".join(words),
                      with_checksum)


Message = Reply | Alert | Info


def _frame(kind: str, text: str, with_checksum: bool) -> bytes:
    body = text.encode("ascii")
    if with_checksum:
        body += b":" + checksum(body).encode("ascii")
    return kind.encode("ascii") + body + TERMINATOR


def parse_message(line: bytes, *, require_checksum: bool = False) -> Message:
    """Decode one complete device message (``@``, ``!`` or ``#``), CR LF included.

    A trailing ``:HH`` is a checksum and is verified. With ``require_checksum`` a message
    without one is refused (a link with ``comm.checksum`` on).

    Raises
    ------
    ProtocolError
        The line is not one well-formed message; the text says which part is wrong.
    """
    if not isinstance(line, bytes | bytearray):
        raise TypeError(f"line must be bytes, got {type(line).__name__}")
    if not line.endswith(TERMINATOR):
        raise ProtocolError(f"incomplete message {bytes(line[:60])!r} (no CR LF)")
    body = bytes(line[: -len(TERMINATOR)])
    if not body:
        raise ProtocolError("empty line")
    kind = chr(body[0])
    if kind not in (REPLY, ALERT, INFO):
        raise ProtocolError(f"message starts with {body[:1]!r}, not '@', '!' or '#': {body[:60]!r}")
    if any(not 0x20 <= b < 0x7F for b in body):
        raise ProtocolError(f"message carries non-printable bytes: {body[:60]!r}")
    checksummed = len(body) >= 4 and body[-3:-2] == b":" and bool(_HEX2.fullmatch(body[-2:]))
    if checksummed:
        given = body[-2:].decode("ascii")
        body = body[:-3]
        expected = checksum(body[1:])
        if given != expected:
            raise ProtocolError(f"bad checksum {given} (computed {expected}) in {body[:60]!r}")
    elif require_checksum:
        raise ProtocolError(f"missing checksum (comm.checksum is on): {body[:60]!r}")
    text = body.decode("ascii")
    if kind == REPLY:
        return _reply(text, checksummed)
    if kind == ALERT:
        match = _ALERT_RE.fullmatch(text)
        if match is None:
            raise ProtocolError(f"malformed alert {text[:60]!r}: expected '!DD A STATUS FLAG'")
        device, axis, status, warning, data = match.groups()
        _check_flag(warning, text)
        return Alert(int(device), int(axis), status, warning, data or "", checksummed)
    match = _INFO_RE.fullmatch(text)
    if match is None:
        raise ProtocolError(f"malformed info message {text[:60]!r}: expected '#DD A text'")
    device, axis, message_id, data = match.groups()
    return Info(int(device), int(axis), _message_id(message_id, text), data, checksummed)


def _reply(text: str, checksummed: bool) -> Reply:
    match = _REPLY_RE.fullmatch(text)
    if match is None:
        raise ProtocolError(f"malformed reply {text[:60]!r}: {_reply_problem(text)}")
    device, axis, message_id, flag, status, warning, data = match.groups()
    _check_flag(warning, text)
    if flag == "RJ" and data not in REJECTION_REASONS and not data.isupper():
        raise ProtocolError(f"rejection without a reason word in {text[:60]!r}")
    return Reply(int(device), int(axis), _message_id(message_id, text), flag, status,
                 warning, data, checksummed)


def _reply_problem(text: str) -> str:
    """Name the first field of a malformed reply that is wrong (for the error message)."""
    words = text[1:].split(" ")
    if not re.fullmatch(r"\d{2}", words[0]):
        return f"device address {words[0]!r} is not two digits"
    if len(words) < 2 or not re.fullmatch(r"\d", words[1]):
        return "axis number missing or not one digit"
    rest = words[2:]
    if rest and re.fullmatch(r"\d{1,3}", rest[0]):
        rest = rest[1:]
    names = ("reply flag (OK/RJ)", "status (BUSY/IDLE)", "warning flag", "data")
    patterns = (r"OK|RJ", r"BUSY|IDLE", r"--|[A-Z]{2}", r".+")
    for name, pattern, word in zip(names, patterns, [*rest, None, None, None, None],
                                   strict=False):
        if word is None:
            return f"{name} missing"
        if not re.fullmatch(pattern, word):
            return f"{name} {word!r} is not valid"
    return "extra spaces or fields"


def _check_flag(flag: str, text: str) -> None:
    if flag != "--" and flag[0] not in "FWN":
        raise ProtocolError(f"warning flag {flag!r} is neither F*, W*, N* nor -- in {text[:60]!r}")


def _message_id(raw: str | None, text: str) -> int | None:
    if raw is None:
        return None
    value = int(raw)
    low, high = MESSAGE_ID_RANGE
    if not low <= value <= high:
        raise ProtocolError(f"message id {value} outside {low}..{high} in {text[:60]!r}")
    return value


def scan_message(line: bytes, *, require_checksum: bool = False) -> Message:
    """Like :func:`parse_message`, but skips garbage before the message on the same line.

    Each place where a message could start (``@``, ``!`` or ``#`` and two digits) is tried
    from the left; the first that decodes wins. Garbage cannot fake a whole valid
    message by accident unless it contains one.

    Raises
    ------
    ProtocolError
        Nothing on the line decodes; the error of the last (rightmost) candidate is given,
        as that is where the real message most likely starts.
    """
    if not isinstance(line, bytes | bytearray):
        raise TypeError(f"line must be bytes, got {type(line).__name__}")
    line = bytes(line)
    if not line.endswith(TERMINATOR):
        raise ProtocolError(f"incomplete message {line[:60]!r} (no CR LF)")
    last: ProtocolError | None = None
    for match in _START_RE.finditer(line):
        try:
            return parse_message(line[match.start():], require_checksum=require_checksum)
        except ProtocolError as err:
            last = err
    if last is not None:
        raise last
    raise ProtocolError(f"no message on the line (line noise?): {line[:60]!r}")


# --------------------------------------------------------------------------- data fields


def parse_int(data: str, what: str = "value") -> int:
    """An integer data field (positions, speeds, settings)."""
    text = data.strip()
    if not _INT_RE.fullmatch(text):
        raise ProtocolError(f"{what} must be an integer, got {data!r}")
    return int(text)


def parse_warnings(data: str) -> tuple[str, ...]:
    """Decode the data of a ``warnings`` reply: a count, then that many flags.

    ``"00"`` → ``()``; ``"02 FO WR"`` → ``("FO", "WR")``.
    """
    words = data.split()
    if not words or not re.fullmatch(r"\d{1,2}", words[0]):
        raise ProtocolError(f"warnings data must start with a count, got {data!r}")
    count, flags = int(words[0]), tuple(words[1:])
    if count != len(flags):
        raise ProtocolError(f"warnings count {count} does not match {len(flags)} flags: "
                            f"{data!r}")
    for flag in flags:
        if not re.fullmatch(r"[FWN][A-Z]", flag):
            raise ProtocolError(f"not a warning flag: {flag!r} in {data!r}")
    return flags
