"""Thorlabs FW102C (6 slots) / FW212C (12 slots) motorised filter wheel over its ASCII port.

Source: Thorlabs, *Motorized Filter Wheel* manual, rev H (October 2, 2014), chapter 5
"Software Control", §5.2.3 "Keywords (Commands and Queries)" (page 11; read at
https://www.easymanua.ls/thorlabs/fw102c/manual?p=11). Confirmed there:

- ``*idn?`` returns the model number and firmware version;
- ``pos=n`` moves the wheel to slot n, ``pos?`` asks for the slot;
- ``pcount=n`` sets the wheel type (n = 6 or 12), ``pcount?`` asks for it;
- ``speed=0`` slow ("normal" here) and ``speed=1`` high move profile, ``speed?``;
- ``trig=0/1`` external trigger input/output, ``sensors=0/1`` (sensors off when idle,
  against stray light / always on), ``baud=0/1`` (9600/115200), ``save`` stores the
  settings as the power-up defaults;
- all keywords are lower case; an incorrect keyword, format or out-of-range argument
  makes the unit "return an error string".

From secondary sources (**unconfirmed** against the manual):

- serial settings 115200 baud, 8N1, no flow control, CR terminator (ISIS IBEX developer
  notes for their FW102C IOC; Odemis ``tlfw.py`` opens it so);
- the echo and the ``"> "`` prompt closing every answer (hispec, J. Feder's driver,
  Odemis), and error lines ``Command error CMD_NOT_DEFINED`` / ``CMD_ARG_INVALID``
  (Odemis, acq4);
- the prompt after ``pos=n`` comes only once the wheel is at the slot (hispec: "the next
  response will wait until the filter wheel is actually in position"), so :meth:`move_to`
  is one exchange whose deadline is the move timeout;
- the move time: about 3 s for half a turn at high speed (hispec), the slow profile about
  half as fast (Odemis assumes 2 s per slot slow, 1 s fast, with a 2× margin). The
  estimate below takes the shorter way round, as Odemis does; the default timeout is
  three times the estimate plus 2 s;
- what a jammed wheel reports is not documented anywhere we found. The driver assumes the
  worst: the prompt never comes. Then :meth:`move_to` raises :class:`WheelMoveTimeout`
  after its timeout, never hangs; a wheel that answers but stands elsewhere raises
  :class:`WheelJammed`. Either error names the wheel and says what to do.

While a move runs the unit answers nothing (it is still inside ``pos=``), so this driver
never sends anything else until the prompt arrives or the timeout passes. After a timeout
it asks ``pos?`` once: a wheel that answers and stands at the slot has arrived (only the
prompt was lost); otherwise :class:`WheelMoveTimeout`. ``pos=`` itself is never repeated.
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Mapping
from typing import Any

import serial

from drivers.base import DeviceIdentity, FilterWheel, WheelSpeed
from drivers.errors import (
    ConnectionFailed,
    DeviceTimeout,
    MotionError,
    ProtocolError,
    StateError,
)
from drivers.thorlabs_ascii_link import CommandRejected, PromptLink
from drivers.thorlabs_ascii_protocol import parse_int

__all__ = ["CommandRejected", "Fw102cWheel", "WheelJammed", "WheelMoveTimeout"]

#: Seconds per degree of wheel rotation, by ``speed?`` value (see the module docstring).
SECONDS_PER_DEGREE = {1: 3.0 / 180.0, 0: 6.0 / 180.0}
#: Fixed overhead of one move (start, settle on the slot's sensor), seconds.
MOVE_OVERHEAD_S = 0.3
_SPEED_CODES = {WheelSpeed.NORMAL: 0, WheelSpeed.HIGH: 1}
_VERSION_RE = re.compile(r"version\s+(\S+)", re.IGNORECASE)


class WheelJammed(MotionError):
    """The wheel did not end at the commanded slot."""


class WheelMoveTimeout(WheelJammed, DeviceTimeout):
    """The wheel did not report arrival within the move timeout (jammed or stalled)."""


class Fw102cWheel(FilterWheel):
    """A Thorlabs FW102C/FW212C filter wheel.

    Parameters
    ----------
    port
        A device path, a pyserial URL (``simfw102c://x``) or an open ``serial.SerialBase``.
    name
        Role name used in every error.
    filters
        Slot → filter description (see :class:`~drivers.base.FilterSpec`).
    speed
        ``"normal"``/``"high"`` (or a :class:`WheelSpeed`) to set at connect; ``None``
        keeps the unit's setting.
    baudrate
        115200 (the unit's default) or 9600.
    reply_timeout, retries
        One answer's timeout; extra attempts for queries (``pos=`` is never repeated).
    move_timeout_factor, move_timeout_margin_s
        See :class:`~drivers.base.FilterWheel`.
    serial_number
        The serial number on the unit's label, for provenance (not reported by the unit).

    Raises
    ------
    ConnectionFailed
        The port cannot be opened, nothing answers, or what answers is no FW102C/FW212C.
    """

    BAUDRATES = (115200, 9600)

    def __init__(
        self,
        port: str | serial.SerialBase,
        *,
        name: str,
        filters: Mapping[Any, Any] | None = None,
        speed: WheelSpeed | str | None = None,
        baudrate: int = 115200,
        reply_timeout: float = 0.5,
        retries: int = 2,
        move_timeout_factor: float = 3.0,
        move_timeout_margin_s: float = 2.0,
        serial_number: str = "",
    ) -> None:
        if baudrate not in self.BAUDRATES:
            raise ValueError(f"the FW102C runs at 115200 or 9600 baud, got {baudrate}")
        super().__init__(name, filters=filters, move_timeout_factor=move_timeout_factor,
                         move_timeout_margin_s=move_timeout_margin_s)
        self.serial_number = str(serial_number)
        self._idn = ""
        self._count = 0
        self._speed_code: int | None = None
        self._link: PromptLink | None = PromptLink.open(
            port, device=name, baudrate=baudrate, reply_timeout=reply_timeout, retries=retries)
        try:
            self._connect(baudrate)
            if speed is not None:
                self.speed = speed
        except BaseException:
            # A failed constructor leaves nothing open that it opened itself.
            self._link.abandon()
            self._link = None
            raise

    # connection ---------------------------------------------------------------
    def _connect(self, baudrate: int) -> None:
        link = self._io("open")
        self._idn = link.identify("*idn", "FW102C/FW212C", r"FW(102|212)C", baudrate=baudrate)
        count = link.query("pcount", lambda t: parse_int(t, 1, 12))
        if count not in (6, 12):
            raise ConnectionFailed(f"the wheel reports {count} slots (6 or 12 expected)",
                                   device=self.name, command="pcount?",
                                   hint="set the wheel type with pcount=6 or pcount=12")
        self._count = count
        self._check_filters(count)

    # FilterWheel hooks --------------------------------------------------------
    def _do_identity(self) -> DeviceIdentity:
        match = _VERSION_RE.search(self._idn)
        return DeviceIdentity(
            vendor="Thorlabs", model="FW102C" if self._count == 6 else "FW212C",
            serial=self.serial_number or "not reported",
            firmware=match.group(1) if match else self._idn,
            extra={"idn": self._idn, "slots": str(self._count)},
        )

    def _do_position_count(self) -> int:
        return self._count

    def _do_get_position(self) -> int:
        return self._io("pos?").query("pos", lambda t: parse_int(t, 1, self._count))

    def _do_get_speed(self) -> WheelSpeed:
        code = self._io("speed?").query("speed", lambda t: parse_int(t, 0, 1))
        self._speed_code = code
        return WheelSpeed.HIGH if code else WheelSpeed.NORMAL

    def _do_set_speed(self, value: WheelSpeed) -> None:
        link = self._io("set speed")
        link.command("speed", _SPEED_CODES[value])
        self._speed_code = None
        if self._do_get_speed() is not value:
            raise ProtocolError(f"speed? does not read back {value.value} after speed=",
                                device=self.name, command=f"speed={_SPEED_CODES[value]}")

    def _do_estimate_move_s(self, start: int, target: int) -> float:
        steps = abs(target - start) % self._count
        steps = min(steps, self._count - steps)
        if steps == 0:
            return 0.0
        code = self._speed_code if self._speed_code is not None else (
            _SPEED_CODES[self._do_get_speed()])
        return steps * (360.0 / self._count) * SECONDS_PER_DEGREE[code] + MOVE_OVERHEAD_S

    def _do_move_to(self, position: int, timeout: float) -> None:
        link = self._io("move_to")
        try:
            link.command("pos", position, timeout=timeout)
        except DeviceTimeout as err:
            # Only the prompt may have been lost: a wheel that answers and stands at the
            # slot has arrived. A jammed one is still inside pos= and answers nothing.
            with contextlib.suppress(DeviceTimeout, ProtocolError):
                if link.query("pos", lambda t: parse_int(t, 1, self._count),
                              attempts=1) == position:
                    return
            raise WheelMoveTimeout(
                f"the wheel did not reach slot {position} within {timeout:g} s; it may be "
                "jammed between slots (it answers nothing while a move is unfinished)",
                device=self.name, command=f"pos={position}",
                hint="check the wheel for an obstruction or a loose filter, power-cycle the "
                "FW102C, then reconnect",
            ) from err

    def _missed_error(self, actual: int, target: int) -> MotionError:
        return WheelJammed(
            f"the wheel reports slot {actual} after a move to slot {target}",
            device=self.name, command=f"pos={target}",
            hint="check the wheel for an obstruction or a loose filter, then move again; "
            "power-cycle the FW102C if it repeats",
        )

    def _do_close(self) -> None:
        if self._link is not None:
            self._link.close()
            self._link = None

    # helpers ------------------------------------------------------------------
    def _io(self, command: str) -> PromptLink:
        if self._link is None:
            raise StateError("device is closed", device=self.name, command=command)
        return self._link
