"""Firmware emulator of a Newport SMC100 (CC) single-axis controller with its stage.

Written from the manual (Newport *SMC100CC & SMC100PP Single-Axis Motion Controller/Driver
User's Manual*) and the transcripts of MagAO-X ``smc100ccCtrl_test.cpp``, independently of
``drivers/`` (it imports nothing from there, so a misreading shared by the driver and the
emulator cannot pass unnoticed).

The device side of the ASCII protocol: requests ``<addr><CMD>[value|?]\\r\\n``; replies
echo address and command (``1TP`` → ``1TP10.500000\\r\\n``); motion and set commands
answer nothing and leave a command error letter in the ``TE`` latch when refused.

Default behaviour, declared once (see :data:`STAGE_MODELS` and :class:`Smc100Emulator`):

- Power-up: state ``0A`` NOT REFERENCED from RESET; the position counter reads 0
  wherever the stage really is (physical ``start_position``).
- ``OR`` homes (only in NOT REFERENCED): state ``1E`` HOMING while the stage drives to its
  home switch at the homing velocity ``OH``, then ``32`` READY from HOMING with the
  counter zeroed at the switch. A homing run longer than ``OT`` seconds ends in ``0B``
  with the homing time-out bit.
- ``PA``/``PR`` move (only in READY, ``32``–``38``): ``28`` MOVING along a trapezoidal
  profile with ``VA``/``AC``; the state stays MOVING for ``settle_s`` after the profile
  ends (the servo settling into its in-position window), then ``33`` READY from
  MOVING. Targets outside the software limits ``SL``/``SR`` are refused with ``G``.
  ``PR`` counts from the set-point (``TH``).
- ``ST`` decelerates a move at ``AC`` (→ ``33``) or aborts a homing run (→ ``0B``).
- ``MM0``/``MM1``: READY ↔ DISABLE (``3C``/``34``); ``MM1`` clears fault bits.
- ``RS`` reboots: nothing is answered for ``reset_busy_s`` (a "busy, no reply" window),
  then ``0A`` with the stored parameters and a counter that reads 0 again.
- ``PW1`` enters CONFIGURATION (``14``) from NOT REFERENCED; settings changed there are
  stored; ``PW0`` writes flash, answers nothing for ``pw0_busy_s`` (the manual allows
  up to 10 s), then ``0C``.
- Refusals latch a ``TE`` letter: ``H`` in NOT REFERENCED, ``I`` CONFIGURATION, ``J``
  DISABLE, ``K`` READY, ``L`` HOMING, ``M`` MOVING, ``E`` homing already started, ``C``
  parameter missing/out of range, ``A`` unknown command. The latch keeps the *last*
  error until ``TE`` reads it (reading clears it, a successful command does not).
- A limit switch reached during a move stops the stage, sets the end-of-run bit
  (``0x0002`` positive, ``0x0001`` negative) and disables the motor (``3D``). A
  fault injected with :meth:`Smc100Emulator.enter_error_state` sets positioner error
  bits (default ``0x0020`` following error), stops the stage and disables it
  (``3C``/``3D``), or aborts a homing run (``0B``).
- Requests for another address are ignored (another controller on the RS-485 chain);
  the "unsolicited" frame used for fault injection is such a neighbour's ``TS`` reply.

Command set. Emulated: ``AC ID MM OH OR OT PA PR PW RS SL SR ST TE TH TP TS VA VE``.
Not emulated (:data:`NOT_EMULATED`, the rest of the manual's command list): tuning and
drive parameters (``BA BH DV FD FE FF HT JR KD KI KP KV QIL QIR QIT SU``), jogging
(``JD JM``), analog/TTL I/O (``RA RB SB``), addressing and configuration dumps (``SA ZT
ZX``), the control-loop state ``SC``, simultaneous start ``SE``, the motion-time query
``PT`` and the error text ``TB``. Each is answered as the controller answers a command
it does not know: nothing, with ``A`` (unknown message code) latched for ``TE``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from hw_mocks.clock import Clock
from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.motion import StageMechanics

__all__ = ["NOT_EMULATED", "STAGE_MODELS", "Smc100Emulator", "StageModel"]

#: Commands of the manual's list this emulator answers as unknown (see the module).
NOT_EMULATED = ("BA", "BH", "DV", "FD", "FE", "FF", "HT", "JD", "JM", "JR", "KD", "KI",
                "KP", "KV", "PT", "QIL", "QIR", "QIT", "RA", "RB", "SA", "SB", "SC", "SE",
                "SU", "TB", "ZT", "ZX")


@dataclass(frozen=True)
class StageModel:
    """A stage an SMC100 drives: its identity, travel and power-up parameters."""

    stage_id: str
    units: str                       # "deg" or "mm"
    travel: tuple[float, float]      # hardware end-of-run switches (physical frame)
    software_limits: tuple[float, float]  # SL, SR at power-up (counter frame)
    velocity: float                  # VA at power-up, units/s
    velocity_max: float              # largest VA accepted
    acceleration: float              # AC at power-up, units/s²
    acceleration_max: float
    home_velocity: float             # OH at power-up, units/s
    start_position: float            # physical position at power-up


#: Stage models, chosen by the URL option ``kind=``. Values are plausible for a URS100BCC
#: rotation stage and an ILS100CC linear stage (home switch at mid-travel); they are the
#: emulator's defaults, not datasheet quotes.
STAGE_MODELS: dict[str, StageModel] = {
    "rotary": StageModel("URS100BCC", "deg", (-math.inf, math.inf), (-170.0, 170.0),
                         20.0, 20.0, 80.0, 320.0, 10.0, 37.0),
    "linear": StageModel("ILS100CC", "mm", (-51.0, 51.0), (-50.0, 50.0),
                         20.0, 100.0, 80.0, 400.0, 5.0, 12.0),
}

_FIRMWARE = "SMC_CC - Controller-driver version 3.0.1"
_REQUEST_RE = re.compile(rb"(\d{1,2})([A-Za-z]{2})(.*)", re.DOTALL)
_NUMBER_RE = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")

# State codes (second field of TS).
_NOTREF_RESET, _NOTREF_HOMING, _NOTREF_CONFIG = 0x0A, 0x0B, 0x0C
_CONFIG, _HOMING, _MOVING = 0x14, 0x1E, 0x28
_READY_HOMING, _READY_MOVING, _READY_DISABLE = 0x32, 0x33, 0x34
_DISABLE_READY, _DISABLE_MOVING = 0x3C, 0x3D

_BIT_NEG_END, _BIT_POS_END = 0x0001, 0x0002
_BIT_HOMING_TIMEOUT, _BIT_FOLLOWING = 0x0040, 0x0020


def _family(state: int) -> str:
    if 0x0A <= state <= 0x10:
        return "notref"
    if state == _CONFIG:
        return "config"
    if state == _HOMING:
        return "homing"
    if state == _MOVING:
        return "moving"
    if 0x32 <= state <= 0x38:
        return "ready"
    return "disable"


#: The TE letter a command refused in each state family latches.
_REFUSAL = {"notref": "H", "config": "I", "disable": "J", "ready": "K", "homing": "L",
            "moving": "M"}


class Smc100Emulator(FirmwareEmulator):
    """An SMC100CC controller at ``address`` driving a ``kind`` stage.

    Parameters
    ----------
    name
        Instance name (URL host part).
    address
        RS-485 address 1..31 the controller answers to.
    kind
        ``"rotary"`` (degrees) or ``"linear"`` (millimetres); selects a :class:`StageModel`.
    start_position
        Physical position at power-up; default from the stage model.
    reset_busy_s, pw0_busy_s
        Length of the "busy, no reply" windows after ``RS`` and ``PW0`` (clock seconds).
    homing_timeout_s
        ``OT`` at power-up.
    settle_s
        Time a move stays MOVING after its profile ends (clock seconds).
    """

    scheme = "simsmc"
    baudrate = 57600

    def __init__(
        self,
        name: str,
        *,
        address: int = 1,
        kind: str = "rotary",
        start_position: float | None = None,
        reset_busy_s: float = 0.5,
        pw0_busy_s: float = 3.0,
        homing_timeout_s: float = 120.0,
        settle_s: float = 0.01,
        clock: Clock | None = None,
        seed: int = 0,
        software_limits: tuple[float, float] | None = None,
    ) -> None:
        super().__init__(name, clock=clock, seed=seed)
        if not 1 <= address <= 31:
            raise ValueError(f"SMC100 address must be 1..31, got {address}")
        if kind not in STAGE_MODELS:
            raise ValueError(f"kind must be one of {sorted(STAGE_MODELS)}, got {kind!r}")
        self.address = address
        self.model = STAGE_MODELS[kind]
        self.kind = kind
        self.reset_busy_s = float(reset_busy_s)
        self.pw0_busy_s = float(pw0_busy_s)
        self.settle_s = float(settle_s)
        self._motion_end = 0.0
        self.serial_number = f"B{10000 + seed % 90000:05d}"
        start = self.model.start_position if start_position is None else start_position
        self.stage = StageMechanics(
            self.clock,
            velocity=self.model.velocity,
            acceleration=self.model.acceleration,
            travel=self.model.travel,
            home_velocity=self.model.home_velocity,
            start_position=float(start),
        )
        #: Parameters in flash (restored by RS); ``params`` holds the working copies.
        self.stored = {
            "VA": self.model.velocity, "AC": self.model.acceleration,
            "OH": self.model.home_velocity, "OT": float(homing_timeout_s),
            "SL": self.model.software_limits[0], "SR": self.model.software_limits[1],
        }
        if software_limits is not None:  # a controller configured for more travel (SL/SR)
            self.stored["SL"], self.stored["SR"] = (float(v) for v in software_limits)
        self.params = dict(self.stored)
        self._apply_params()
        self.state = _NOTREF_RESET
        self.error_latch = "@"
        self.fault_bits = 0
        self.setpoint = 0.0
        self._busy_until = -math.inf
        self._after_busy: int | None = None
        self._home_started = 0.0
        self._home_from = 0.0
        self._home_fail_at: float | None = None
        #: Requests swallowed by a busy window (for tests).
        self.ignored: list[bytes] = []

    # backdoor -----------------------------------------------------------------
    def ts_value(self) -> str:
        """The six hex digits ``TS`` would answer now."""
        with self.lock:
            self._update()
            return f"{self._error_bits():04X}{self.state:02X}"

    def is_busy(self) -> bool:
        with self.lock:
            return self.clock.now() < self._busy_until

    # FirmwareEmulator ---------------------------------------------------------
    def _handle_input(self, buf: bytearray) -> list[bytes]:
        replies: list[bytes] = []
        while True:
            end = buf.find(b"\r\n")
            if end < 0:
                if len(buf) > 256:  # a line this long is noise; the UART drops it
                    buf.clear()
                return replies
            line = bytes(buf[:end])
            del buf[: end + 2]
            # Software flow-control characters are link control, not data.
            line = line.replace(b"\x11", b"").replace(b"\x13", b"")
            reply = self._execute(line)
            if reply is not None:
                replies.append(reply)

    def poll(self) -> list[bytes]:
        with self.lock:
            self._update()
        return []

    def unsolicited_frame(self) -> bytes:
        """A neighbour on the RS-485 chain answering its own ``TS``."""
        neighbour = self.address % 31 + 1
        return f"{neighbour}TS000033\r\n".encode("ascii")

    def enter_error_state(self, code: str | None = None) -> None:
        """Set positioner error bits (``code``: 4 hex digits, default following error)."""
        with self.lock:
            try:
                bits = int(code, 16) if code else _BIT_FOLLOWING
            except ValueError:
                raise ValueError(f"SMC100 error state code must be 4 hex digits of "
                                 f"positioner error bits, got {code!r}") from None
            self._update()
            self.fault_bits |= bits
            family = _family(self.state)
            if family == "homing":
                self.stage.stop(immediate=True)
                self.state = _NOTREF_HOMING
            elif family == "moving":
                self.stage.stop(immediate=True)
                self.state = _DISABLE_MOVING
            elif family == "ready":
                self.state = _DISABLE_READY
            self.setpoint = self.stage.position()

    # state machine ------------------------------------------------------------
    def _update(self) -> None:
        now = self.clock.now()
        if self._after_busy is not None and now >= self._busy_until:
            self.state, self._after_busy = self._after_busy, None
        if self.state == _HOMING:
            # Checked before asking the stage: a late poll must not see a homing run
            # finish that OT had already aborted.
            if self._home_fail_at is not None and now >= self._home_fail_at:
                travelled = (self._home_fail_at - self._home_started) * self.stage.home_velocity
                where = self._home_from - math.copysign(travelled, self._home_from)
                self.stage.teleport(where)  # where the run stopped when OT expired
                self.stage.homed = False
                self.fault_bits |= _BIT_HOMING_TIMEOUT
                self.state = _NOTREF_HOMING
            elif not self.stage.is_homing() and self.stage.homed:
                self.state = _READY_HOMING
                self.setpoint = 0.0
        elif self.state == _MOVING and not self.stage.is_moving():
            if self.stage.at_limit is not None:
                # End of run reached: the motor is switched off where the switch tripped.
                self.state = _DISABLE_MOVING
                self.setpoint = self.stage.position()
            elif now >= self._motion_end + self.settle_s:
                self.state = _READY_MOVING

    def _error_bits(self) -> int:
        bits = self.fault_bits
        if self.stage.at_limit == "forward":
            bits |= _BIT_POS_END
        elif self.stage.at_limit == "reverse":
            bits |= _BIT_NEG_END
        return bits

    def _apply_params(self) -> None:
        self.stage.velocity = self.params["VA"]
        self.stage.acceleration = self.params["AC"]
        self.stage.home_velocity = self.params["OH"]

    def _refuse(self, letter: str | None = None) -> None:
        self.error_latch = letter or _REFUSAL[_family(self.state)]

    # command interpreter ------------------------------------------------------
    def _execute(self, line: bytes) -> bytes | None:
        now = self.clock.now()
        if now < self._busy_until:
            self.ignored.append(line)  # rebooting or writing flash: deaf
            return None
        self._update()
        match = _REQUEST_RE.fullmatch(line)
        if match is None:
            self.error_latch = "A"
            return None
        address = int(match.group(1))
        if address != self.address:
            if not 1 <= address <= 31:
                self.error_latch = "B"
            return None  # addressed to another controller on the chain
        try:
            command = match.group(2).decode("ascii")
            arg = match.group(3).decode("ascii").strip()
        except UnicodeDecodeError:
            self.error_latch = "A"
            return None
        handler = getattr(self, f"_cmd_{command}", None)
        if handler is None:
            self.error_latch = "A"
            return None
        value = handler(arg)
        if value is None:
            return None
        return f"{self.address}{command}{value}\r\n".encode("ascii")

    def _number(self, arg: str) -> float | None:
        if not _NUMBER_RE.fullmatch(arg):
            self.error_latch = "C"
            return None
        value = float(arg)
        if not math.isfinite(value):
            self.error_latch = "C"
            return None
        return value

    # queries: answered in every state
    def _cmd_TS(self, arg: str) -> str | None:
        return None if self._no_arg(arg) else f"{self._error_bits():04X}{self.state:02X}"

    def _cmd_TE(self, arg: str) -> str | None:
        if self._no_arg(arg):
            return None
        letter, self.error_latch = self.error_latch, "@"
        return letter

    def _cmd_TP(self, arg: str) -> str | None:
        return None if self._no_arg(arg) else f"{self.stage.position():.6f}"

    def _cmd_TH(self, arg: str) -> str | None:
        if self._no_arg(arg):
            return None
        target = self.stage.target()
        return f"{(self.setpoint if target is None else target):.6f}"

    def _cmd_VE(self, arg: str) -> str | None:
        return None if self._no_arg(arg) else f" {_FIRMWARE}"

    def _cmd_ID(self, arg: str) -> str | None:
        if arg != "?":
            self.error_latch = "C" if arg else "A"  # setting the stage ID needs PW1
            return None
        return f"{self.model.stage_id}_{self.serial_number}"

    def _no_arg(self, arg: str) -> bool:
        if arg:
            self.error_latch = "C"
            return True
        return False

    # motion
    def _cmd_OR(self, arg: str) -> None:
        family = _family(self.state)
        if family == "homing":
            self._refuse("E")
        elif family != "notref":
            self._refuse()
        else:
            self.fault_bits = 0
            self._home_from = self.stage.physical_position()
            self.stage.start_homing()
            self._home_started = self.clock.now()
            run = abs(self._home_from) / self.stage.home_velocity
            over = run > self.params["OT"]
            self._home_fail_at = self._home_started + self.params["OT"] if over else None
            self.state = _HOMING

    def _cmd_PA(self, arg: str) -> None:
        self._move(arg, relative=False)

    def _cmd_PR(self, arg: str) -> None:
        self._move(arg, relative=True)

    def _move(self, arg: str, *, relative: bool) -> None:
        if _family(self.state) != "ready":
            self._refuse()
            return
        value = self._number(arg) if arg and arg != "?" else None
        if value is None:
            self.error_latch = "C"
            return
        target = self.setpoint + value if relative else value
        if not self.params["SL"] <= target <= self.params["SR"]:
            self.error_latch = "G"
            return
        self.setpoint = target
        self._motion_end = self.clock.now() + self.stage.move_to(target)
        self.state = _MOVING
        self._update()  # a zero-length move is over at once

    def _cmd_ST(self, arg: str) -> None:
        family = _family(self.state)
        if family == "moving":
            speed = abs(self.stage.velocity_now())
            self._motion_end = self.clock.now() + speed / self.stage.acceleration
            self.stage.stop(immediate=False)
            target = self.stage.target()
            self.setpoint = self.stage.position() if target is None else target
        elif family == "homing":
            self.stage.stop(immediate=True)
            self.state = _NOTREF_HOMING
        # Elsewhere there is nothing to stop; ST is accepted silently.

    def _cmd_MM(self, arg: str) -> None:
        family = _family(self.state)
        if arg not in ("0", "1"):
            self.error_latch = "C"
        elif family not in ("ready", "disable"):
            self._refuse()
        elif arg == "0" and family == "ready":
            self.state = _DISABLE_READY
        elif arg == "1" and family == "disable":
            self.fault_bits = 0
            self.state = _READY_DISABLE
            self.setpoint = self.stage.position()

    def _cmd_RS(self, arg: str) -> None:
        self.stage.stop(immediate=True)
        # The encoder counter restarts at 0 where the stage stands; the reference is lost.
        self.stage.counter_offset = self.stage.physical_position()
        self.stage.homed = False
        self.stage.at_limit = None
        self.params = dict(self.stored)
        self._apply_params()
        self.fault_bits = 0
        self.error_latch = "@"
        self.setpoint = 0.0
        self._busy_until = self.clock.now() + self.reset_busy_s
        self._after_busy = _NOTREF_RESET

    def _cmd_PW(self, arg: str) -> None:
        family = _family(self.state)
        if arg == "1":
            if family == "notref":
                self.state = _CONFIG
            else:
                self._refuse()
        elif arg == "0":
            if family == "config":
                self.stored = dict(self.params)
                self._busy_until = self.clock.now() + self.pw0_busy_s
                self._after_busy = _NOTREF_CONFIG
            else:
                self._refuse("D")
        else:
            self.error_latch = "C"

    # parameters
    def _param(self, key: str, arg: str, valid) -> str | None:
        if arg == "?":
            return f"{self.params[key]:.6f}"
        family = _family(self.state)
        if family in ("moving", "homing"):
            self._refuse()
            return None
        value = self._number(arg)
        if value is None:
            return None
        if not valid(value):
            self.error_latch = "C"
            return None
        self.params[key] = value
        if family == "config":
            self.stored[key] = value
        self._apply_params()
        return None

    def _cmd_VA(self, arg: str) -> str | None:
        return self._param("VA", arg, lambda v: 0.0 < v <= self.model.velocity_max)

    def _cmd_AC(self, arg: str) -> str | None:
        return self._param("AC", arg, lambda v: 0.0 < v <= self.model.acceleration_max)

    def _cmd_OH(self, arg: str) -> str | None:
        return self._param("OH", arg, lambda v: 0.0 < v <= self.model.velocity_max)

    def _cmd_OT(self, arg: str) -> str | None:
        return self._param("OT", arg, lambda v: 0.0 < v <= 1e3)

    # The manual's rule: the negative limit is <= 0 and the positive one >= 0.
    def _cmd_SL(self, arg: str) -> str | None:
        return self._param("SL", arg, lambda v: -1e12 <= v <= 0.0)

    def _cmd_SR(self, arg: str) -> str | None:
        return self._param("SR", arg, lambda v: 0.0 <= v <= 1e12)
