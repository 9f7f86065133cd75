"""Zaber motion stages (rotary and linear) over the Zaber ASCII protocol.

Serial settings: 115200 baud, 8N1, no flow control (Zaber *ASCII Protocol Manual*; many scripts
open ``serial.Serial(port, 115200)``). The older *binary* protocol ran at 9600 baud and is
not spoken here. The message layer is :mod:`drivers.zaber_protocol`.

Sources
-------
* Zaber Technologies, *ASCII Protocol Manual* (Zaber wiki ``Manuals/ASCII_Protocol_Manual``,
  firmware 6.06 and up), "Conventions Used Throughout this Document": commands end in CR
  and/or LF, replies in CR LF, positions are in microsteps ("for devices that do not use
  stepper motors, the encoder resolution should be substituted").
* S. Hunt, *Zaber's ASCII Protocol*, zaber.com/articles/ascii-protocol (2022): reply fields
  (address, axis, ``OK``/``RJ``, ``BUSY``/``IDLE``, highest warning flag, data), axis 0 =
  the whole device, alerts off by default.
* Zaber wiki, T-Series command reference include pages "Set Target Speed / A-Series Speed
  Conversion" (speed = data / 1.6384 microsteps/s, i.e. data is microsteps per 1.6384 s)
  and "Set Acceleration / A-Series Motorized Devices" (acceleration = 10000 · data / 1.6384
  microsteps/s²), and "Set Microstep Resolution" (microsteps per full step, default 64).
  These pages describe the binary commands of firmware 6; the ASCII settings ``maxspeed``
  and ``accel`` carry the same data **[the ASCII manual's settings table could not be
  read in the stored copy; confirm on hardware: one ``set maxspeed`` and a timed move]**.
* Not confirmed against the manual (its later sections could not be read here): the
  message id and checksum details and the alert layout (Zaber's own ``zaber.serial``
  library, see :mod:`drivers.zaber_protocol`); the ``warnings`` reply layout (a count,
  then the flags); ``driver enable``/``driver disable`` and the ``FO`` flag (firmware 7.11+,
  Zaber Motion Library ``WarningFlags``: "driver disabled on startup or by command";
  firmware 7.10 and lower report ``FD``); the setting names ``system.axiscount``,
  ``deviceid``, ``system.serial``, ``version``, ``resolution``, ``limit.min``,
  ``limit.max``, ``comm.alert``, ``comm.checksum`` (Zaber's own example code and a
  published Tcl driver that reads them).

How this driver deals with the protocol
---------------------------------------
* Addressing: ``device`` is the daisy-chain address (1..99), ``axis`` the axis on it
  (1..9); device-wide settings go to axis 0. Every axis of one chain shares the port:
  axes opened with the same port string (or the same port object) share one link, one
  exchange at a time, with message ids unique on the link. The port closes with the last
  axis that uses it (ADR 0007).
* Units: positions are integer microsteps, converted with ``microstep_size`` (degrees or
  millimetres per microstep, from the product's specification). ``get resolution`` is read
  on open; when ``resolution`` (the microsteps per step that ``microstep_size`` belongs to)
  is given and the device runs another one, the microstep size is rescaled.
  Velocities: ``maxspeed`` data = units/s / microstep_size × 1.6384; accelerations:
  ``accel`` data = units/s² / microstep_size × 1.6384 / 10000.
* Message ids (on by default, 0..99 cycling) tie each reply to its command, so a late
  reply after a timeout, a neighbour's reply or an alert is skipped, never mistaken for
  ours. Without them, stale input is discarded before every command.
* Checksums (``checksum=True``): every command carries one, ``comm.checksum`` is set to 1
  on open and every reply must then carry a valid one. Without the flag, a checksum that
  arrives is still verified.
* Alerts (``alerts=True``): ``comm.alert`` is set to 1 on open; alerts (``!01 1 IDLE --``)
  are consumed while waiting for replies and kept (:attr:`ZaberAxis.alerts`). Alerts
  from a device configured by someone else are consumed the same way.
* Status: ``get pos`` (position, BUSY/IDLE), then ``warnings`` (every active flag).
  ``WR``/``WH`` → not homed; ``FO``/``FD`` → disabled; any other ``F*`` fault → a
  :class:`ZaberFault` while waiting (and motion refused until cleared); ``WL`` (unexpected
  limit trigger) → :class:`ZaberLimitTriggered`. ``enable()`` clears them
  (``warnings clear``, ``driver enable``).
* ``RJ`` replies raise :class:`ZaberRejected` (subclasses for busy, disabled driver and a
  target out of the device's limits), naming the reason.
* Only idempotent commands are retried after a timeout or a garbled reply (queries,
  settings, ``move abs``, ``stop``, ``warnings clear``, ``driver``); ``move rel`` and
  ``home`` are sent once. Every read has a deadline; lines that are not messages (line
  noise) are skipped and reported if nothing valid follows.
* Open: wait ``flush_s`` for bytes already in flight, discard stale input, check the
  device answers and has the axis, then read the resolution and (unless given) the soft
  limits ``limit.min``/``limit.max``.

Faults and what follows them
----------------------------
=========================  ===========================================================
lost or late reply         idempotent: re-sent (``retries`` times; the late reply is
                           skipped by its id); else :class:`DeviceTimeout` saying the
                           outcome is unknown
reply split in pieces      reassembled line by line
garbage before a reply     skipped up to the message start (resynchronisation)
corrupted reply            with checksums: rejected and retried; without: a reply that
                           no longer parses is retried, a changed digit is undetectable
unsolicited alert          consumed and kept (:attr:`ZaberAxis.alerts`)
link lost                  :class:`ConnectionFailed`; close and open anew
fault flag (FS, FQ ...)    :class:`ZaberFault` with the flag as ``code``; motion stopped;
                           ``enable()`` clears it, then re-home if needed
=========================  ===========================================================
"""

from __future__ import annotations

import collections
import contextlib
import math
import threading
import time
from collections.abc import Callable
from typing import TypeVar

import serial

from drivers.base import AxisKind, AxisStatus, DeviceIdentity, MotionAxis, retry_count
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
from drivers.shared_port import PortRegistry, SharedPort, port_channel, port_lock
from drivers.transport import SerialChannel
from drivers.zaber_protocol import (
    MESSAGE_ID_RANGE,
    REJECTION_REASONS,
    TERMINATOR,
    WARNING_FLAGS,
    Alert,
    Info,
    Reply,
    encode_command,
    parse_int,
    parse_warnings,
    scan_message,
)

__all__ = [
    "SPEED_PERIOD_S",
    "ZaberAxis",
    "ZaberBusy",
    "ZaberDriverDisabled",
    "ZaberFault",
    "ZaberLimitTriggered",
    "ZaberRejected",
    "ZaberTargetOutOfRange",
    "accel_from_data",
    "accel_to_data",
    "speed_from_data",
    "speed_to_data",
]

T = TypeVar("T")

#: ``maxspeed`` is in microsteps per this many seconds; ``accel`` in units of
#: 10000 / SPEED_PERIOD_S microsteps/s² (Zaber wiki A-Series conversions).
SPEED_PERIOD_S = 1.6384
_ACCEL_UNIT = 10000.0 / SPEED_PERIOD_S
_MAX_LINE = 256
_DISABLED_FLAGS = frozenset({"FO", "FD"})
_NOT_HOMED_FLAGS = frozenset({"WR", "WH"})


# --------------------------------------------------------------------------- errors


class ZaberRejected(ControllerError):
    """The device answered ``RJ``; ``code`` is the reason word (``BADDATA`` ...)."""


class ZaberBusy(ZaberRejected, StateError):
    """Rejected because the device is busy (``STATUSBUSY``, ``AGAIN``)."""


class ZaberDriverDisabled(ZaberRejected, StateError):
    """Rejected because the motor driver is disabled (``DRIVERDISABLED``)."""


class ZaberTargetOutOfRange(ZaberRejected, LimitError):
    """A move target outside the device's ``limit.min``..``limit.max`` (``BADDATA``)."""


class ZaberFault(ControllerError):
    """A fault flag is active on the axis; ``code`` is the flag (``FS``, ``FQ`` ...)."""


class ZaberLimitTriggered(ZaberFault, LimitError):
    """A limit sensor stopped the axis unexpectedly (warning flag ``WL``)."""


# --------------------------------------------------------------------------- units


def speed_to_data(units_per_s: float, microstep_size: float) -> int:
    """``maxspeed`` data for a speed in units/s (microsteps per 1.6384 s)."""
    return round(units_per_s / microstep_size * SPEED_PERIOD_S)


def speed_from_data(data: int, microstep_size: float) -> float:
    return data / SPEED_PERIOD_S * microstep_size


def accel_to_data(units_per_s2: float, microstep_size: float) -> int:
    """``accel`` data for an acceleration in units/s² (10000/1.6384 microsteps/s² each)."""
    return round(units_per_s2 / microstep_size / _ACCEL_UNIT)


def accel_from_data(data: int, microstep_size: float) -> float:
    return data * _ACCEL_UNIT * microstep_size


# --------------------------------------------------------------------------- shared link


class _Link(SharedPort):
    """One serial port shared by every axis of a daisy chain opened through it."""

    def __init__(self, key: str, channel: SerialChannel, owned: bool) -> None:
        super().__init__(key, channel, owned)
        self.next_id = MESSAGE_ID_RANGE[0]
        self.alerts: collections.deque[Alert] = collections.deque(maxlen=200)


_links: PortRegistry[_Link] = PortRegistry(_Link)


def _acquire_link(port: str | serial.SerialBase, name: str) -> tuple[_Link, bool]:
    """The link for ``port`` (shared if already open); True if it was opened just now."""
    return _links.acquire(port, name, baudrate=ZaberAxis.BAUDRATE)


def _release_link(link: _Link, *, close_port: bool = True) -> None:
    """Drop one user; the last one closes the port (unless ``close_port`` is False)."""
    _links.release(link, close_port=close_port)


# --------------------------------------------------------------------------- driver


class ZaberAxis(MotionAxis):
    """One axis of a Zaber device on an ASCII-protocol daisy chain.

    Parameters
    ----------
    port
        A device path (``/dev/ttyUSB0``), a pyserial URL (``simzaber://x``) or an open
        ``serial.SerialBase`` (used as is; the caller set its baud rate).
    name
        Role name used in every error.
    microstep_size
        Degrees (rotary) or millimetres (linear) per microstep, from the product's
        specification ("microstep size (default resolution)").
    device, axis
        Daisy-chain address 1..99 and axis number 1..9.
    kind
        :class:`AxisKind` or ``"rotary"``/``"linear"``.
    resolution
        Microsteps per step that ``microstep_size`` belongs to (usually 64). If given and
        the device reports another ``resolution``, the microstep size is rescaled.
    soft_limits
        ``(low, high)`` in axis units; ``None`` reads ``limit.min``/``limit.max``.
    position_tolerance
        See :class:`MotionAxis`; default 0.01° or 0.001 mm; at least one microstep.
    reply_timeout
        Seconds to wait for one reply line.
    retries
        Extra attempts for idempotent commands after a timeout or a garbled reply.
    checksum, alerts, message_ids
        Protocol options (see the module docstring).
    flush_s
        Seconds to let bytes already in flight arrive before stale input is discarded
        on open.

    Raises
    ------
    ConnectionFailed
        The port cannot be opened, no device answers at ``device``, or it has no ``axis``.
    """

    BAUDRATE = 115200

    def __init__(
        self,
        port: str | serial.SerialBase,
        *,
        name: str,
        microstep_size: float,
        device: int = 1,
        axis: int = 1,
        kind: AxisKind | str = AxisKind.ROTARY,
        resolution: int | None = None,
        soft_limits: tuple[float, float] | None = None,
        position_tolerance: float | None = None,
        poll_interval: float = 0.01,
        reply_timeout: float = 0.5,
        retries: int = 2,
        checksum: bool = False,
        alerts: bool = False,
        message_ids: bool = True,
        flush_s: float = 0.05,
    ) -> None:
        if isinstance(kind, str):
            try:
                kind = AxisKind[kind.upper()]
            except KeyError:
                raise ValueError(f"kind must be 'rotary' or 'linear', got {kind!r}") from None
        microstep_size = float(microstep_size)
        if not (math.isfinite(microstep_size) and microstep_size > 0):
            raise ValueError(f"microstep_size must be a finite number > 0, got {microstep_size}")
        encode_command(device, axis, "")  # validates device and axis before anything opens
        if axis == 0:
            raise ValueError("axis must be 1..9 (axis 0 is the whole device)")
        if resolution is not None and (int(resolution) != resolution or resolution < 1):
            raise ValueError(f"resolution must be a positive integer, got {resolution}")
        if not reply_timeout > 0 or flush_s < 0:
            raise ValueError("reply_timeout must be > 0 and flush_s >= 0")
        retries = retry_count(retries)
        if position_tolerance is None:
            position_tolerance = 0.01 if kind is AxisKind.ROTARY else 0.001
        if position_tolerance < microstep_size:
            raise ValueError(f"position_tolerance {position_tolerance:g} is below one "
                             f"microstep ({microstep_size:g} {kind.units})")
        super().__init__(
            name, kind=kind, soft_limits=soft_limits or (-math.inf, math.inf),
            position_tolerance=position_tolerance, poll_interval=poll_interval,
        )
        self.device = device
        self.axis = axis
        self._nominal_microstep = microstep_size
        self._nominal_resolution = None if resolution is None else int(resolution)
        self.microstep_size = microstep_size
        #: Microsteps per step the device reports (``get resolution``).
        self.resolution: int | None = None
        self.reply_timeout = float(reply_timeout)
        self.retries = int(retries)
        self.checksum = bool(checksum)
        self.alerts_enabled = bool(alerts)
        self.message_ids = bool(message_ids)
        self._require_checksum = False
        #: Lines skipped while waiting for replies (stale, foreign, info, noise).
        self.skipped_lines = 0
        self._flags: tuple[str, ...] = ()
        self._link: _Link | None = None
        link, fresh = _acquire_link(port, name)
        try:
            self._link = link
            self._connect(float(flush_s) if fresh else None,
                          read_limits=soft_limits is None)
        except BaseException:
            # A failed constructor leaves nothing open that it opened itself; a port
            # object handed in stays the caller's (ADR 0002).
            self._link = None
            _release_link(link, close_port=link.owned)
            raise

    # connection ---------------------------------------------------------------
    def _connect(self, flush_s: float | None, *, read_limits: bool) -> None:
        if flush_s is not None:  # a port just opened (not one shared with another axis)
            with self._lock():
                if flush_s:
                    time.sleep(flush_s)  # let stale bytes already on their way arrive
                self._chan("open").discard_input()
        try:
            count = self._query("get system.axiscount", parse_int, axis=0)
        except (DeviceTimeout, ProtocolError) as err:
            raise ConnectionFailed(
                f"no Zaber device answers at address {self.device}", device=self.name,
                command=self._text("get system.axiscount", 0),
                hint="check the address, the cable, the baud rate (115200) and the power; "
                "the device must speak the ASCII protocol",
            ) from err
        if self.axis > count:
            raise ConnectionFailed(
                f"device {self.device} has {count} axis(es); there is no axis {self.axis}",
                device=self.name, command="open", hint="check the axis number in the profile")
        if self.checksum:
            self._command("set comm.checksum 1", axis=0)
            self._require_checksum = True
        if self.alerts_enabled:
            self._command("set comm.alert 1", axis=0)
        self.resolution = self._query("get resolution", parse_int)
        if self._nominal_resolution is not None and self.resolution != self._nominal_resolution:
            self.microstep_size = (self._nominal_microstep * self._nominal_resolution
                                   / self.resolution)
        if read_limits:
            low = self._query("get limit.min", parse_int) * self.microstep_size
            high = self._query("get limit.max", parse_int) * self.microstep_size
            self.soft_limits = (low, high)

    # wire ---------------------------------------------------------------------
    def _text(self, command: str, axis: int | None = None) -> str:
        """The command as errors name it (without message id and checksum)."""
        axis = self.axis if axis is None else axis
        return f"/{self.device} {axis} {command}".strip()

    def _chan(self, command: str) -> SerialChannel:
        return port_channel(self._link, self.name, command)

    def _lock(self) -> threading.RLock:
        return port_lock(self._link, self.name)

    def _take_id(self) -> int | None:
        if not self.message_ids or self._link is None:
            return None
        low, high = MESSAGE_ID_RANGE
        message_id = self._link.next_id
        self._link.next_id = low if message_id >= high else message_id + 1
        return message_id

    @property
    def alerts(self) -> list[Alert]:
        """Alerts received for this axis (or its whole device) on the shared link."""
        if self._link is None:
            return []
        return [a for a in self._link.alerts
                if a.device == self.device and a.axis in (0, self.axis)]

    def _send(self, command: str, axis: int) -> tuple[int | None, str]:
        """Write one command; return its message id and its text for errors."""
        text = self._text(command, axis)
        channel = self._chan(text)
        message_id = self._take_id()
        request = encode_command(self.device, axis, command, message_id=message_id,
                                 with_checksum=self.checksum)
        if message_id is None:
            channel.discard_input()  # no id to tell a stale reply from ours
        channel.write(request, command=text)
        return message_id, text

    def _read_reply(self, axis: int, message_id: int | None, text: str) -> Reply:
        """Read lines until the reply to our command arrives."""
        deadline = time.monotonic() + self.reply_timeout
        noise: list[str] = []
        while True:
            try:
                line = self._chan(text).read_line_by(TERMINATOR, deadline, command=text,
                                                     noise=noise, max_bytes=_MAX_LINE)
            except ProtocolError as err:
                raise ProtocolError(err.message, device=self.name, command=text) from err
            try:
                message = scan_message(line, require_checksum=self._require_checksum)
            except ProtocolError as err:
                self.skipped_lines += 1
                noise.append(err.message)
                continue
            if isinstance(message, Alert):
                if self._link is not None:
                    self._link.alerts.append(message)
                continue
            if isinstance(message, Info) or not self._is_ours(message, axis, message_id):
                self.skipped_lines += 1  # info text, a stale reply, a neighbour's reply
                continue
            return message

    def _is_ours(self, reply: Reply, axis: int, message_id: int | None) -> bool:
        if reply.device != self.device or reply.message_id != message_id:
            return False
        # A rejection may name axis 0 when the axis it was sent to does not exist.
        return reply.axis == axis or (reply.rejected and reply.axis == 0)

    def _exchange(self, command: str, axis: int | None, parse: Callable[[Reply], T], *,
                  retry: bool) -> T:
        """Send ``command``, read its reply, raise on ``RJ``, return ``parse(reply)``.

        Timeouts, garbled replies and replies whose data does not parse are retried
        ``retries`` times when ``retry`` (the command is idempotent).
        """
        axis = self.axis if axis is None else axis
        attempts = self.retries + 1 if retry else 1
        text = self._text(command, axis)
        last: DeviceError | None = None
        for _ in range(attempts):
            try:
                with self._lock():
                    message_id, text = self._send(command, axis)
                    reply = self._read_reply(axis, message_id, text)
                if reply.rejected:
                    raise self._rejection(reply, text)
                return parse(reply)
            except ProtocolError as err:
                last = ProtocolError(err.message, device=self.name, command=text,
                                     hint=err.hint)
            except DeviceTimeout as err:
                last = err
        assert last is not None
        raise attempts_exhausted(
            last, attempts, device=self.name, command=text,
            hint=None if retry else "the command's outcome is unknown; check status()",
        ) from last

    def _query(self, command: str, parse: Callable[[str], T], *, axis: int | None = None) -> T:
        """An idempotent ``get``: the reply's data parsed by ``parse``."""
        return self._exchange(command, axis, lambda r: _parsed(parse, r.data, command),
                              retry=True)

    def _command(self, command: str, *, axis: int | None = None, retry: bool = True) -> Reply:
        return self._exchange(command, axis, lambda r: r, retry=retry)

    def _rejection(self, reply: Reply, text: str) -> ZaberRejected:
        reason = reply.data
        meaning = REJECTION_REASONS.get(reason, "undocumented reason")
        message = f"device rejected the command: {meaning} (RJ {reason})"
        kw = {"code": reason, "device": self.name, "command": text}
        if reason in ("STATUSBUSY", "AGAIN"):
            return ZaberBusy(message, hint="wait for the motion to end, then retry", **kw)
        if reason == "DRIVERDISABLED":
            return ZaberDriverDisabled(message, hint="call enable() first", **kw)
        if reason == "BADDATA" and " move " in f" {text} ":
            return ZaberTargetOutOfRange(
                message, hint="the target is outside the device's limit.min..limit.max; "
                "check the soft limits in the bench profile", **kw)
        if reason == "BADAXIS":
            return ZaberRejected(message, hint="check the axis number", **kw)
        return ZaberRejected(message, hint="check the command and its value for this device",
                             **kw)

    # public extras ------------------------------------------------------------
    def warnings(self) -> tuple[str, ...]:
        """Every warning flag active on the axis (``WR``, ``FS`` ...)."""
        self._check_open("warnings")
        return self._query("warnings", parse_warnings)

    def clear_warnings(self) -> tuple[str, ...]:
        """``warnings clear``: clear faults and notices; return the flags that were active."""
        self._check_open("clear_warnings")
        return self._exchange("warnings clear", None,
                              lambda r: _parsed(parse_warnings, r.data, "warnings clear"),
                              retry=True)

    @property
    def position_usteps(self) -> int:
        """Position in microsteps, as the device counts."""
        self._check_open("position_usteps")
        return self._query("get pos", parse_int)

    # MotionAxis hooks ---------------------------------------------------------
    def _do_identity(self) -> DeviceIdentity:
        device_id = self._query("get deviceid", str, axis=0)
        serial_number = self._query("get system.serial", str, axis=0)
        firmware = self._query("get version", str, axis=0)
        try:
            peripheral = self._query("get peripheralid", str)
        except ZaberRejected:
            peripheral = ""  # integrated devices have no peripheral
        extra = {"device": str(self.device), "axis": str(self.axis), "deviceid": device_id,
                 "resolution": str(self.resolution),
                 "microstep_size": f"{self.microstep_size:.9g} {self.units}"}
        if peripheral:
            extra["peripheralid"] = peripheral
        model = f"device id {device_id}" + (f", peripheral id {peripheral}" if peripheral
                                            else "")
        return DeviceIdentity(vendor="Zaber", model=model, serial=serial_number,
                              firmware=firmware, extra=extra)

    def _do_status(self) -> AxisStatus:
        # Position and BUSY first, the flags second: a fault that stops the axis between
        # the two replies is then seen (moving, then faulted), never missed (flags clean,
        # then at rest short of the target).
        position, busy, top = self._exchange(
            "get pos", None,
            lambda r: (_parsed(parse_int, r.data, "get pos"), r.busy, r.warning),
            retry=True)
        flags = self._query("warnings", parse_warnings)
        if top != "--" and top not in flags:
            flags = (top, *flags)
        self._flags = flags
        active = set(flags)
        homed = not (active & _NOT_HOMED_FLAGS)
        return AxisStatus(
            position=position * self.microstep_size,
            is_moving=busy,
            is_homed=homed,
            is_enabled=not (active & _DISABLED_FLAGS),
            is_homing=busy and not homed,
            error=self._error_text(flags),
        )

    def _do_get_position(self) -> float:
        return self._query("get pos", parse_int) * self.microstep_size

    @staticmethod
    def _faults(flags: tuple[str, ...]) -> list[str]:
        return [f for f in flags if (f[0] == "F" and f not in _DISABLED_FLAGS) or f == "WL"]

    def _error_text(self, flags: tuple[str, ...]) -> str | None:
        faults = self._faults(flags)
        if not faults:
            return None
        return "; ".join(f"{WARNING_FLAGS.get(f, 'undocumented flag')} ({f})" for f in faults)

    def _raise_status_error(self, status: AxisStatus, command: str) -> None:
        faults = self._faults(self._flags)
        code = faults[0] if faults else None
        cls = ZaberLimitTriggered if code == "WL" else ZaberFault
        raise cls(status.error or "fault", code=code, device=self.name, command=command,
                  hint="enable() clears the fault (warnings clear, driver enable); "
                  "home() again if the position may have been lost")

    def _refuse_if_faulted(self, command: str) -> None:
        """Motion is not started while a fault flag from the last status is active."""
        faults = self._faults(self._flags)
        if faults:
            status = AxisStatus(0.0, False, True, True, error=self._error_text(self._flags))
            self._raise_status_error(status, command)

    def _do_enable(self) -> None:
        self._command("warnings clear")
        self._command("driver enable")
        self._flags = ()

    def _do_disable(self) -> None:
        if self._do_status().is_moving:
            self._do_stop()
            deadline = time.monotonic() + 30.0
            while self._do_status().is_moving:
                if time.monotonic() >= deadline:
                    raise DeviceTimeout("the axis did not come to rest within 30 s",
                                        device=self.name, command="disable")
                time.sleep(self.poll_interval)
        self._command("driver disable")

    def _do_home(self) -> None:
        self._refuse_if_faulted("home")
        self._command("home", retry=False)

    def _do_move_absolute(self, target: float) -> None:
        self._refuse_if_faulted("move_to")
        self._command(f"move abs {self._usteps(target)}")

    def _do_move_relative(self, delta: float, target: float) -> None:
        self._refuse_if_faulted("move_by")
        # The step in microsteps between the two quantised positions, so that rounding
        # never accumulates over many relative moves.
        step = self._usteps(target) - self._usteps(target - delta)
        self._command(f"move rel {step}", retry=False)

    def _do_stop(self) -> None:
        with contextlib.suppress(ZaberBusy, ZaberDriverDisabled):  # nothing to stop
            self._command("stop")
        self._target = None

    def _do_get_velocity(self) -> float:
        return speed_from_data(self._query("get maxspeed", parse_int), self.microstep_size)

    def _do_set_velocity(self, value: float) -> None:
        data = speed_to_data(value, self.microstep_size)
        if data < 1:
            raise ValueError(f"{self.name}: velocity {value:g} {self.units}/s is below the "
                             f"device's resolution")
        self._command(f"set maxspeed {data}")

    def _do_get_acceleration(self) -> float:
        return accel_from_data(self._query("get accel", parse_int), self.microstep_size)

    def _do_set_acceleration(self, value: float) -> None:
        data = accel_to_data(value, self.microstep_size)
        if data < 1:
            raise ValueError(f"{self.name}: acceleration {value:g} {self.units}/s² is below "
                             f"the device's resolution")
        self._command(f"set accel {data}")

    def _do_close(self) -> None:
        if self._link is not None:
            link, self._link = self._link, None
            _release_link(link)

    # helpers ------------------------------------------------------------------
    def _usteps(self, value: float) -> int:
        return round(value / self.microstep_size)


def _parsed(parse: Callable[[str], T], data: str, command: str) -> T:
    try:
        return parse(data)
    except ProtocolError as err:
        raise ProtocolError(f"reply to {command!r}: {err.message}") from err
