"""Thorlabs APT motion controllers: K10CR1 rotation mount, KDC101 with PRM1-Z8 or MTS25-Z8.

Protocol facts (frames, ids, status bits, scaling, quirks) are in *Thorlabs APT Controllers
Host-Controller Communications Protocol*, Issue 23 (2018) and Issue 25 (2020) and
:mod:`drivers.apt_protocol`. Transport: FTDI USB-serial at 115200 8N1 with RTS/CTS flow
control, opened through :func:`drivers.transport.open_serial`, so a device path, a
pseudo-terminal or a ``simapt://`` URL all work.

How this driver deals with the protocol's habits
------------------------------------------------
* Open: RTS is cycled (tolerated where the port cannot, e.g. a pty), automatic status
  updates are switched off (HW_STOP_UPDATEMSGS) and stale input flushed, the identity is
  read (HW_REQ_INFO) and checked against the configured stage, the channel is enabled,
  and home and velocity parameters are written explicitly and read back: power-up values
  can be zero, and then homing never ends (pylablib docs; Thorlabs Motion_Control_Examples
  #33; PnPQ writes them on init because they are "lost on poweroff").
* Replies are matched by message id. Anything else that arrives meanwhile
  (MOVE_COMPLETED, MOVE_HOMED, MOVE_STOPPED, status updates, late replies) is consumed;
  HW_RESPONSE / HW_RICHRESPONSE error events raise :class:`ControllerError`.
* Motion is tracked by polling status (as pylablib and QMI do), not by waiting for
  MOVE_COMPLETED, which some firmware fails to send (PnPQ #104). Stepper (K10CR1):
  MOT_REQ_STATUSBITS + MOT_REQ_POSCOUNTER; DC servo (KDC101): MOT_REQ_DCSTATUSUPDATE.
* The stage may stop a few counts short of its target (PnPQ: "will sometimes stop a small
  distance away"): the base class accepts a final position within ``position_tolerance``.
* Only idempotent queries are retried (after a timeout or an undecodable reply); motion
  commands are sent once. Every read has a deadline.

Faults and what follows them
----------------------------
=========================  ===========================================================
lost or late reply         the query is re-sent (``retries`` times), a late reply is
                           consumed as stale later; then :class:`DeviceTimeout`
reply split in pieces      reassembled by the stream parser
garbage before a reply     skipped byte by byte (resynchronisation)
corrupted header           the frame is rejected, the query retried as for a lost reply
corrupted data bytes       undetectable (APT has no checksum); the next poll corrects it
unsolicited message        consumed (counted in ``unsolicited_count``)
link lost                  :class:`ConnectionFailed`; recover by closing and opening anew
no answer when opening     :class:`ConnectionFailed` (wrong port, baud rate, power),
                           chained from the timeout or protocol error
controller error           :class:`ControllerError` (HW_RESPONSE/RICHRESPONSE ``code``, or
                           the status error bits); disable/enable the axis, re-home.
                           ``stop()`` is written before any pending input is read, so
                           an error event waiting there never blocks a stop
=========================  ===========================================================
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import serial

from drivers import apt_protocol as apt
from drivers.apt_protocol import AptMessage, MessageId, StatusBits
from drivers.base import AxisKind, AxisStatus, DeviceIdentity, MotionAxis
from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceError,
    DeviceTimeout,
    LimitError,
    ProtocolError,
    StateError,
    UnsupportedFeature,
)
from drivers.transport import SerialChannel, open_serial

__all__ = ["STAGES", "AptMotor", "AptStage"]

log = logging.getLogger(__name__)

T = TypeVar("T")

_INT32 = 2**31 - 1
# KDC101 servo loop period: velocities are counts per period scaled by 2**16, and
# accelerations counts per period² scaled by 2**16 (pylablib ``_calculate_scale``).
_KDC_PERIOD_S = 2048.0 / 6.0e6


@dataclass(frozen=True)
class AptStage:
    """A controller + stage combination and its unit conversions.

    Attributes
    ----------
    counts_per_unit
        Position counts per degree or millimetre.
    velocity_scale, acceleration_scale
        Device units per unit/s and per unit/s² (MOT_SET_VELPARAMS, HOMEPARAMS).
    travel
        Mechanical travel in the stage's own frame (home switch at 0); ``None`` for
        continuous rotation.
    """

    name: str
    controller: str
    kind: AxisKind
    counts_per_unit: float
    velocity_scale: float
    acceleration_scale: float
    stepper: bool
    stage_id: int  # HW_GET_INFO stage id on a KDC101 (0 = not reported)
    travel: tuple[float, float] | None
    max_velocity: float
    velocity: float
    acceleration: float
    home_velocity: float
    position_tolerance: float


def _kdc_stage(name: str, kind: AxisKind, cpu: float, stage_id: int, **kw: Any) -> AptStage:
    return AptStage(
        name=name, controller="KDC101", kind=kind, counts_per_unit=cpu,
        velocity_scale=cpu * _KDC_PERIOD_S * 65536.0,
        acceleration_scale=cpu * _KDC_PERIOD_S**2 * 65536.0,
        stepper=False, stage_id=stage_id, **kw,
    )


#: Supported stages. K10CR1: 409600 µsteps per 3° (136533.33 counts/°), velocity
#: 7329109 per °/s, acceleration 1502 per °/s² (QMI ``k10crx.py``; PnPQ cites protocol
#: p.41). PRM1-Z8: 1919.6418578623391 counts/° (pylablib, "what it says in the manual");
#: MTS25-Z8: 34304 counts/mm. Tolerances: 0.01° / 0.001 mm, far above the few counts
#: these stages stop short and below what a BRDF scan resolves.
STAGES: dict[str, AptStage] = {
    "K10CR1": AptStage(
        name="K10CR1", controller="K10CR1", kind=AxisKind.ROTARY,
        counts_per_unit=409600.0 / 3.0, velocity_scale=7329109.0,
        acceleration_scale=1502.0, stepper=True, stage_id=0, travel=None,
        max_velocity=10.0, velocity=10.0, acceleration=10.0, home_velocity=10.0,
        position_tolerance=0.01,
    ),
    "PRM1-Z8": _kdc_stage(
        "PRM1-Z8", AxisKind.ROTARY, 1919.6418578623391, 6, travel=None,
        max_velocity=25.0, velocity=10.0, acceleration=10.0, home_velocity=10.0,
        position_tolerance=0.01,
    ),
    "MTS25-Z8": _kdc_stage(
        "MTS25-Z8", AxisKind.LINEAR, 34304.0, 7, travel=(0.0, 25.0),
        max_velocity=2.4, velocity=2.0, acceleration=1.5, home_velocity=1.0,
        position_tolerance=0.001,
    ),
}

_HOME_REVERSE = 2  # direction: 1 forward, 2 reverse
_SWITCH_REVERSE = 1  # limit switch: 1 reverse, 4 forward
_STOP_IMMEDIATE = 1
_STOP_PROFILED = 2


class AptMotor(MotionAxis):
    """One axis on a Thorlabs APT controller.

    Parameters
    ----------
    port
        Device path, pyserial URL (``simapt://…``) or an open ``serial.SerialBase``.
    name
        Role name used in every error.
    stage
        ``"K10CR1"``, ``"PRM1-Z8"`` or ``"MTS25-Z8"`` (the latter two on a KDC101).
    soft_limits
        ``(low, high)`` in deg or mm. Default: the stage travel (linear), or the range
        the int32 position counter can hold (rotary, about ±15700° on a K10CR1).
    position_tolerance
        Accepted distance of a finished move from its target (default per stage).
    home_velocity, velocity, acceleration
        Written to the controller on open (units/s, units/s²); default per stage.
    home_offset
        Distance of the zero from the home switch (deg or mm), written in the home
        parameters; the controller's zero is there after homing.
    timeout
        Seconds to wait for one reply.
    retries
        Extra attempts for idempotent queries after a timeout or an undecodable reply.
    rts_settle_s, flush_s
        Pauses of the open sequence (RTS cycling, waiting for stale bytes before the
        flush). The defaults follow the APT document and PnPQ; tests may pass 0.
    stop_mode
        ``"profiled"`` (decelerate) or ``"immediate"``.
    """

    def __init__(
        self,
        port: str | serial.SerialBase,
        *,
        name: str,
        stage: str = "K10CR1",
        soft_limits: tuple[float, float] | None = None,
        position_tolerance: float | None = None,
        home_velocity: float | None = None,
        home_offset: float = 0.0,
        velocity: float | None = None,
        acceleration: float | None = None,
        timeout: float = 1.0,
        retries: int = 2,
        poll_interval: float = 0.01,
        rts_settle_s: float = 0.05,
        flush_s: float = 0.2,
        stop_mode: str = "profiled",
        channel: int = 1,
    ) -> None:
        try:
            spec = STAGES[stage]
        except KeyError:
            raise ValueError(f"unknown APT stage {stage!r}; known: {', '.join(STAGES)}"
                             ) from None
        self.spec = spec
        self._counter_range = _INT32 / spec.counts_per_unit
        if soft_limits is None:
            if spec.travel is not None:
                soft_limits = (spec.travel[0] - home_offset, spec.travel[1] - home_offset)
            else:
                soft_limits = (-math.floor(self._counter_range), math.floor(self._counter_range))
        super().__init__(
            name, kind=spec.kind, soft_limits=soft_limits,
            position_tolerance=(spec.position_tolerance if position_tolerance is None
                                else position_tolerance),
            poll_interval=poll_interval,
        )
        if max(abs(v) for v in self.soft_limits) > self._counter_range:
            raise ValueError(f"soft limits {self.soft_limits} exceed the position counter "
                             f"range ±{self._counter_range:.6g} {self.units}")
        if stop_mode not in ("profiled", "immediate"):
            raise ValueError("stop_mode must be 'profiled' or 'immediate'")
        if not (timeout > 0 and retries >= 0 and rts_settle_s >= 0 and flush_s >= 0):
            raise ValueError("timeout must be > 0; retries, rts_settle_s, flush_s >= 0")
        self._home_velocity = self._checked_velocity(
            spec.home_velocity if home_velocity is None else home_velocity, "home_velocity")
        self._velocity0 = self._checked_velocity(
            spec.velocity if velocity is None else velocity, "velocity")
        self._acceleration0 = float(spec.acceleration if acceleration is None
                                    else acceleration)
        if not (math.isfinite(self._acceleration0) and self._acceleration0 > 0):
            raise ValueError("acceleration must be a finite number > 0")
        self._home_offset = float(home_offset)
        self.channel = int(channel)
        self.timeout = float(timeout)
        self.retries = int(retries)
        self._rts_settle_s = float(rts_settle_s)
        self._flush_s = float(flush_s)
        self._stop_p2 = _STOP_PROFILED if stop_mode == "profiled" else _STOP_IMMEDIATE
        self._io_lock = threading.RLock()
        self._unpacker = apt.AptUnpacker(sources={apt.USB_DEVICE})
        #: Unsolicited frames consumed (MOVE_COMPLETED, status updates, late replies).
        self.unsolicited_count = 0
        #: The last unsolicited frame consumed, for diagnostics.
        self.last_unsolicited: AptMessage | None = None
        #: False where the port could not toggle RTS (a pseudo-terminal).
        self.rts_cycled = False
        self.info: apt.HwInfo | None = None

        port_obj = open_serial(port, device=name, baudrate=115200, rtscts=True,
                               timeout=self.timeout)
        try:
            self._chan = SerialChannel(port_obj, device=name)
            self._open_sequence()
        except BaseException:
            # A failed constructor leaves nothing open that it opened itself; a port the
            # caller handed in stays the caller's (ADR 0002).
            if not isinstance(port, serial.SerialBase):
                try:
                    port_obj.close()
                except (serial.SerialException, OSError):
                    log.debug("%s: closing the port after a failed open failed too", name)
            raise

    # ------------------------------------------------------------------ open
    def _open_sequence(self) -> None:
        self._cycle_rts()
        self._send(apt.pack_short(MessageId.HW_STOP_UPDATEMSGS), "HW_STOP_UPDATEMSGS",
                   drain=False)
        if self._flush_s:
            time.sleep(self._flush_s)  # let messages already in flight arrive, then drop
        dropped = self._chan.discard_input()
        self._unpacker.clear()
        if dropped:
            log.debug("%s: dropped %d stale bytes on open", self.name, dropped)
        try:
            self.info = self._read_info()
        except (DeviceTimeout, ProtocolError) as err:
            # Nothing (or nothing decodable) answers the first query: the wrong port, a
            # wrong baud rate, or a controller that is off. Say so rather than "timeout".
            raise ConnectionFailed(
                f"no APT controller answers on this port ({err.message})",
                device=self.name, command="HW_REQ_INFO",
                hint="check the port, the baud rate (115200), the cable, the controller's "
                     "power and that no other program (Kinesis) holds the device",
            ) from err
        self._check_model(self.info)
        self._do_enable()
        self._write_home_params()
        self._write_velparams(self._velocity0, self._acceleration0)

    def _cycle_rts(self) -> None:
        # APT document (quoted in QMI k10crx.py) and pylablib ``_cycle_rts``: raise RTS,
        # wait, purge partial data, wait, drop RTS, wait. A pty cannot: skip the pauses.
        if not self._chan.set_rts(True):
            self.rts_cycled = False
            log.debug("%s: port cannot set RTS (pseudo-terminal?); not cycling", self.name)
            return
        time.sleep(self._rts_settle_s)
        self._chan.discard_input()
        time.sleep(self._rts_settle_s)
        self._chan.set_rts(False)
        time.sleep(self._rts_settle_s)
        self.rts_cycled = True

    def _check_model(self, info: apt.HwInfo) -> None:
        spec = self.spec
        wrong = not info.model.upper().startswith(spec.controller)
        if not wrong and spec.stage_id and info.stage_id and info.stage_id != spec.stage_id:
            wrong = True
        if wrong:
            raise ConnectionFailed(
                f"the device is a {info.model} (stage id {info.stage_id}, S/N "
                f"{info.serial}), not a {spec.controller} with a {spec.name}",
                device=self.name, command="HW_REQ_INFO",
                hint="check the stage named for this axis in the bench profile",
            )

    def _write_home_params(self) -> None:
        params = apt.HomeParams(
            self.channel, _HOME_REVERSE, _SWITCH_REVERSE,
            self._vel_units(self._home_velocity), self._counts(self._home_offset),
        )
        self._write_checked(MessageId.MOT_SET_HOMEPARAMS, apt.encode_homeparams(params),
                            params, "home", self._read_homeparams)

    def _write_velparams(self, velocity: float, acceleration: float) -> None:
        params = apt.VelParams(self.channel, 0, self._acc_units(acceleration),
                               self._vel_units(velocity))
        self._write_checked(MessageId.MOT_SET_VELPARAMS, apt.encode_velparams(params),
                            params, "velocity", self._read_velparams)

    def _write_checked(self, set_id: MessageId, data: bytes, params: object, what: str,
                       read_back: Callable[[], object]) -> None:
        """Write a parameter set once (SET messages get no reply) and read it back."""
        command = set_id.name
        self._send(apt.pack_long(set_id, data), command)
        got = read_back()
        if got != params:
            raise ControllerError(
                f"{what} parameters read back as {got}, written {params}",
                device=self.name, command=command,
                hint=f"the controller rejected the {what} parameters; check the stage type",
            )

    # ------------------------------------------------------------------ units
    def _counts(self, value: float) -> int:
        counts = round(value * self.spec.counts_per_unit)
        if abs(counts) > _INT32:
            raise LimitError(f"{value:g} {self.units} is beyond the position counter range",
                             device=self.name, command="move")
        return counts

    def _units(self, counts: int) -> float:
        return counts / self.spec.counts_per_unit

    def _vel_units(self, velocity: float) -> int:
        return round(velocity * self.spec.velocity_scale)

    def _acc_units(self, acceleration: float) -> int:
        return round(acceleration * self.spec.acceleration_scale)

    def _checked_velocity(self, value: float, what: str) -> float:
        value = float(value)
        vmax = self.spec.max_velocity
        # A velocity read back from the controller is quantised to device units, so
        # scaling it back up can overshoot the maximum by a rounding error (10.0000014
        # deg/s on a K10CR1); that is the maximum, not an error.
        if vmax < value <= vmax * (1.0 + 1e-6):
            value = vmax
        if not (math.isfinite(value) and 0 < value <= vmax):
            raise ValueError(f"{self.name}: {what} must be in (0, {self.spec.max_velocity:g}] "
                             f"{self.units}/s for a {self.spec.name}, got {value:g}")
        return value

    # ------------------------------------------------------------------ messaging
    def _req(self, msg_id: int) -> bytes:
        return apt.pack_short(msg_id, self.channel, 0)

    def _send(self, frame: bytes, command: str, *, drain: bool = True) -> None:
        with self._io_lock:
            if drain:
                self._drain(command)
            self._chan.write(frame, command=command)

    def _query(self, frame: bytes, reply_id: int, command: str, *,
               decode: Callable[[AptMessage], T]) -> T:
        """Send an idempotent request and return its decoded reply, retrying on loss."""
        last: DeviceError | None = None
        with self._io_lock:
            for attempt in range(1 + self.retries):
                self._drain(command)
                self._chan.write(frame, command=command)
                try:
                    msg = self._await(reply_id, command)
                    return decode(msg)
                except (DeviceTimeout, ProtocolError) as err:
                    last = err
                    if isinstance(err, ProtocolError) and err.device is None:
                        last = ProtocolError(err.message, device=self.name, command=command,
                                             hint=err.hint)
                        last.__cause__ = err
                    log.debug("%s: %s attempt %d failed: %s", self.name, command,
                              attempt + 1, err)
        assert last is not None
        raise last

    def _await(self, reply_id: int, command: str) -> AptMessage:
        deadline = time.monotonic() + self.timeout
        while True:
            msg = self._unpacker.pop()
            if msg is None:
                self._receive(deadline, reply_id, command)
                continue
            if msg.msg_id == reply_id:
                self._check_channel(msg, command)
                return msg
            self._consume(msg, command)

    def _check_channel(self, msg: AptMessage, command: str) -> None:
        chan = msg.param1 if msg.data is None else int.from_bytes(msg.data[:2], "little")
        expected = self.channel
        if msg.msg_id == MessageId.MOD_GET_CHANENABLESTATE:
            expected = 1 << (self.channel - 1)  # a bitmask there
        if msg.msg_id != MessageId.HW_GET_INFO and chan != expected:
            raise ProtocolError(f"{msg.name} for channel {chan}, expected {expected}",
                                device=self.name, command=command)

    def _receive(self, deadline: float, reply_id: int, command: str) -> None:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise self._no_reply(reply_id, command)
        try:
            data = self._chan.read_exact(1, timeout=remaining, command=command)
        except DeviceTimeout as err:
            raise self._no_reply(reply_id, command) from err
        self._feed(data + self._chan.read_available(command=command), command)

    def _no_reply(self, reply_id: int, command: str) -> DeviceTimeout:
        return DeviceTimeout(
            f"no {apt.message_name(reply_id)} reply within {self.timeout:g} s",
            device=self.name, command=command,
            hint="check the cable, the controller's power and that no other "
                 "program (Kinesis) holds the device",
        )

    def _feed(self, data: bytes, command: str) -> None:
        try:
            self._unpacker.feed(data)
        except ProtocolError as err:
            raise ProtocolError(err.message, device=self.name, command=command,
                                hint=err.hint) from err

    def _drain(self, command: str) -> None:
        """Consume whatever has arrived unasked; surface device error events."""
        data = self._chan.read_available(command=command)
        if data:
            self._feed(data, command)
        while (msg := self._unpacker.pop()) is not None:
            self._consume(msg, command)

    def _consume(self, msg: AptMessage, command: str) -> None:
        if msg.msg_id == MessageId.HW_RESPONSE:
            raise ControllerError(
                "the controller reported an error event (HW_RESPONSE)",
                device=self.name, command=command,
                hint="read status() for the error bits; disable and re-enable the axis "
                     "(or power-cycle the controller) to clear it",
            )
        if msg.msg_id == MessageId.HW_RICHRESPONSE:
            rich = apt.decode_rich_response(msg)
            about = apt.message_name(rich.msg_id) if rich.msg_id else "no message"
            raise ControllerError(
                f"the controller reported error code 0x{rich.code:04X} "
                f"({rich.notes or 'no description'}; concerning {about})",
                code=rich.code, device=self.name, command=command,
                hint="read status() for the error bits; disable and re-enable the axis "
                     "(or power-cycle the controller) to clear it",
            )
        self.unsolicited_count += 1
        self.last_unsolicited = msg
        log.debug("%s: consumed %s while waiting in %s", self.name, msg.name, command)

    # ------------------------------------------------------------------ identity
    def _do_identity(self) -> DeviceIdentity:
        info = self.info
        if info is None:  # not reachable after a successful open; kept for safety
            info = self._read_info()
        return DeviceIdentity(
            vendor="Thorlabs", model=info.model, serial=str(info.serial),
            firmware=info.firmware_str,
            extra={"stage": self.spec.name, "hw_version": str(info.hw_version),
                   "notes": info.notes},
        )

    def identify(self) -> None:
        """Blink the controller's front-panel LED (MOD_IDENTIFY)."""
        self._check_open("identify")
        self._send(apt.pack_short(MessageId.MOD_IDENTIFY), "MOD_IDENTIFY")

    # ------------------------------------------------------------------ status
    def read_status_bits(self) -> tuple[int, int]:
        """(position in counts, raw 32-bit status word)."""
        self._check_open("status")
        return self._read_raw_status()

    def _read_raw_status(self) -> tuple[int, int]:
        if self.spec.stepper:
            _chan, bits = self._query(self._req(MessageId.MOT_REQ_STATUSBITS),
                                      MessageId.MOT_GET_STATUSBITS, "MOT_REQ_STATUSBITS",
                                      decode=apt.decode_statusbits)
            return self._read_counter(), bits
        update = self._query(self._req(MessageId.MOT_REQ_DCSTATUSUPDATE),
                             MessageId.MOT_GET_DCSTATUSUPDATE, "MOT_REQ_DCSTATUSUPDATE",
                             decode=apt.decode_status_update)
        return update.position, update.status

    def _read_counter(self) -> int:
        _chan, counts = self._query(
            self._req(MessageId.MOT_REQ_POSCOUNTER), MessageId.MOT_GET_POSCOUNTER,
            "MOT_REQ_POSCOUNTER",
            decode=lambda m: apt.decode_chan_value(m, "MOT_GET_POSCOUNTER"))
        return counts

    def _do_status(self) -> AxisStatus:
        counts, raw = self._read_raw_status()
        return decode_status(self._units(counts), raw)

    def _do_get_position(self) -> float:
        return self._units(self._read_counter())

    def _raise_status_error(self, status: AxisStatus, command: str) -> None:
        raise ControllerError(
            f"the controller reports {status.error}", device=self.name, command=command,
            hint="re-enable the axis to clear the error, then re-home if it lost position",
        )

    # ------------------------------------------------------------------ commands
    def _set_enable(self, enable: bool) -> None:
        state = 1 if enable else 2
        command = "MOD_SET_CHANENABLESTATE"
        # The channel ident here is a bitmask (1, 2, 4, 8) rather than a number.
        mask = 1 << (self.channel - 1)
        self._send(apt.pack_short(MessageId.MOD_SET_CHANENABLESTATE, mask, state), command)
        # No reply is promised (the K10CR1 sends none), so read the state back.
        got = self._query(apt.pack_short(MessageId.MOD_REQ_CHANENABLESTATE, mask, 0),
                          MessageId.MOD_GET_CHANENABLESTATE, "MOD_REQ_CHANENABLESTATE",
                          decode=lambda m: m.param2)
        if got != state:
            raise ControllerError(
                f"channel is {'enabled' if got == 1 else 'disabled'} after asking to "
                f"{'enable' if enable else 'disable'} it",
                code=got, device=self.name, command=command,
            )

    def _do_enable(self) -> None:
        self._set_enable(True)

    def _do_disable(self) -> None:
        self._set_enable(False)

    def _do_home(self) -> None:
        # MotionAxis.home() has checked the channel is enabled: a disabled channel ignores
        # MOT_MOVE_HOME without a word, and an axis homed before would look done at once.
        # Home parameters again: a controller power-cycled since open is back to zero
        # home velocity, and homing would never end.
        self._write_home_params()
        self._send(apt.pack_short(MessageId.MOT_MOVE_HOME, self.channel, 0), "MOT_MOVE_HOME")

    def _do_move_absolute(self, target: float) -> None:
        data = apt.encode_chan_value(self.channel, self._counts(target))
        self._send(apt.pack_long(MessageId.MOT_MOVE_ABSOLUTE, data), "MOT_MOVE_ABSOLUTE")

    def _do_move_relative(self, delta: float, target: float) -> None:
        # The controller moves relative to where it is; sending target - position (not
        # the bare delta) keeps a stage that stopped a few counts short from accumulating
        # the shortfall over a series of relative moves.
        step = self._counts(target) - self._read_counter()
        data = apt.encode_chan_value(self.channel, step)
        self._send(apt.pack_long(MessageId.MOT_MOVE_RELATIVE, data), "MOT_MOVE_RELATIVE")

    def _do_stop(self) -> None:
        # Sent before anything else is read: an error event waiting in the input (which
        # draining would raise) must never keep a moving stage from being stopped. The
        # next exchange consumes and reports it.
        self._send(apt.pack_short(MessageId.MOT_MOVE_STOP, self.channel, self._stop_p2),
                   "MOT_MOVE_STOP", drain=False)
        # The old target is void: a wait() afterwards reports where the axis came to
        # rest (no MotionError), and move_by() counts from there.
        self._target = None

    def move_continuous(self, *, forward: bool = True) -> None:
        """Turn without end at the set :attr:`velocity` (MOT_MOVE_VELOCITY, p2 = 1
        forward, 2 reverse) until :meth:`stop`: a sample spinner. Only a
        continuous-rotation stage (no travel limits) may; the position counter wraps
        after some turns (a 32-bit register), so home again before positioning moves."""
        self._check_open("move_continuous")
        if self.spec.travel is not None:
            raise UnsupportedFeature(
                f"{self.spec.name} has a limited travel: only a continuous-rotation stage "
                "(K10CR1, PRM1-Z8) turns continuously", device=self.name,
                command="move_continuous")
        if not self.status().is_enabled:
            # a disabled channel ignores the command without a word
            raise StateError("channel disabled: enable it before a continuous move",
                             device=self.name, command="move_continuous")
        self._target = None  # no arrival to check: it turns until stopped
        self._send(apt.pack_short(MessageId.MOT_MOVE_VELOCITY, self.channel,
                                  1 if forward else 2), "MOT_MOVE_VELOCITY")

    def _read_info(self) -> apt.HwInfo:
        return self._query(apt.pack_short(MessageId.HW_REQ_INFO), MessageId.HW_GET_INFO,
                           "HW_REQ_INFO", decode=apt.decode_hw_info)

    def _read_homeparams(self) -> apt.HomeParams:
        return self._query(self._req(MessageId.MOT_REQ_HOMEPARAMS),
                           MessageId.MOT_GET_HOMEPARAMS, "MOT_REQ_HOMEPARAMS",
                           decode=apt.decode_homeparams)

    def _read_velparams(self) -> apt.VelParams:
        return self._query(self._req(MessageId.MOT_REQ_VELPARAMS),
                           MessageId.MOT_GET_VELPARAMS, "MOT_REQ_VELPARAMS",
                           decode=apt.decode_velparams)

    def _do_get_velocity(self) -> float:
        return self._read_velparams().max_velocity / self.spec.velocity_scale

    def _do_set_velocity(self, value: float) -> None:
        value = self._checked_velocity(value, "velocity")
        current = self._read_velparams()
        self._write_velparams(value, current.acceleration / self.spec.acceleration_scale)

    def _do_get_acceleration(self) -> float:
        return self._read_velparams().acceleration / self.spec.acceleration_scale

    def _do_set_acceleration(self, value: float) -> None:
        current = self._read_velparams()
        self._write_velparams(current.max_velocity / self.spec.velocity_scale, value)

    def _do_close(self) -> None:
        self._chan.close()


def decode_status(position: float, raw: int) -> AxisStatus:
    """Turn a raw APT status word into an :class:`AxisStatus` (position in units)."""
    bits = StatusBits(raw & 0xFFFFFFFF)
    errors = bits & StatusBits.error_mask()
    error = None
    if errors:
        names = "|".join(b.name for b in StatusBits if b & errors and b.name)
        error = f"error bits {names} (status 0x{raw:08X})"
    return AxisStatus(
        position=position,
        is_moving=bool(bits & (StatusBits.moving_mask() | StatusBits.HOMING
                               | StatusBits.ACTIVE)),
        is_homed=bool(bits & StatusBits.HOMED),
        is_enabled=bool(bits & StatusBits.ENABLED),
        is_homing=bool(bits & StatusBits.HOMING),
        at_forward_limit=bool(bits & StatusBits.CW_HARD_LIMIT),
        at_reverse_limit=bool(bits & StatusBits.CCW_HARD_LIMIT),
        error=error,
    )
