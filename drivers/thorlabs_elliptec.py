"""Thorlabs Elliptec ELL14 rotation mounts (and other ELLx rotation modules) on one bus.

Serial settings: 9600 baud, 8N1, no handshake. The message layer is
:mod:`drivers.elliptec_protocol` (with its sources: the *ELLx modules protocol manual*).

How this driver deals with the protocol
---------------------------------------
* **One bus, several mounts.** Up to sixteen modules (addresses ``0``-``F``) share one
  serial line (an interface board, or the ELLB distribution bus). Every mount opened with
  the same port string (or port object) shares one port, one lock (one exchange at a time)
  and a mailbox per address: a reply read while waiting for another address's is kept for
  it, never dropped. The port closes with the last mount (ADR 0100).
* **Units.** Positions are encoder pulses; the degrees per pulse come from the module's
  own ``in`` reply (ELL14: 360° per 143360 pulses), read on open. A module whose travel is
  not 360 is refused (this is a rotation-mount driver).
* **Moves are non-blocking.** ``ma``/``mr``/``ho`` are sent and not waited for: the module
  answers them when the motion ends (``PO`` with the final position, or ``GS`` with the
  reason it failed). Meanwhile ``gs`` answers ``GS09`` (busy) and ``gp`` the position.
  The driver counts the motion replies it owes itself: a ``PO`` it meets while waiting for
  another reply is that motion's and is skipped; a ``GS`` other than ok/busy met while a
  motion reply is owed is the motion's failure and is latched as the mount's fault.
* **Status codes.** ``GS`` codes other than 0 (ok) and 9 (busy) raise
  :class:`ElliptecError` (``code`` = the number; the message names the address and the
  manual's meaning). A fault met during a motion is kept: :meth:`status` reports it, a
  :meth:`wait` raises it (the base class stops the mount first) and motion is refused
  until :meth:`enable` clears it.
* **What the module does not have**, done on the host: a homed flag (the mount is homed
  once :meth:`home` has completed in this session, or with ``assume_homed``), an enable
  state (:meth:`disable` stops the mount and refuses motion until :meth:`enable`) and an
  acceleration setting (reading it gives ``nominal_acceleration``, for move-time
  estimates; setting it raises :class:`~drivers.errors.UnsupportedFeature`).
* **Velocity**: ``sv``/``gv`` take a percentage of the module's maximum speed
  (``max_velocity``, 430°/s for the ELL14 per its specification sheet).
* **Stop**: ``st`` ends any motion at once **[the manual documents it for continuous
  jogging; that it also ends a move is assumed]**.
* **Bus time.** At 9600 baud (10 bits a byte) one status poll (``gs`` 3 bytes, ``GS``
  reply 7, ``gp`` 3, ``PO`` reply 13) is 26 bytes, 27 ms on the wire: a bus of four mounts
  polled in turn cannot report faster than about 9 rounds a second, whatever
  ``poll_interval`` says.
* Only idempotent commands are retried after a timeout or a garbled reply (queries,
  ``sv``, ``st``); ``ma``, ``mr`` and ``ho`` are written once and never read back
  synchronously. Every read has a deadline.

Faults and what follows them
----------------------------
=========================  ===========================================================
lost or late reply         queries re-sent ``retries`` times, then :class:`DeviceTimeout`
reply split in pieces      reassembled line by line
garbage before a reply     skipped up to the reply's start (resynchronisation)
another address's reply    kept in that address's mailbox on the bus
motion fails (``GS02`` …)  :class:`ElliptecError` from :meth:`wait`; ``enable()`` clears
link lost                  :class:`ConnectionFailed`; close and open anew
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

from drivers.base import (
    AxisKind,
    AxisStatus,
    DeviceIdentity,
    MotionAxis,
    check_settings,
    retry_count,
)
from drivers.elliptec_protocol import (
    BAUDRATE,
    STATUS_BUSY,
    STATUS_OK,
    TERMINATOR,
    Info,
    Reply,
    encode_command,
    parse_info,
    parse_position,
    parse_status,
    parse_velocity,
    pulses_to_hex,
    scan_reply,
    status_text,
)
from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceError,
    DeviceTimeout,
    LimitError,
    ProtocolError,
    StateError,
    UnsupportedFeature,
    attempts_exhausted,
)
from drivers.shared_port import PortRegistry, SharedPort, port_channel, port_lock
from drivers.transport import SerialChannel

__all__ = ["ElliptecBusy", "ElliptecError", "ElliptecMount", "ElliptecOutOfRange"]

T = TypeVar("T")

_MAX_LINE = 128
_MAILBOX = 64
#: Motion commands: answered when the motion ends, not when they are taken.
_MOTION = ("ma", "mr", "ho")


class ElliptecError(ControllerError):
    """A module answered a ``GS`` status other than ok/busy; ``code`` is the number."""


class ElliptecOutOfRange(ElliptecError, LimitError):
    """Status 4 (value out of range) or 12 (out of range)."""


class ElliptecBusy(ElliptecError, StateError):
    """Status 9: the module is busy and did not take the command."""


def status_error(code: int, address: str, *, device: str, command: str,
                 hint: str | None = None) -> ElliptecError:
    """The typed error for ``GS`` ``code`` of the module at ``address``."""
    message = f"module at address {address}: {status_text(code)} (GS{code:02X})"
    if code in (4, 12):
        return ElliptecOutOfRange(message, code=code, device=device, command=command,
                                  hint="choose a value inside the module's range")
    if code == STATUS_BUSY:
        return ElliptecBusy(message, code=code, device=device, command=command,
                            hint="wait for the motion to end, then retry")
    hints = {1: "check the cable; a command arrived incomplete",
             2: "the mount is blocked or overloaded; free it, enable() and home() again",
             3: "the module does not take this command",
             7: "power-cycle the module", 8: "let the module cool down",
             10: "the position sensor failed; home() again or service the mount",
             11: "the motor failed; power-cycle the module",
             13: "the motor drew too much current; check for obstruction"}
    return ElliptecError(message, code=code, device=device, command=command,
                         hint=hint or hints.get(code,
                                                "check the module; enable() clears the fault"))


class _Bus(SharedPort):
    """One serial line and the replies read on it for each address."""

    def __init__(self, key: str, channel: SerialChannel, owned: bool) -> None:
        super().__init__(key, channel, owned)
        self.mailbox: dict[str, collections.deque[Reply]] = collections.defaultdict(
            lambda: collections.deque(maxlen=_MAILBOX))


_buses: PortRegistry[_Bus] = PortRegistry(_Bus)


class ElliptecMount(MotionAxis):
    """One Elliptec rotation mount (ELL14, ELL18) at ``address`` on a shared bus.

    Parameters
    ----------
    port
        A device path, a pyserial URL (``simell://bus``) or an open ``serial.SerialBase``.
    name
        Role name used in every error.
    address
        The module's bus address, one character ``0``-``9``/``A``-``F``.
    soft_limits
        ``(low, high)`` in degrees; default: the 32-bit pulse counter's range.
    position_tolerance
        Degrees a finished move may miss its target by; default 0.05°.
    reply_timeout
        Seconds to wait for one reply line.
    retries
        Extra attempts for idempotent commands after a timeout or a garbled reply.
    max_velocity
        Degrees/s at 100 % velocity (the ELL14's 430°/s by default).
    nominal_acceleration
        Degrees/s² reported by :attr:`acceleration` (the module has no such setting).
    home_direction
        ``"cw"`` or ``"ccw"``: the direction ``ho`` searches the index in.
    assume_homed
        Treat the mount as homed from the start (its counter already references the optic).
    flush_s
        Seconds to let bytes already in flight arrive before stale input is discarded on a
        freshly opened port.

    Raises
    ------
    ConnectionFailed
        The port cannot be opened, no module answers at ``address``, or it is not a
        rotation mount.
    """

    BAUDRATE = BAUDRATE

    def __init__(
        self,
        port: str | serial.SerialBase,
        *,
        name: str,
        address: str = "0",
        soft_limits: tuple[float, float] | None = None,
        position_tolerance: float = 0.05,
        poll_interval: float = 0.01,
        reply_timeout: float = 0.5,
        retries: int = 2,
        max_velocity: float = 430.0,
        nominal_acceleration: float = 5000.0,
        home_direction: str = "cw",
        assume_homed: bool = False,
        flush_s: float = 0.05,
    ) -> None:
        address = str(address).upper()
        encode_command(address, "gs")  # validates the address before anything opens
        if home_direction not in ("cw", "ccw"):
            raise ValueError(f"home_direction must be 'cw' or 'ccw', got {home_direction!r}")
        check_settings(reply_timeout=reply_timeout, max_velocity=max_velocity,
                       nominal_acceleration=nominal_acceleration)
        retries = retry_count(retries)
        if flush_s < 0:
            raise ValueError(f"flush_s must be >= 0, got {flush_s}")
        super().__init__(name, kind=AxisKind.ROTARY,
                         soft_limits=soft_limits or (-math.inf, math.inf),
                         position_tolerance=position_tolerance, poll_interval=poll_interval)
        self.address = address
        self.reply_timeout = float(reply_timeout)
        self.retries = int(retries)
        self.max_velocity = float(max_velocity)
        self.nominal_acceleration = float(nominal_acceleration)
        self.home_direction = home_direction
        #: Lines skipped while waiting for replies (stale motion replies, noise).
        self.skipped_lines = 0
        self.info: Info | None = None
        self.degrees_per_pulse = 0.0
        self._homed = bool(assume_homed)
        self._homing = False
        self._enabled = True
        self._fault: int | None = None
        self._owed = 0  # motion replies not yet received
        self._bus: _Bus | None = None
        bus, fresh = _buses.acquire(port, name, baudrate=self.BAUDRATE)
        try:
            self._bus = bus
            self._connect(float(flush_s) if fresh else None, soft_limits is None)
        except BaseException:
            # A failed constructor leaves nothing open that it opened itself; a port
            # object handed in stays the caller's (ADR 0002).
            self._bus = None
            _buses.release(bus, close_port=bus.owned)
            raise

    # connection ---------------------------------------------------------------
    def _connect(self, flush_s: float | None, default_limits: bool) -> None:
        if flush_s is not None:  # a port just opened, not one shared with another mount
            with self._lock():
                if flush_s:
                    time.sleep(flush_s)  # let stale bytes already on their way arrive
                self._chan("open").discard_input()
        try:
            info = self._query("in", "IN", parse_info)
        except (DeviceTimeout, ProtocolError) as err:
            raise ConnectionFailed(
                f"no Elliptec module answers at address {self.address}", device=self.name,
                command=self._text("in"),
                hint="check the address (0-F), the cable, the baud rate (9600) and the power",
            ) from err
        if not info.is_rotary:
            raise ConnectionFailed(
                f"the module at address {self.address} (type {info.module_type}, travel "
                f"{info.travel}) is not a rotation mount", device=self.name, command="open",
                hint="this driver drives rotation mounts such as the ELL14")
        self.info = info
        self.degrees_per_pulse = info.degrees_per_pulse
        if self.position_tolerance < self.degrees_per_pulse:
            raise ConnectionFailed(
                f"position_tolerance {self.position_tolerance:g}° is below one pulse "
                f"({self.degrees_per_pulse:g}°)", device=self.name, command="open",
                hint="raise position_tolerance in the bench profile")
        if default_limits:
            self.soft_limits = (-(2**31) * self.degrees_per_pulse,
                                (2**31 - 1) * self.degrees_per_pulse)

    # wire ---------------------------------------------------------------------
    def _text(self, command: str, data: str = "") -> str:
        """The command as errors name it (the packet itself)."""
        return f"{self.address}{command}{data}"

    def _chan(self, command: str) -> SerialChannel:
        return port_channel(self._bus, self.name, command)

    def _lock(self) -> threading.RLock:
        return port_lock(self._bus, self.name)

    def _drain(self, text: str) -> None:
        """Before a command: sort what has arrived by now. Other addresses' replies go to
        their mailboxes; ours can only be stale (a late answer to a retried query) or the
        reply of a motion, and are settled here, so the command's answer is the next."""
        assert self._bus is not None
        for line in self._chan(text).read_lines_available(TERMINATOR, command=text):
            try:
                reply = scan_reply(line)
            except ProtocolError:
                self.skipped_lines += 1
                continue
            self._bus.mailbox[reply.address].append(reply)
        box = self._bus.mailbox[self.address]
        while box:
            reply = box.popleft()
            self.skipped_lines += 1
            if reply.code == "PO":
                self._owed = max(self._owed - 1, 0)
            elif reply.code == "GS":
                with contextlib.suppress(ProtocolError):
                    code = parse_status(reply.data)
                    if code not in (STATUS_OK, STATUS_BUSY, 1):
                        self._owed = max(self._owed - 1, 0)
                        self._fault = code

    def _next_reply(self, text: str, deadline: float, noise: list[str]) -> Reply:
        """The next reply for this address: from its mailbox, else from the wire."""
        assert self._bus is not None
        box = self._bus.mailbox[self.address]
        while not box:
            line = self._chan(text).read_line_by(TERMINATOR, deadline, command=text,
                                                 noise=noise, max_bytes=_MAX_LINE)
            try:
                reply = scan_reply(line)
            except ProtocolError as err:
                self.skipped_lines += 1
                noise.append(err.message)
                continue
            self._bus.mailbox[reply.address].append(reply)
        return box.popleft()

    def _read_reply(self, expect: str, text: str) -> Reply:
        """Read until the reply ``expect`` (``"GS"``, ``"PO"`` ...) to our command arrives.

        Motion replies owed to earlier moves are absorbed on the way (see the module
        docstring); a ``GS`` with a fault when another reply was expected is returned, for
        the caller to raise.
        """
        deadline = time.monotonic() + self.reply_timeout
        noise: list[str] = []
        while True:
            reply = self._next_reply(text, deadline, noise)
            if reply.code == "PO" and expect != "PO":
                self._owed = max(self._owed - 1, 0)  # a motion's end (or a stale reply)
                self.skipped_lines += 1
                continue
            if reply.code == "GS":
                try:
                    code = parse_status(reply.data)
                except ProtocolError as err:
                    noise.append(err.message)
                    self.skipped_lines += 1
                    continue
                if code not in (STATUS_OK, STATUS_BUSY) and self._owed:
                    self._owed -= 1  # the failure reply of a motion
                    self._fault = code
                    continue
                if expect == "GS" or code not in (STATUS_OK, STATUS_BUSY):
                    return reply
                self.skipped_lines += 1  # a stale ok/busy
                continue
            if reply.code == expect:
                return reply
            self.skipped_lines += 1

    def _exchange(self, command: str, data: str, expect: str, *, retry: bool) -> Reply:
        """Send one packet and return its reply; retried when ``retry`` (idempotent)."""
        text = self._text(command, data)
        packet = encode_command(self.address, command, data)
        attempts = self.retries + 1 if retry else 1
        last: DeviceError | None = None
        for _ in range(attempts):
            try:
                with self._lock():
                    self._drain(text)
                    self._chan(text).write(packet, command=text)
                    reply = self._read_reply(expect, text)
            except ProtocolError as err:
                last = ProtocolError(err.message, device=self.name, command=text,
                                     hint=err.hint)
                continue
            except DeviceTimeout as err:
                last = err
                continue
            if reply.code == "GS" and expect != "GS":
                raise status_error(parse_status(reply.data), self.address, device=self.name,
                                   command=text)
            return reply
        assert last is not None
        raise attempts_exhausted(last, attempts, device=self.name, command=text) from last

    def _query(self, command: str, expect: str, parse: Callable[[str], T],
               data: str = "") -> T:
        """An idempotent exchange whose reply data is decoded by ``parse``."""
        reply = self._exchange(command, data, expect, retry=True)
        try:
            return parse(reply.data)
        except ProtocolError as err:
            raise ProtocolError(f"reply to {self._text(command, data)!r}: {err.message}",
                                device=self.name, command=self._text(command, data)) from err

    def _status_code(self, command: str, data: str = "") -> int:
        """Send an idempotent command answered by ``GS``; return its status code."""
        return self._query(command, "GS", parse_status, data)

    def _start_motion(self, command: str, data: str) -> None:
        """Write a motion command once; its reply comes when the motion ends."""
        text = self._text(command, data)
        with self._lock():
            self._drain(text)
            self._chan(text).write(encode_command(self.address, command, data), command=text)
            self._owed += 1

    def _check(self, code: int, command: str) -> None:
        """A setting's ``GS`` answer: anything but ok (busy included) refused it."""
        if code != STATUS_OK:
            raise status_error(code, self.address, device=self.name, command=command)

    # public extras ------------------------------------------------------------
    @property
    def position_pulses(self) -> int:
        """Position in encoder pulses, as the module counts."""
        self._check_open("position_pulses")
        return self._query("gp", "PO", parse_position)

    @property
    def jog_step(self) -> float:
        """The jog step in degrees (``gj``): what :meth:`jog` moves by."""
        self._check_open("jog_step")
        return self._query("gj", "GJ", parse_position) * self.degrees_per_pulse

    @jog_step.setter
    def jog_step(self, degrees: float) -> None:
        self._check_open("set jog_step")
        degrees = float(degrees)
        if not (math.isfinite(degrees) and degrees > 0):
            raise ValueError(f"{self.name}: a jog step must be a finite number > 0 degrees, "
                             f"got {degrees}")
        data = pulses_to_hex(self._pulses(degrees))
        self._check(self._status_code("sj", data), self._text("sj", data))

    def jog(self, forward: bool = True, *, wait: bool = False, timeout: float = 60.0) -> None:
        """Move one jog step forward (``fw``) or backward (``bw``): a relative move whose
        size the module holds, e.g. to step a waveplate by a fixed angle with one byte
        triple per step. The target is forgotten (a later :meth:`wait` checks no arrival)."""
        self._check_open("jog")
        self._require_ready("jog")
        self._refuse_if_faulted("jog")
        self._target = None
        self._start_motion("fw" if forward else "bw", "")
        if wait:
            self.wait(timeout)

    @property
    def fault(self) -> int | None:
        """The status code of the last fault met (``None``: no fault); cleared by enable()."""
        return self._fault

    # MotionAxis hooks ---------------------------------------------------------
    def _do_identity(self) -> DeviceIdentity:
        info = self.info
        assert info is not None
        return DeviceIdentity(
            vendor="Thorlabs", model=f"ELL{info.module_type}", serial=info.serial,
            firmware=info.firmware,
            extra={"address": self.address, "year": info.year, "hardware": info.hardware,
                   "pulses_per_revolution": str(info.pulses_per_unit),
                   "degrees_per_pulse": f"{self.degrees_per_pulse:.9g}"})

    def _do_status(self) -> AxisStatus:
        code = self._status_code("gs")
        if code not in (STATUS_OK, STATUS_BUSY, 1):  # 1: a garbled packet, not a fault
            self._fault = code
        busy = code == STATUS_BUSY
        position = self._do_get_position()
        if self._homing and not busy:
            self._homing = False
            self._homed = self._fault is None
        return AxisStatus(
            position=position, is_moving=busy, is_homed=self._homed,
            is_enabled=self._enabled, is_homing=self._homing and busy,
            error=None if self._fault is None else
            f"{status_text(self._fault)} (GS{self._fault:02X})")

    def _do_get_position(self) -> float:
        return self._query("gp", "PO", parse_position) * self.degrees_per_pulse

    def _raise_status_error(self, status: AxisStatus, command: str) -> None:
        code = self._fault if self._fault is not None else 0
        raise status_error(code, self.address, device=self.name, command=command)

    def _refuse_if_faulted(self, command: str) -> None:
        if self._fault is not None:
            raise status_error(
                self._fault, self.address, device=self.name, command=command,
                hint="enable() clears the fault; home() again if the position may be lost")

    def _do_enable(self) -> None:
        self._status_code("gs")  # reads (and so clears) a status the module still holds
        self._fault = None
        self._enabled = True

    def _do_disable(self) -> None:
        self._do_stop()
        self._enabled = False

    def _do_home(self) -> None:
        self._refuse_if_faulted("home")
        self._homing = True
        self._homed = False
        self._start_motion("ho", "0" if self.home_direction == "cw" else "1")

    def _do_move_absolute(self, target: float) -> None:
        self._refuse_if_faulted("move_to")
        self._start_motion("ma", pulses_to_hex(self._pulses(target)))

    def _do_move_relative(self, delta: float, target: float) -> None:
        self._refuse_if_faulted("move_by")
        # The step between the two quantised positions: rounding never accumulates.
        step = self._pulses(target) - self._pulses(target - delta)
        self._start_motion("mr", pulses_to_hex(step))

    def _do_stop(self) -> None:
        # Always allowed, also on a faulted mount: a fault code in the reply is kept, not
        # raised (the caller is stopping because something went wrong).
        code = self._status_code("st")
        if code not in (STATUS_OK, STATUS_BUSY, 1):
            self._fault = code
        self._homing = False

    def _do_get_velocity(self) -> float:
        return self._query("gv", "GV", parse_velocity) / 100.0 * self.max_velocity

    def _do_set_velocity(self, value: float) -> None:
        percent = round(value / self.max_velocity * 100.0)
        if not 1 <= percent <= 100:
            raise ValueError(f"{self.name}: velocity {value:g} deg/s is outside 1-100 % of "
                             f"the module's {self.max_velocity:g} deg/s")
        text = self._text("sv", f"{percent:02X}")
        self._check(self._status_code("sv", f"{percent:02X}"), text)

    def _do_get_acceleration(self) -> float:
        return self.nominal_acceleration

    def _do_set_acceleration(self, value: float) -> None:
        raise UnsupportedFeature(
            "an Elliptec module has no acceleration setting", device=self.name,
            command="set acceleration",
            hint="leave acceleration out of the bench profile for this mount")

    def _do_close(self) -> None:
        if self._bus is not None:
            bus, self._bus = self._bus, None
            _buses.release(bus)

    # helpers ------------------------------------------------------------------
    def _pulses(self, degrees: float) -> int:
        return round(degrees / self.degrees_per_pulse)
