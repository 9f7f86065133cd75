"""Firmware emulator of a Zaber ASCII-protocol controller with one or more axes.

Written from the protocol facts (hardware reference §1d; Zaber's *ASCII Protocol Manual*
conventions, the *A-Series ASCII Protocol (alpha)* wiki page, the article *Zaber's ASCII
Protocol*, and Zaber's own ``zaber.serial`` library for the checksum and alert layouts),
independently of ``drivers/``: it imports nothing from there, so a misreading shared by
the driver and the emulator cannot pass unnoticed.

The device side of the protocol:

- Host → device: ``/[device] [axis] [id] command [args][:CC]`` ended by CR, LF or both.
  Up to three leading integers are the device (0 = every device), the axis (0 = the whole
  device) and the message id (echoed in the reply). Bytes before ``/`` are ignored;
  backspace erases the last byte, DEL (127) or any other non-printable byte discards the
  command being received (the alpha wiki page, "Protocol Specifications").
- Device → host: ``@DD A [ID] OK|RJ BUSY|IDLE FLAG data`` + CR LF; ``!DD A STATUS FLAG``
  alerts when ``comm.alert`` is 1; a ``:CC`` checksum on every message when
  ``comm.checksum`` is 1. A command carrying a checksum that does not match is dropped
  without a reply **[assumed: the manual's rule could not be read]**.

Default behaviour, declared once (see :data:`STAGE_MODELS` and :class:`ZaberEmulator`):

- Positions are integer microsteps; the stage mechanics (:mod:`hw_mocks.motion`) work in
  the stage's own units, ``microstep_size`` apart. ``maxspeed`` is in microsteps per
  1.6384 s and ``accel`` in units of 10000/1.6384 microsteps/s² (the A-Series speed and
  acceleration conversions of the Zaber wiki; the ASCII settings use the same data).
- Power-up: driver enabled, no reference position (warning ``WR``), the counter reads 0
  wherever the stage is (physical ``start_position``).
- ``home`` drives to the home sensor (physical 0) at ``maxspeed`` and zeroes the counter
  there; ``WR`` clears. Moves are accepted without a reference (the counter frame is then
  arbitrary) **[no source for the firmware's rule; the driver never does this]**.
- ``move abs``/``move rel`` outside ``limit.min``..``limit.max`` are rejected ``BADDATA``;
  ``move rel`` counts from the target of a move in progress, else from the position
  **[unverified]**. The axis reads ``BUSY`` until the trapezoidal profile ends.
- ``stop`` decelerates at ``accel`` (a homing run stops at once, unreferenced); it sets the
  notice ``NI`` on an interrupted move (cleared by the next motion command).
- ``driver disable`` → fault flag ``FO`` and every motion command rejected
  ``DRIVERDISABLED``; refused ``STATUSBUSY`` while the axis moves **[assumed]**;
  ``driver enable`` clears ``FO``.
- A limit sensor reached during a move (the physical travel, narrower than the limits only
  when a test makes it so) stops the axis and raises ``WL`` (unexpected limit trigger).
  A fault injected with :meth:`ZaberEmulator.enter_error_state` (default ``FS`` stalled
  and stopped) stops the axis at once. Faults and ``WL`` persist until ``warnings clear``,
  whose reply lists the flags it cleared.
- ``warnings`` answers the count and every active flag (``02 FO WR``); the warning field of
  a reply shows the highest-priority one (faults before warnings before notices).
- Rejections: ``BADCOMMAND`` (unknown command or setting, or setting a read-only one),
  ``BADAXIS`` (no such axis), ``BADDATA`` (not an integer, or out of range),
  ``DEVICEONLY`` (a device setting sent to an axis), ``BADMESSAGEID`` (id above 99).
- A command addressed to another device is ignored (another device on the daisy chain);
  the "unsolicited" frame used for fault injection is an alert.
- A host reconnecting finds stale bytes in the pipe: the tail of an old reply, an old
  reply and an alert.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hw_mocks.clock import Clock
from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.motion import StageMechanics

__all__ = ["STAGE_MODELS", "ZaberEmulator", "ZaberStageModel"]

#: Data units of ``maxspeed`` (microsteps per this many seconds) and of ``accel``
#: (microsteps/s² per data unit = 10000 / 1.6384), Zaber wiki A-Series conversions.
_SPEED_PERIOD_S = 1.6384
_ACCEL_FACTOR = 10000.0 / 1.6384
_FIRMWARE = "7.38"


@dataclass(frozen=True)
class ZaberStageModel:
    """An axis the controller drives: identity, microstep size, travel, power-up settings."""

    product: str
    peripheral_id: int
    units: str                          # "deg" or "mm"
    microstep_size: float               # units per microstep at resolution 64
    travel: tuple[float, float]         # limit sensors (physical frame)
    limits: tuple[float, float]         # limit.min, limit.max at power-up (units)
    maxspeed: float                     # units/s at power-up
    maxspeed_max: float                 # largest maxspeed accepted, units/s
    accel: float                        # units/s² at power-up
    accel_max: float
    start_position: float               # physical position at power-up


#: Axis models, chosen by the URL option ``kind=``. The microstep sizes are typical of
#: Zaber rotary and lead-screw stages; the other values are the emulator's defaults, not
#: datasheet quotes. The linear model has its home sensor mid-travel, like the SMC100
#: emulator's linear stage, so one contract range suits every emulated axis; the
#: accelerations are high enough that one ``accel`` data unit (about 0.3 mm/s² on the
#: linear stage) is a small fraction of them.
STAGE_MODELS: dict[str, ZaberStageModel] = {
    "rotary": ZaberStageModel("emulated rotary stage", 70001, "deg", 0.000234375,
                              (-math.inf, math.inf), (-180.0, 180.0),
                              20.0, 60.0, 200.0, 2000.0, 37.0),
    "linear": ZaberStageModel("emulated linear stage", 70002, "mm", 0.000047625,
                              (-26.0, 26.0), (-25.0, 25.0),
                              5.0, 20.0, 200.0, 2000.0, 12.0),
}

#: Warning flags in the order a reply's warning field reports them (faults, warnings,
#: notices; the order within a level is the emulator's).
_PRIORITY = ("FF", "FH", "FV", "FO", "FD", "FQ", "FS", "FT", "FE", "FC", "FM", "FI", "FA",
             "FR", "FB", "FP", "FN", "FZ", "WL", "WV", "WT", "WS", "WM", "WP", "WR", "WH",
             "NC", "NI", "ND", "NR", "NT", "NU", "NJ", "NB")
_FAULT_CODES = frozenset(f for f in _PRIORITY if f[0] == "F") - {"FO"}
_DEVICE_SETTINGS = ("deviceid", "system.serial", "version", "system.axiscount",
                    "comm.alert", "comm.checksum")
_AXIS_SETTINGS = ("pos", "maxspeed", "accel", "resolution", "limit.min", "limit.max",
                  "peripheralid")
_WRITABLE = frozenset({"maxspeed", "accel", "limit.min", "limit.max", "comm.alert",
                       "comm.checksum"})
_MAX_LINE = 256
_BS, _DEL = 0x08, 0x7F


class _Reject(Exception):
    """A command is rejected; ``reason`` goes into the RJ reply's data."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def _checksum(body: bytes) -> str:
    # Two's complement of the low byte of the sum (zaber.serial: "XOR + 1 ... LRC").
    return f"{(256 - sum(body) % 256) % 256:02X}"


class _Axis:
    """One axis: stage mechanics in physical units, settings in device units."""

    def __init__(self, number: int, model: ZaberStageModel, clock: Clock,
                 start_position: float) -> None:
        self.number = number
        self.model = model
        self.ms = model.microstep_size
        self.resolution = 64
        self.maxspeed = self.speed_data(model.maxspeed)
        self.accel = self.accel_data(model.accel)
        self.limit_min = round(model.limits[0] / self.ms)
        self.limit_max = round(model.limits[1] / self.ms)
        self.stage = StageMechanics(
            clock, velocity=model.maxspeed, acceleration=model.accel, travel=model.travel,
            home_velocity=model.maxspeed, start_position=start_position)
        self.driver_enabled = True
        self.faults: set[str] = set()      # persistent F* flags and WL
        self.notices: set[str] = set()
        self.motion: str | None = None     # "move" | "home" | None: what BUSY means
        self.target: int | None = None     # microsteps, of the move in progress

    # units -------------------------------------------------------------------
    def speed_data(self, units_per_s: float) -> int:
        return round(units_per_s / self.ms * _SPEED_PERIOD_S)

    def accel_data(self, units_per_s2: float) -> int:
        return round(units_per_s2 / self.ms / _ACCEL_FACTOR)

    def position(self) -> int:
        return round(self.stage.position() / self.ms)

    def apply_dynamics(self) -> None:
        velocity = self.maxspeed / _SPEED_PERIOD_S * self.ms
        self.stage.velocity = velocity
        self.stage.acceleration = self.accel * _ACCEL_FACTOR * self.ms
        self.stage.home_velocity = velocity

    # state -------------------------------------------------------------------
    def busy(self) -> bool:
        return self.stage.is_moving()

    def flags(self) -> list[str]:
        active = set(self.faults) | set(self.notices)
        if not self.driver_enabled:
            active.add("FO")
        if not self.stage.homed:
            active.add("WR")
        return [f for f in _PRIORITY if f in active] + sorted(active - set(_PRIORITY))

    def top_flag(self) -> str:
        flags = self.flags()
        return flags[0] if flags else "--"


class ZaberEmulator(FirmwareEmulator):
    """A Zaber controller at daisy-chain address ``device`` with ``len(kinds)`` axes.

    Parameters
    ----------
    name
        Instance name (URL host part).
    device
        Address 1..99 the controller answers to (and 0, which reaches every device).
    kinds
        One :data:`STAGE_MODELS` key per axis (``"rotary"``, ``"linear"``), axis 1 first.
    start_positions
        Physical power-up positions, one per axis; default from the models.
    checksum, alerts
        Power-up values of ``comm.checksum`` and ``comm.alert``.
    """

    scheme = "simzaber"
    baudrate = 115200

    def __init__(
        self,
        name: str,
        *,
        device: int = 1,
        kinds: tuple[str, ...] | list[str] = ("rotary",),
        start_positions: tuple[float, ...] | list[float] | None = None,
        checksum: bool = False,
        alerts: bool = False,
        clock: Clock | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__(name, clock=clock, seed=seed)
        if not 1 <= device <= 99:
            raise ValueError(f"Zaber device address must be 1..99, got {device}")
        kinds = tuple(kinds)
        if not 1 <= len(kinds) <= 9:
            raise ValueError(f"a controller has 1..9 axes, got {len(kinds)}")
        for kind in kinds:
            if kind not in STAGE_MODELS:
                raise ValueError(f"kind must be one of {sorted(STAGE_MODELS)}, got {kind!r}")
        if start_positions is not None and len(start_positions) != len(kinds):
            raise ValueError("give one start position per axis")
        self.device = device
        self.kinds = kinds
        self.axes: dict[int, _Axis] = {}
        for i, kind in enumerate(kinds, start=1):
            model = STAGE_MODELS[kind]
            start = model.start_position if start_positions is None else start_positions[i - 1]
            self.axes[i] = _Axis(i, model, self.clock, float(start))
        self.comm_checksum = bool(checksum)
        self.comm_alert = bool(alerts)
        self.serial_number = 40000 + seed % 50000
        self.device_id = 50000 + self.axes[1].model.peripheral_id % 1000
        self._collecting: bytearray | None = None
        self._pending: list[bytes] = []   # alerts waiting to go out
        #: Commands dropped for a bad checksum (for tests).
        self.dropped: list[bytes] = []

    @property
    def stage(self) -> StageMechanics:
        """Axis 1's mechanics (the virtual bench reads one stage per emulator)."""
        return self.axes[1].stage

    # backdoor -----------------------------------------------------------------
    def flags(self, axis: int = 1) -> list[str]:
        """Every warning flag active on ``axis`` now, highest priority first."""
        with self.lock:
            self._update()
            return self.axes[axis].flags()

    def position_usteps(self, axis: int = 1) -> int:
        with self.lock:
            self._update()
            return self.axes[axis].position()

    # FirmwareEmulator ---------------------------------------------------------
    def _handle_input(self, buf: bytearray) -> list[bytes]:
        out: list[bytes] = []
        for byte in bytes(buf):
            if self._collecting is None:
                if byte == ord("/"):
                    self._collecting = bytearray()
                continue  # outside a command: line noise, ignored
            if byte in (0x0D, 0x0A):
                line, self._collecting = bytes(self._collecting), None
                out += self._execute(line)
            elif byte == _BS:
                del self._collecting[-1:]
            elif byte == _DEL or not 0x20 <= byte < 0x7F:
                self._collecting = None  # the incomplete command is discarded
            elif len(self._collecting) >= _MAX_LINE:
                self._collecting = None
            else:
                self._collecting.append(byte)
        buf.clear()
        return out

    def poll(self) -> list[bytes]:
        with self.lock:
            self._update()
            out, self._pending = self._pending, []
            return out

    def on_connect(self) -> list[bytes]:
        super().on_connect()
        with self.lock:
            self._collecting = None
            if self.connections <= 1:
                return []
            # What an earlier session left in the USB-serial buffer: the tail of a reply,
            # a whole old reply and an alert.
            old = self._frame("@", f"{self.device:02d} 1 OK IDLE -- 0")
            alert = self._frame("!", f"{self.device:02d} 1 IDLE {self.axes[1].top_flag()}")
            return [old[-7:], old, alert]

    def unsolicited_frame(self) -> bytes:
        """An alert, as a device with ``comm.alert`` on sends when a move ends."""
        with self.lock:
            self._update()
            axis = self.axes[1]
            status = "BUSY" if axis.busy() else "IDLE"
            return self._frame("!", f"{self.device:02d} 1 {status} {axis.top_flag()}")

    def enter_error_state(self, code: str | None = None) -> None:
        """Raise a fault: ``code`` is a flag (default ``FS``), optionally ``"N:FLAG"`` for axis N.

        The axis stops at once and the flag persists until ``warnings clear``.
        """
        with self.lock:
            number, flag = 1, (code or "FS").strip().upper()
            if ":" in flag:
                head, flag = flag.split(":", 1)
                number = int(head)
            if flag not in _FAULT_CODES | {"WL"}:
                raise ValueError(f"Zaber error state must be a fault flag such as FS or FQ, "
                                 f"got {code!r}")
            if number not in self.axes:
                raise ValueError(f"no axis {number}")
            self._update()
            axis = self.axes[number]
            axis.stage.stop(immediate=True)
            axis.faults.add(flag)
            self._update()

    # state ------------------------------------------------------------------------
    def _update(self) -> None:
        """Bring every axis to ``clock.now()``; note finished motions (alerts, WL)."""
        for axis in self.axes.values():
            if axis.motion is None:
                continue
            stage = axis.stage
            if stage.is_moving():
                continue
            if axis.motion == "move" and stage.at_limit is not None:
                axis.faults.add("WL")  # stopped by a limit sensor it was not homing to
            axis.motion = None
            axis.target = None
            if self.comm_alert:
                self._pending.append(
                    self._frame("!", f"{self.device:02d} {axis.number} IDLE "
                                     f"{axis.top_flag()}"))

    def _frame(self, kind: str, text: str) -> bytes:
        body = text.encode("ascii")
        if self.comm_checksum:
            body += b":" + _checksum(body).encode("ascii")
        return kind.encode("ascii") + body + b"\r\n"

    # command interpreter ------------------------------------------------------------
    def _execute(self, line: bytes) -> list[bytes]:
        text = line.decode("ascii")  # printable by construction
        if len(text) >= 3 and text[-3] == ":":
            given = text[-2:]
            text = text[:-3]
            if given.upper() != _checksum(text.encode("ascii")):
                self.dropped.append(line)
                return []
        words = text.split()
        numbers: list[int] = []
        while words and len(numbers) < 3 and words[0].isdigit():
            numbers.append(int(words.pop(0)))
        device = numbers[0] if numbers else 0
        axis_no = numbers[1] if len(numbers) > 1 else 0
        message_id = numbers[2] if len(numbers) > 2 else None
        if device not in (0, self.device):
            return []  # another device on the chain
        self._update()
        id_text = None
        try:
            if message_id is not None:
                if message_id > 99:
                    raise _Reject("BADMESSAGEID")
                id_text = f"{message_id:02d}"
            if axis_no != 0 and axis_no not in self.axes:
                raise _Reject("BADAXIS")
            flag, data = "OK", self._command(axis_no, words)
        except _Reject as rejection:
            flag, data = "RJ", rejection.reason
        self._update()
        status, warning = self._scope_state(axis_no)
        # The reply names the axis as addressed (one digit; a longer number cannot be one).
        fields = [f"{self.device:02d}", str(axis_no if axis_no <= 9 else 0)]
        if id_text is not None:
            fields.append(id_text)
        fields += [flag, status, warning, data]
        replies = [*self._pending, self._frame("@", " ".join(fields))]
        self._pending = []
        return replies

    def _scope_state(self, axis_no: int) -> tuple[str, str]:
        axes = [self.axes[axis_no]] if axis_no in self.axes else list(self.axes.values())
        status = "BUSY" if any(a.busy() for a in axes) else "IDLE"
        flags = [f for a in axes for f in a.flags()]
        ranked = sorted(flags, key=lambda f: _PRIORITY.index(f) if f in _PRIORITY else 99)
        return status, (ranked[0] if ranked else "--")

    def _targets(self, axis_no: int) -> list[_Axis]:
        return [self.axes[axis_no]] if axis_no else list(self.axes.values())

    def _command(self, axis_no: int, words: list[str]) -> str:
        if not words:
            return "0"  # empty command: a status poll
        head, args = words[0], words[1:]
        if head == "get" and len(args) == 1:
            return self._get(axis_no, args[0])
        if head == "set" and len(args) == 2:
            return self._set(axis_no, args[0], args[1])
        if head == "move" and len(args) == 2 and args[0] in ("abs", "rel"):
            return self._move(axis_no, args[0], args[1])
        if head == "home" and not args:
            return self._home(axis_no)
        if head == "stop" and not args:
            for axis in self._targets(axis_no):
                self._stop(axis)
            return "0"
        if head == "warnings" and args in ([], ["clear"]):
            return self._warnings(axis_no, clear=bool(args))
        if head == "driver" and len(args) == 1 and args[0] in ("enable", "disable"):
            return self._driver(axis_no, args[0] == "enable")
        raise _Reject("BADCOMMAND")

    # settings
    def _get(self, axis_no: int, setting: str) -> str:
        if setting in _DEVICE_SETTINGS:
            if axis_no:
                raise _Reject("DEVICEONLY")
            return {
                "deviceid": str(self.device_id),
                "system.serial": str(self.serial_number),
                "version": _FIRMWARE,
                "system.axiscount": str(len(self.axes)),
                "comm.alert": str(int(self.comm_alert)),
                "comm.checksum": str(int(self.comm_checksum)),
            }[setting]
        if setting not in _AXIS_SETTINGS:
            raise _Reject("BADCOMMAND")
        # Device scope: one value per axis, axis 1 first.
        return " ".join(str(self._axis_value(a, setting)) for a in self._targets(axis_no))

    @staticmethod
    def _axis_value(axis: _Axis, setting: str) -> int:
        return {
            "pos": axis.position,
            "maxspeed": lambda: axis.maxspeed,
            "accel": lambda: axis.accel,
            "resolution": lambda: axis.resolution,
            "limit.min": lambda: axis.limit_min,
            "limit.max": lambda: axis.limit_max,
            "peripheralid": lambda: axis.model.peripheral_id,
        }[setting]()

    def _set(self, axis_no: int, setting: str, raw: str) -> str:
        if setting not in _DEVICE_SETTINGS + _AXIS_SETTINGS:
            raise _Reject("BADCOMMAND")
        if setting not in _WRITABLE:
            raise _Reject("BADCOMMAND")  # read-only here
        value = _integer(raw)
        if setting in ("comm.alert", "comm.checksum"):
            if axis_no:
                raise _Reject("DEVICEONLY")
            if value not in (0, 1):
                raise _Reject("BADDATA")
            if setting == "comm.alert":
                self.comm_alert = bool(value)
            else:
                self.comm_checksum = bool(value)
            return "0"
        targets = self._targets(axis_no)
        for axis in targets:  # validate every axis before changing any
            if not self._valid(axis, setting, value):
                raise _Reject("BADDATA")
        for axis in targets:
            setattr(axis, setting.replace("limit.", "limit_"), value)
        return "0"

    @staticmethod
    def _valid(axis: _Axis, setting: str, value: int) -> bool:
        if setting == "maxspeed":
            return 1 <= value <= axis.speed_data(axis.model.maxspeed_max)
        if setting == "accel":
            return 1 <= value <= axis.accel_data(axis.model.accel_max)
        if setting == "limit.min":
            return value < axis.limit_max
        return value > axis.limit_min  # limit.max

    # motion
    def _ready_for_motion(self, axis: _Axis) -> None:
        if not axis.driver_enabled:
            raise _Reject("DRIVERDISABLED")

    def _move(self, axis_no: int, mode: str, raw: str) -> str:
        value = _integer(raw)
        plan = []
        for axis in self._targets(axis_no):
            self._ready_for_motion(axis)
            if mode == "abs":
                target = value
            else:
                base = axis.target if axis.motion == "move" and axis.target is not None \
                    else axis.position()
                target = base + value
            if not axis.limit_min <= target <= axis.limit_max:
                raise _Reject("BADDATA")
            plan.append((axis, target))
        for axis, target in plan:
            axis.apply_dynamics()
            axis.notices.discard("NI")
            axis.stage.move_to(target * axis.ms)
            axis.motion, axis.target = "move", target
        return "0"

    def _home(self, axis_no: int) -> str:
        targets = self._targets(axis_no)
        for axis in targets:
            self._ready_for_motion(axis)
        for axis in targets:
            axis.apply_dynamics()
            axis.notices.discard("NI")
            axis.stage.start_homing()
            axis.motion, axis.target = "home", None
        return "0"

    def _stop(self, axis: _Axis) -> None:
        if axis.motion == "home":
            axis.stage.stop(immediate=True)  # the reference stays unknown
        elif axis.motion == "move" and axis.busy():
            axis.notices.add("NI")
            axis.stage.stop(immediate=False)
            end = axis.stage.target()
            axis.target = None if end is None else round(end / axis.ms)

    def _warnings(self, axis_no: int, *, clear: bool) -> str:
        targets = self._targets(axis_no)
        flags = [f for a in targets for f in a.flags()]
        if clear:
            for axis in targets:
                axis.faults.clear()
                axis.notices.clear()
        return " ".join([f"{len(flags):02d}", *flags])

    def _driver(self, axis_no: int, enable: bool) -> str:
        targets = self._targets(axis_no)
        if not enable and any(a.busy() for a in targets):
            raise _Reject("STATUSBUSY")
        for axis in targets:
            axis.driver_enabled = enable
        return "0"


def _integer(raw: str) -> int:
    text = raw[1:] if raw[:1] in "+-" else raw
    if not text.isdigit() or len(text) > 18:
        raise _Reject("BADDATA")
    return int(raw)
