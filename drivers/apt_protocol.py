"""Thorlabs APT ("Kinesis") binary protocol: message ids, frames, payloads, stream parser.

Source: *Thorlabs APT Controllers Host-Controller Communications Protocol* (Issue 23, 2018;
Issue 25, 2020), cross-checked with pylablib ``kinesis.py`` and thorlabs-apt-protocol.
Everything is little-endian.

Frames
------
Every message starts with a 6-byte header.

* Short form (no data): ``<HBBBB`` = message id, param1, param2, destination, source.
* Long form (data follows): ``<HHBB`` = message id, data length, destination | 0x80,
  source, then ``length`` data bytes. Bit 7 of the destination byte flags the long form.

Addresses: the host is 0x01; a USB device (K-cubes, K10CR1) is 0x50. Channel ident in a
payload is 1 for single-channel devices.

The protocol has no checksum and no start byte, so a stream parser can only
resynchronise by plausibility: it accepts a header only if its id is one the host expects
from a device, its addresses are right and its length matches what that id carries;
otherwise it drops one byte and tries again. Garbage that happens to look like a valid
header can still swallow the bytes after it; callers recover by retrying idempotent
queries.
"""

from __future__ import annotations

import enum
import struct
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from drivers.errors import ProtocolError

__all__ = [
    "DEVICE_ADDRESSES",
    "DEVICE_TO_HOST",
    "HOST",
    "LONG_FLAG",
    "USB_DEVICE",
    "AptMessage",
    "AptUnpacker",
    "HomeParams",
    "HwInfo",
    "MessageId",
    "RichResponse",
    "StatusBits",
    "StatusUpdate",
    "VelParams",
    "decode_chan_value",
    "decode_homeparams",
    "decode_hw_info",
    "decode_payload",
    "decode_rich_response",
    "decode_status_update",
    "decode_statusbits",
    "decode_velparams",
    "encode_chan_value",
    "encode_homeparams",
    "encode_velparams",
    "message_name",
    "pack_long",
    "pack_short",
    "unpack_header",
]

HOST = 0x01
USB_DEVICE = 0x50
#: Addresses a device may send from: USB device, rack motherboard, bays 1..10.
DEVICE_ADDRESSES = frozenset({USB_DEVICE, 0x11, *range(0x21, 0x2B)})
LONG_FLAG = 0x80
HEADER_LEN = 6


class MessageId(enum.IntEnum):
    """Message ids used by a rotation/linear-stage driver (APT protocol names)."""

    HW_RESPONSE = 0x0080
    HW_RICHRESPONSE = 0x0081
    HW_REQ_INFO = 0x0005
    HW_GET_INFO = 0x0006
    HW_START_UPDATEMSGS = 0x0011
    HW_STOP_UPDATEMSGS = 0x0012
    MOD_IDENTIFY = 0x0223
    MOD_SET_CHANENABLESTATE = 0x0210
    MOD_REQ_CHANENABLESTATE = 0x0211
    MOD_GET_CHANENABLESTATE = 0x0212
    MOT_SET_POSCOUNTER = 0x0410
    MOT_REQ_POSCOUNTER = 0x0411
    MOT_GET_POSCOUNTER = 0x0412
    MOT_SET_VELPARAMS = 0x0413
    MOT_REQ_VELPARAMS = 0x0414
    MOT_GET_VELPARAMS = 0x0415
    MOT_SET_JOGPARAMS = 0x0416
    MOT_REQ_JOGPARAMS = 0x0417
    MOT_GET_JOGPARAMS = 0x0418
    MOT_REQ_STATUSBITS = 0x0429
    MOT_GET_STATUSBITS = 0x042A
    MOT_SET_HOMEPARAMS = 0x0440
    MOT_REQ_HOMEPARAMS = 0x0441
    MOT_GET_HOMEPARAMS = 0x0442
    MOT_MOVE_HOME = 0x0443
    MOT_MOVE_HOMED = 0x0444
    MOT_MOVE_RELATIVE = 0x0448
    MOT_MOVE_ABSOLUTE = 0x0453
    MOT_MOVE_VELOCITY = 0x0457
    MOT_MOVE_COMPLETED = 0x0464
    MOT_MOVE_STOP = 0x0465
    MOT_MOVE_STOPPED = 0x0466
    MOT_MOVE_JOG = 0x046A
    MOT_REQ_STATUSUPDATE = 0x0480
    MOT_GET_STATUSUPDATE = 0x0481
    MOT_REQ_DCSTATUSUPDATE = 0x0490
    MOT_GET_DCSTATUSUPDATE = 0x0491
    MOT_ACK_DCSTATUSUPDATE = 0x0492


M = MessageId

#: Messages a device sends to the host, with the data lengths each may carry
#: (0 = the short, header-only form). MOVE_COMPLETED/STOPPED come as a bare header on
#: some controllers and as a 14-byte status packet on K10CR1/KDC101.
DEVICE_TO_HOST: Mapping[int, frozenset[int]] = {
    M.HW_RESPONSE: frozenset({0}),
    M.HW_RICHRESPONSE: frozenset({68}),
    M.HW_GET_INFO: frozenset({84}),
    M.MOD_GET_CHANENABLESTATE: frozenset({0}),
    M.MOT_GET_POSCOUNTER: frozenset({6}),
    M.MOT_GET_VELPARAMS: frozenset({14}),
    M.MOT_GET_JOGPARAMS: frozenset({22}),
    M.MOT_GET_STATUSBITS: frozenset({6}),
    M.MOT_GET_HOMEPARAMS: frozenset({14}),
    M.MOT_MOVE_HOMED: frozenset({0}),
    M.MOT_MOVE_COMPLETED: frozenset({0, 14}),
    M.MOT_MOVE_STOPPED: frozenset({0, 14}),
    M.MOT_GET_STATUSUPDATE: frozenset({14}),
    M.MOT_GET_DCSTATUSUPDATE: frozenset({14}),
}


class StatusBits(enum.IntFlag):
    """The 32-bit motor status word (names after the APT manual, as PnPQ uses them).

    Sources disagree on which hardware limit is "forward" (pylablib calls bit 0 the
    backward limit); here bit 0 (CW) is the forward limit and bit 1 (CCW) the reverse,
    matching the manual's CW/CCW naming and the forward = CW convention of the home
    parameters.
    """

    CW_HARD_LIMIT = 0x1
    CCW_HARD_LIMIT = 0x2
    CW_SOFT_LIMIT = 0x4
    CCW_SOFT_LIMIT = 0x8
    IN_MOTION_CW = 0x10
    IN_MOTION_CCW = 0x20
    JOGGING_CW = 0x40
    JOGGING_CCW = 0x80
    CONNECTED = 0x100
    HOMING = 0x200
    HOMED = 0x400
    INITIALISING = 0x800
    TRACKING = 0x1000
    SETTLED = 0x2000
    MOTION_ERROR = 0x4000
    INSTRUMENT_ERROR = 0x8000
    INTERLOCK = 0x10000
    OVERTEMP = 0x20000
    BUS_VOLTAGE_FAULT = 0x40000
    COMMUTATION_ERROR = 0x80000
    CURRENT_LIMIT = 0x1000000
    ENCODER_FAULT = 0x2000000
    OVERCURRENT = 0x4000000
    CURRENT_SUPPLY_FAULT = 0x8000000
    POWER_OK = 0x10000000
    ACTIVE = 0x20000000
    ERROR = 0x40000000
    ENABLED = 0x80000000

    @classmethod
    def moving_mask(cls) -> StatusBits:
        return cls.IN_MOTION_CW | cls.IN_MOTION_CCW | cls.JOGGING_CW | cls.JOGGING_CCW

    @classmethod
    def error_mask(cls) -> StatusBits:
        return (cls.MOTION_ERROR | cls.INSTRUMENT_ERROR | cls.OVERTEMP
                | cls.BUS_VOLTAGE_FAULT | cls.COMMUTATION_ERROR | cls.CURRENT_LIMIT
                | cls.ENCODER_FAULT | cls.OVERCURRENT | cls.CURRENT_SUPPLY_FAULT | cls.ERROR)


def message_name(msg_id: int) -> str:
    try:
        return MessageId(msg_id).name
    except ValueError:
        return f"0x{msg_id:04X}"


# --------------------------------------------------------------------------- frames


@dataclass(frozen=True)
class AptMessage:
    """One decoded frame. ``data`` is ``None`` for the short form."""

    msg_id: int
    dest: int
    source: int
    param1: int = 0
    param2: int = 0
    data: bytes | None = None

    @property
    def name(self) -> str:
        return message_name(self.msg_id)

    @property
    def is_long(self) -> bool:
        return self.data is not None

    def pack(self) -> bytes:
        if self.data is None:
            return pack_short(self.msg_id, self.param1, self.param2,
                              dest=self.dest, source=self.source)
        return pack_long(self.msg_id, self.data, dest=self.dest, source=self.source)


def pack_short(msg_id: int, param1: int = 0, param2: int = 0, *,
               dest: int = USB_DEVICE, source: int = HOST) -> bytes:
    """Header-only message: ``<HBBBB`` (id, param1, param2, dest, source)."""
    return struct.pack("<HBBBB", msg_id, param1 & 0xFF, param2 & 0xFF, dest, source)


def pack_long(msg_id: int, data: bytes, *, dest: int = USB_DEVICE,
              source: int = HOST) -> bytes:
    """Header plus data: ``<HHBB`` (id, len, dest | 0x80, source) + data."""
    if len(data) > 0xFFFF:
        raise ValueError("APT data packet too long")
    return struct.pack("<HHBB", msg_id, len(data), dest | LONG_FLAG, source) + bytes(data)


def unpack_header(header: bytes) -> tuple[int, int, int, int, int, bool]:
    """Split a 6-byte header into (id, a, b, dest, source, long).

    For the short form ``a, b`` are param1 and param2; for the long form ``a`` is the
    data length and ``b`` is 0. ``dest`` is returned without the long-form flag.
    """
    if len(header) != HEADER_LEN:
        raise ProtocolError(f"an APT header has 6 bytes, got {len(header)}")
    msg_id, p1, p2, dest, source = struct.unpack("<HBBBB", header)
    if dest & LONG_FLAG:
        (length,) = struct.unpack_from("<H", header, 2)
        return msg_id, length, 0, dest & ~LONG_FLAG, source, True
    return msg_id, p1, p2, dest, source, False


class AptUnpacker:
    """Streaming frame decoder that resynchronises on garbage.

    Feed it bytes as they arrive; complete frames come out of :meth:`pop` (or by
    iterating) in order. A header is accepted only if its id is in ``expected``, its
    form/length is one that id carries, its destination is ``dest`` and its source is in
    ``sources``; otherwise the first byte is discarded and decoding retried, so a valid
    frame after garbage is still found.

    Parameters
    ----------
    expected
        Message id → allowed data lengths (0 = short form).
    dest
        Our address (0x01 for the host).
    sources
        Addresses frames may come from.
    max_garbage
        Raise :class:`ProtocolError` once this many bytes in a row could not be decoded
        (a wrong baud rate or a different device on the port); the count then restarts.
    """

    def __init__(
        self,
        *,
        expected: Mapping[int, frozenset[int]] = DEVICE_TO_HOST,
        dest: int = HOST,
        sources: Iterable[int] = DEVICE_ADDRESSES,
        max_garbage: int = 4096,
    ) -> None:
        self._expected = dict(expected)
        self._dest = dest
        self._sources = frozenset(sources)
        self._max_garbage = max_garbage
        self._buf = bytearray()
        self._out: deque[AptMessage] = deque()
        self._run = 0  # consecutive bytes discarded
        #: Total bytes discarded while resynchronising.
        self.discarded = 0

    def feed(self, data: bytes) -> None:
        """Add bytes; decode every complete frame.

        Raises
        ------
        ProtocolError
            More than ``max_garbage`` consecutive bytes were not a frame. Frames decoded
            before (and after) the garbage in ``data`` are still available.
        """
        self._buf += data
        too_much = False
        while len(self._buf) >= HEADER_LEN:
            length = self._frame_length(self._buf)
            if length is None:
                del self._buf[0]
                self.discarded += 1
                self._run += 1
                if self._run > self._max_garbage:
                    too_much = True
                    self._run = 0
                continue
            if len(self._buf) < length:
                break  # wait for the rest of the data packet
            frame = bytes(self._buf[:length])
            del self._buf[:length]
            self._run = 0
            self._out.append(self._decode(frame))
        if too_much:
            raise ProtocolError(
                f"more than {self._max_garbage} bytes without a valid APT frame",
                hint="check the baud rate (115200) and that this is a Thorlabs APT device",
            )

    def _frame_length(self, buf: bytearray) -> int | None:
        msg_id, a, _b, dest, source, long = unpack_header(bytes(buf[:HEADER_LEN]))
        allowed = self._expected.get(msg_id)
        if allowed is None or dest != self._dest or source not in self._sources:
            return None
        if long:
            return HEADER_LEN + a if a in allowed and a > 0 else None
        return HEADER_LEN if 0 in allowed else None

    @staticmethod
    def _decode(frame: bytes) -> AptMessage:
        msg_id, a, b, dest, source, long = unpack_header(frame[:HEADER_LEN])
        if long:
            return AptMessage(msg_id, dest, source, data=frame[HEADER_LEN:])
        return AptMessage(msg_id, dest, source, param1=a, param2=b)

    def pop(self) -> AptMessage | None:
        """The oldest decoded frame, or ``None``."""
        return self._out.popleft() if self._out else None

    def __iter__(self) -> Iterator[AptMessage]:
        while self._out:
            yield self._out.popleft()

    @property
    def pending_bytes(self) -> int:
        """Bytes held back as a possibly incomplete frame."""
        return len(self._buf)

    def clear(self) -> None:
        self._buf.clear()
        self._out.clear()
        self._run = 0


# --------------------------------------------------------------------------- payloads


def _unpack(fmt: str, msg: AptMessage | bytes, what: str) -> tuple[Any, ...]:
    data = msg.data if isinstance(msg, AptMessage) else msg
    if data is None:
        raise ProtocolError(f"{what}: expected a data packet, got a header-only message")
    size = struct.calcsize(fmt)
    if len(data) != size:
        raise ProtocolError(f"{what}: expected {size} data bytes, got {len(data)}")
    return struct.unpack(fmt, data)


@dataclass(frozen=True)
class HwInfo:
    """HW_GET_INFO payload (84 bytes, ``<l8sH4s48s12sHHH``)."""

    serial: int
    model: str
    hw_type: int
    firmware: tuple[int, int, int]  # (major, interim, minor)
    notes: str
    stage_id: int  # bytes 76..77 (KDC101 stage autodetection; 0 if none)
    hw_version: int
    mod_state: int
    n_channels: int

    @property
    def firmware_str(self) -> str:
        return ".".join(str(v) for v in self.firmware)


def _cstr(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("ascii", errors="replace").strip()


def decode_hw_info(msg: AptMessage | bytes) -> HwInfo:
    serial, model, hw_type, fw, notes, space, hw_ver, mod_state, nchan = _unpack(
        "<l8sH4s48s12sHHH", msg, "HW_GET_INFO")
    # Firmware bytes are stored minor, interim, major, unused.
    (stage_id,) = struct.unpack_from("<H", space, 10)
    return HwInfo(serial, _cstr(model), hw_type, (fw[2], fw[1], fw[0]), _cstr(notes),
                  stage_id, hw_ver, mod_state, nchan)


def decode_chan_value(msg: AptMessage | bytes, what: str = "payload") -> tuple[int, int]:
    """``<Hi`` (channel, signed value): POSCOUNTER, MOVE_ABSOLUTE, MOVE_RELATIVE."""
    return _unpack("<Hi", msg, what)


def encode_chan_value(chan: int, value: int) -> bytes:
    return struct.pack("<Hi", chan, value)


def decode_statusbits(msg: AptMessage | bytes) -> tuple[int, int]:
    """``<HL`` (channel, status bits)."""
    return _unpack("<HL", msg, "MOT_GET_STATUSBITS")


@dataclass(frozen=True)
class VelParams:
    """Velocity parameters in device units (``<Hiii``: chan, min vel, accel, max vel)."""

    chan: int
    min_velocity: int
    acceleration: int
    max_velocity: int


def decode_velparams(msg: AptMessage | bytes) -> VelParams:
    return VelParams(*_unpack("<Hiii", msg, "MOT_GET_VELPARAMS"))


def encode_velparams(p: VelParams) -> bytes:
    return struct.pack("<Hiii", p.chan, p.min_velocity, p.acceleration, p.max_velocity)


@dataclass(frozen=True)
class HomeParams:
    """Home parameters (``<HHHii``).

    ``direction`` 1 forward / 2 reverse; ``limit_switch`` 1 reverse / 4 forward;
    ``velocity`` in device velocity units; ``offset`` in counts.
    """

    chan: int
    direction: int
    limit_switch: int
    velocity: int
    offset: int


def decode_homeparams(msg: AptMessage | bytes) -> HomeParams:
    return HomeParams(*_unpack("<HHHii", msg, "MOT_GET_HOMEPARAMS"))


def encode_homeparams(p: HomeParams) -> bytes:
    return struct.pack("<HHHii", p.chan, p.direction, p.limit_switch, p.velocity, p.offset)


@dataclass(frozen=True)
class StatusUpdate:
    """Position and status from a status packet (counts and raw status bits)."""

    chan: int
    position: int
    status: int


def decode_status_update(msg: AptMessage) -> StatusUpdate:
    """Decode GET_STATUSUPDATE (``<HllL``), GET_DCSTATUSUPDATE and the 14-byte
    MOVE_COMPLETED/MOVE_STOPPED form (``<HlhHL``: chan, position, velocity, reserved,
    status)."""
    if msg.msg_id == M.MOT_GET_STATUSUPDATE:
        chan, pos, _enc, status = _unpack("<HllL", msg, msg.name)
    else:
        chan, pos, _vel, _res, status = _unpack("<HlhHL", msg, msg.name)
    return StatusUpdate(chan, pos, status)


@dataclass(frozen=True)
class RichResponse:
    """HW_RICHRESPONSE payload (``<HH64s``): the message it concerns, code, notes."""

    msg_id: int
    code: int
    notes: str


def decode_rich_response(msg: AptMessage) -> RichResponse:
    msg_id, code, notes = _unpack("<HH64s", msg, "HW_RICHRESPONSE")
    return RichResponse(msg_id, code, _cstr(notes))


_DECODERS: dict[int, Callable[[AptMessage], object]] = {
    M.HW_GET_INFO: decode_hw_info,
    M.HW_RICHRESPONSE: decode_rich_response,
    M.MOT_GET_POSCOUNTER: lambda m: decode_chan_value(m, "MOT_GET_POSCOUNTER"),
    M.MOT_GET_VELPARAMS: decode_velparams,
    M.MOT_GET_HOMEPARAMS: decode_homeparams,
    M.MOT_GET_STATUSBITS: decode_statusbits,
    M.MOT_GET_STATUSUPDATE: decode_status_update,
    M.MOT_GET_DCSTATUSUPDATE: decode_status_update,
}


def decode_payload(msg: AptMessage) -> object:
    """Decode the data packet of any device-to-host message this module knows.

    Returns the payload object (``None`` for header-only messages and for ids whose data
    is not interpreted); raises :class:`ProtocolError` if the data does not fit.
    """
    if msg.msg_id in (M.MOT_MOVE_COMPLETED, M.MOT_MOVE_STOPPED):
        return None if msg.data is None else decode_status_update(msg)
    decoder = _DECODERS.get(msg.msg_id)
    if decoder is None:
        return None
    return decoder(msg)
