"""Thorlabs "keyword" ASCII protocol (SC10, FW102C and their siblings): requests and replies.

No I/O happens here; :mod:`drivers.thorlabs_ascii_link` does the talking. Every decoder
raises only :class:`~drivers.errors.ProtocolError` on bytes that break the protocol.

Wire format (SC10 manual 8654-D02, "Keywords (Commands and Queries)"; FW102C manual rev H,
§5.2.3; where the manuals are silent, the observed behaviour in open-source drivers that
were run against the units, named below):

- A request is a lower-case keyword, optionally ``=value`` (a command) or ``?`` (a query),
  ended by a carriage return: ``pos=3\\r``, ``pos?\\r``, ``ens\\r``, ``*idn?\\r``.
- The unit echoes what it received, terminator included, then sends the answer (if any)
  ended by a CR, then the prompt ``"> "`` (greater-than and space, no terminator after
  it): ``pos?\\r`` → ``pos?\\r3\\r> ``; ``pos=3\\r`` → ``pos=3\\r> ``. (Observed: the
  hispec and Jacob Feder FW102C drivers and Odemis's ``tlfw.py`` strip exactly
  ``echo … \\r> ``; Micro-Manager's SC10 adapter reads up to ``>`` and then meets the
  trailing space at the start of the next answer.)
- A refused request is answered, after the echo, by an error line ``Command error
  <CODE>`` (``CMD_NOT_DEFINED``: unknown keyword or bad format; ``CMD_ARG_INVALID``:
  argument out of range), then the prompt. The manuals only say "the unit will return an
  error string"; the texts are those the open-source drivers match, and Odemis records a
  line feed after them. The decoder therefore treats CR and LF alike as line breaks.

:func:`split_reply` takes one chunk of bytes through a prompt. Bytes before our echo
(line noise, NUL bytes a unit sends at power-up) are skipped; a chunk without our echo
answers some other request (a late reply after a timeout) and is reported as not ours.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from drivers.errors import ProtocolError

__all__ = [
    "COMMAND_ERRORS",
    "PROMPT",
    "TERMINATOR",
    "CommandErrorReply",
    "Reply",
    "format_request",
    "looks_like_reply",
    "parse_flag",
    "parse_int",
    "split_reply",
]

TERMINATOR = b"\r"
PROMPT = b"> "
ERROR_PREFIX = "Command error"

#: Error codes the units send after ``Command error`` (texts as matched by Odemis,
#: InstrumentKit and the acq4 FW102C driver; the manuals do not list them).
COMMAND_ERRORS: dict[str, str] = {
    "CMD_NOT_DEFINED": "unknown command or malformed request",
    "CMD_ARG_INVALID": "argument invalid or out of range",
}

_KEYWORD_RE = re.compile(r"\*?[a-z][a-z0-9]*")
#: Any plausible complete answer: printable echo, CR, printable lines, prompt.
_ANY_REPLY_RE = re.compile(rb"[\x20-\x7e]*\r[\x20-\x7e\r\n]*> ")
_INT_RE = re.compile(r"[+-]?\d{1,9}", re.ASCII)


def format_request(keyword: str, value: int | None = None, *, query: bool = False) -> bytes:
    """Bytes of one request, terminator included.

    >>> format_request("pos", 3), format_request("pos", query=True), format_request("ens")
    (b'pos=3\\r', b'pos?\\r', b'ens\\r')
    """
    if not isinstance(keyword, str) or not _KEYWORD_RE.fullmatch(keyword):
        raise ValueError(f"keyword must be lower-case letters and digits, got {keyword!r}")
    if query and value is not None:
        raise ValueError("a query carries no value")
    if value is None:
        text = f"{keyword}?" if query else keyword
    else:
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError(f"the units take integer arguments, got {value!r}")
        text = f"{keyword}={value}"
    return text.encode("ascii") + TERMINATOR


@dataclass(frozen=True)
class CommandErrorReply:
    """A ``Command error <code>`` answer."""

    code: str
    meaning: str


@dataclass(frozen=True)
class Reply:
    """One decoded answer to our request.

    ``lines`` are the non-empty text lines between the echo and the prompt; ``skipped`` the
    bytes that came before the echo.
    """

    lines: tuple[str, ...]
    skipped: bytes = b""

    @property
    def error(self) -> CommandErrorReply | None:
        """The unit's refusal, if the answer is an error line."""
        for line in self.lines:
            if line.startswith(ERROR_PREFIX):
                code = line[len(ERROR_PREFIX):].strip()
                return CommandErrorReply(code, COMMAND_ERRORS.get(code, "undocumented error"))
        return None

    @property
    def value(self) -> str:
        """The single answer line of a query.

        Raises
        ------
        ProtocolError
            No line, or more than one.
        """
        if len(self.lines) != 1:
            raise ProtocolError(f"expected one answer line, got {list(self.lines)!r}")
        return self.lines[0]


def looks_like_reply(chunk: bytes) -> bool:
    """Whether ``chunk`` is a well-formed answer to *some* request (not line noise)."""
    return _ANY_REPLY_RE.fullmatch(chunk) is not None


def split_reply(chunk: bytes, request: bytes) -> Reply | None:
    """Decode ``chunk`` (bytes through a prompt) as the answer to ``request``.

    Returns ``None`` when the chunk carries no echo of ``request``: it answers something
    else (stale or foreign) or is noise.

    Raises
    ------
    ProtocolError
        ``chunk`` does not end with the prompt, or it carries our echo but the answer is
        not printable ASCII (a corrupted answer to our request).
    """
    if not chunk.endswith(PROMPT):
        raise ProtocolError(f"incomplete answer {chunk!r} (no '> ' prompt)")
    if not request.endswith(TERMINATOR) or len(request) < 2:
        raise ValueError(f"not a request: {request!r}")
    body = chunk[: -len(PROMPT)]
    at = body.rfind(request)
    if at < 0:
        return None
    raw = body[at + len(request):]
    if any(not (0x20 <= b < 0x7F or b in (0x0A, 0x0D)) for b in raw):
        raise ProtocolError(f"answer to {request.strip().decode()!r} carries non-ASCII bytes: "
                            f"{chunk!r}")
    lines = tuple(line.strip() for line in re.split(r"[\r\n]", raw.decode("ascii")))
    return Reply(tuple(line for line in lines if line), skipped=bytes(body[:at]))


def parse_int(text: str, low: int | None = None, high: int | None = None) -> int:
    """A decimal integer answer, optionally checked against ``[low, high]``."""
    stripped = text.strip()
    if not _INT_RE.fullmatch(stripped):
        raise ProtocolError(f"expected an integer, got {text!r}")
    value = int(stripped)
    if (low is not None and value < low) or (high is not None and value > high):
        raise ProtocolError(f"value {value} outside [{low}, {high}]")
    return value


def parse_flag(text: str) -> bool:
    """A ``0``/``1`` answer."""
    return bool(parse_int(text, 0, 1))
