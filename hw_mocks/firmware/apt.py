"""Firmware emulator of Thorlabs APT motion controllers: K10CR1 and KDC101 (+ stage).

Written from the protocol description (*Thorlabs APT Controllers Host-Controller
Communications Protocol*, Issue 23 (2018) and Issue 25 (2020)), not from the driver: it
imports nothing from ``drivers/`` and packs its own bytes, so a bug shared by both sides
cannot pass.

Frames are little-endian: a 6-byte header ``<HBBBB`` (id, param1, param2, dest, source),
or ``<HHBB`` (id, data length, dest | 0x80, source) followed by the data. The device is
address 0x50, the host 0x01.

Default behaviour, declared once in :data:`PROFILES` and :class:`AptDefaults`:

- Motion: trapezoidal profiles on a :class:`~hw_mocks.motion.StageMechanics` (``.stage``,
  physical units: degrees or millimetres); counts and device velocity units are
  converted here. The controller powers up with its channel *disabled* and not homed.
  Source of the disabled channel: field practice, not the protocol document (which does
  not state the power-up state): hosts written against the hardware enable the channel
  before they move (PnPQ's K10CR1 driver sends MOD_SET_CHANENABLESTATE at start;
  thorlabs_apt_device's KDC101 users call ``set_enabled(True)``). It is modelled in the
  pessimistic state on purpose, so that a host that forgets to enable fails here and not
  on a bench that a previous program left disabled.
- Quirks seen in the field, modelled on purpose:

  * home velocity is zero at power-up, so MOT_MOVE_HOME never completes until the host
    writes MOT_SET_HOMEPARAMS (pylablib docs; Thorlabs Motion_Control_Examples #33;
    qpit/thorlabs_apt #13, #24);
  * a reconnect finds stale unsolicited frames (a partial one first) in the pipe
    (PnPQ ``_clean_buffer``);
  * a move stops up to ``stop_short_counts`` counts short of its target (PnPQ
    ``waveplate_thorlabs_k10cr1.py``: "will sometimes stop a small distance away");
  * the K10CR1 does not answer MOD_SET_CHANENABLESTATE (nor, per the protocol, does any
    SET message; ``replies_to_set_enable`` makes an emulator that does, to check hosts
    tolerate it).

- Settle (KDC101 servo): after a move's profile the status keeps ACTIVE and lacks
  SETTLED for ``settle_s`` (the position loop's in-position window), and MOVE_COMPLETED
  follows only then. The open-loop K10CR1 settles at once.
- MOVE_COMPLETED (14-byte status form), MOVE_STOPPED (same form) and MOVE_HOMED (short)
  are sent unsolicited when motion ends. HW_START_UPDATEMSGS starts a status stream every
  ``update_period_s`` of emulator time (GET_STATUSUPDATE on the stepper K10CR1,
  GET_DCSTATUSUPDATE on the KDC101).
- Limit switches at the ends of the stage travel set status bit 0 (CW, forward) or
  bit 1 (CCW, reverse).
- Error state (fault injection, :meth:`AptEmulator.enter_error_state`): the stage stops,
  status bits ERROR | MOTION_ERROR are set, an HW_RICHRESPONSE is sent, and every motion
  command is answered with an HW_RICHRESPONSE naming it and not executed. Re-enabling
  the channel (MOD_SET_CHANENABLESTATE enable) clears it: that is this emulator's model
  of a recovery, not a documented device behaviour.
- Home offset: after the home switch (physical 0) the stage moves by the offset from the
  home parameters and zeroes its counter there; MOVE_HOMED follows.
- Motion commands on a disabled channel are ignored (no motion, no reply).
- MOT_MOVE_VELOCITY (p2 = 1 forward, 2 reverse) turns the stage continuously at the
  velocity parameters' maximum velocity, accelerating at their acceleration, until
  MOT_MOVE_STOP (then MOVE_STOPPED) or a limit switch; a continuous-rotation stage never
  meets one. The position counter is a 32-bit register and wraps (the K10CR1's "overflows
  after 43 full turns", QMI's k10crx documentation).
"""

from __future__ import annotations

import math
import random
import struct
import zlib
from dataclasses import dataclass, replace
from typing import ClassVar

from hw_mocks.clock import Clock
from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.motion import StageMechanics

__all__ = ["PROFILES", "AptDefaults", "AptEmulator", "AptStageProfile"]

# Addresses and message ids (APT protocol names), kept private to the device side.
_HOST = 0x01
_DEV = 0x50
_LONG = 0x80

_HW_RESPONSE = 0x0080
_HW_RICHRESPONSE = 0x0081
_HW_REQ_INFO = 0x0005
_HW_GET_INFO = 0x0006
_HW_START_UPDATEMSGS = 0x0011
_HW_STOP_UPDATEMSGS = 0x0012
_MOD_IDENTIFY = 0x0223
_MOD_SET_CHANENABLESTATE = 0x0210
_MOD_REQ_CHANENABLESTATE = 0x0211
_MOD_GET_CHANENABLESTATE = 0x0212
_MOT_SET_POSCOUNTER = 0x0410
_MOT_REQ_POSCOUNTER = 0x0411
_MOT_GET_POSCOUNTER = 0x0412
_MOT_SET_VELPARAMS = 0x0413
_MOT_REQ_VELPARAMS = 0x0414
_MOT_GET_VELPARAMS = 0x0415
_MOT_REQ_STATUSBITS = 0x0429
_MOT_GET_STATUSBITS = 0x042A
_MOT_SET_HOMEPARAMS = 0x0440
_MOT_REQ_HOMEPARAMS = 0x0441
_MOT_GET_HOMEPARAMS = 0x0442
_MOT_MOVE_HOME = 0x0443
_MOT_MOVE_HOMED = 0x0444
_MOT_MOVE_RELATIVE = 0x0448
_MOT_MOVE_ABSOLUTE = 0x0453
_MOT_MOVE_VELOCITY = 0x0457
_MOT_MOVE_COMPLETED = 0x0464
_MOT_MOVE_STOP = 0x0465
_MOT_MOVE_STOPPED = 0x0466
_MOT_REQ_STATUSUPDATE = 0x0480
_MOT_GET_STATUSUPDATE = 0x0481
_MOT_REQ_DCSTATUSUPDATE = 0x0490
_MOT_GET_DCSTATUSUPDATE = 0x0491
_MOT_ACK_DCSTATUSUPDATE = 0x0492

# Status bits (32-bit word).
_CW_LIMIT = 0x1          # forward hardware limit
_CCW_LIMIT = 0x2         # reverse hardware limit
_MOVING_CW = 0x10
_MOVING_CCW = 0x20
_CONNECTED = 0x100
_HOMING = 0x200
_HOMED = 0x400
_SETTLED = 0x2000
_MOTION_ERROR = 0x4000
_ACTIVE = 0x20000000
_ERROR = 0x40000000
_ENABLED = 0x80000000

# KDC101 time base: velocities are counts/sample-period scaled by 2^16, sample period
# 2048 / 6 MHz (pylablib ``_calculate_scale``, time_conv=2048/6E6).
_KDC_T = 2048.0 / 6.0e6


@dataclass(frozen=True)
class AptStageProfile:
    """What a controller + stage pair looks like from the wire.

    Units are the stage's: degrees (rotary) or millimetres (linear).
    """

    controller: str                 # model string in HW_GET_INFO
    stage: str
    serial_prefix: int              # first two digits of the 8-digit serial number
    stage_id: int                   # HW_GET_INFO bytes 76..77 (KDC101 autodetection)
    firmware: tuple[int, int, int]  # (major, interim, minor)
    counts_per_unit: float
    velocity_scale: float           # device velocity units per unit/s
    acceleration_scale: float       # device acceleration units per unit/s²
    travel: tuple[float, float]     # physical travel; limit switches at the ends
    start_position: float          # physical position at power-up
    velocity: float                 # power-up max velocity, unit/s
    acceleration: float             # power-up acceleration, unit/s²
    stop_short_counts: int          # a move ends up to this many counts short
    stepper: bool                   # stepper (STATUSUPDATE) or DC servo (DCSTATUSUPDATE)
    settle_s: float = 0.0           # in-position window after a move's profile, seconds


_K10CR1_CPU = 409600.0 / 3.0  # 409600 microsteps per 3 degrees of the worm drive
_PRM1_CPU = 1919.6418578623391  # counts per degree, "what it says in the manual"
_MTS25_CPU = 34304.0  # counts per mm of the Z8 motor stages (34304 = 512 x 67)

def _kdc101(stage: str, *, stage_id: int, counts_per_unit: float,
            travel: tuple[float, float], start_position: float, velocity: float,
            acceleration: float) -> AptStageProfile:
    """A stage on a KDC101 DC servo controller: its velocity and acceleration units
    follow from the encoder counts and the servo period."""
    return AptStageProfile(
        controller="KDC101", stage=stage, serial_prefix=27, stage_id=stage_id,
        firmware=(2, 0, 4), counts_per_unit=counts_per_unit,
        velocity_scale=counts_per_unit * _KDC_T * 65536.0,
        acceleration_scale=counts_per_unit * _KDC_T * _KDC_T * 65536.0,
        travel=travel, start_position=start_position, velocity=velocity,
        acceleration=acceleration, stop_short_counts=5, stepper=False,
        # A servo holds its position loop for a moment after the profile before it calls
        # itself settled (status bit 0x2000). The length is this emulator's choice, not a
        # datasheet figure; the stepper K10CR1 runs open loop and has none.
        settle_s=0.02,
    )


#: Every (controller, stage) the emulator knows, keyed by ``(model, stage)``.
PROFILES: dict[tuple[str, str], AptStageProfile] = {
    ("K10CR1", "K10CR1"): AptStageProfile(
        controller="K10CR1", stage="K10CR1", serial_prefix=55, stage_id=0,
        firmware=(1, 0, 3), counts_per_unit=_K10CR1_CPU,
        # Stepper controller: vel = counts/s * 53.68, acc = counts/s² * 204.94e-6 * 53.68
        # (QMI k10crx.py: 7329109 per deg/s and 1502 per deg/s²).
        velocity_scale=7329109.0, acceleration_scale=1502.0,
        travel=(-math.inf, math.inf), start_position=37.0,
        velocity=10.0, acceleration=10.0, stop_short_counts=100, stepper=True,
    ),
    ("KDC101", "PRM1-Z8"): _kdc101(
        "PRM1-Z8", stage_id=6, counts_per_unit=_PRM1_CPU, travel=(-math.inf, math.inf),
        start_position=-21.5, velocity=10.0, acceleration=10.0,
    ),
    ("KDC101", "MTS25-Z8"): _kdc101(
        "MTS25-Z8", stage_id=7, counts_per_unit=_MTS25_CPU, travel=(0.0, 25.0),
        start_position=8.0, velocity=2.0, acceleration=1.5,
    ),
}


@dataclass(frozen=True)
class AptDefaults:
    """Behaviour shared by every APT emulator (override with :func:`dataclasses.replace`)."""

    #: Home velocity at power-up, units/s: zero, the field quirk.
    power_up_home_velocity: float = 0.0
    #: Status stream period after HW_START_UPDATEMSGS (10 Hz), emulator seconds.
    update_period_s: float = 0.1
    #: Complete stale status frames found in the pipe on a reconnect (plus a partial one).
    stale_frames_on_reconnect: int = 2
    #: Answer MOD_SET_CHANENABLESTATE with a GET (no real K10CR1 does).
    replies_to_set_enable: bool = False
    #: Code in the HW_RICHRESPONSE of an error state when none is given.
    error_code: int = 0x0010


DEFAULTS = AptDefaults()


# --------------------------------------------------------------------------- framing


def _short(msg_id: int, p1: int = 0, p2: int = 0) -> bytes:
    return struct.pack("<HBBBB", msg_id, p1, p2, _HOST, _DEV)


def _long(msg_id: int, data: bytes) -> bytes:
    return struct.pack("<HHBB", msg_id, len(data), _HOST | _LONG, _DEV) + data


class AptEmulator(FirmwareEmulator):
    """One single-channel APT controller with its stage.

    Parameters
    ----------
    name
        Instance name (URL host part).
    model
        ``"K10CR1"`` or ``"KDC101"``.
    stage
        Stage on a KDC101: ``"PRM1-Z8"`` (default) or ``"MTS25-Z8"``; ignored on K10CR1.
    defaults
        Shared behaviour (:class:`AptDefaults`).
    start_position
        Physical power-up position, overriding the profile.
    stop_short_counts
        Overrides the profile's maximum shortfall of a move, in counts.
    """

    scheme: ClassVar[str] = "simapt"
    baudrate: ClassVar[int] = 115200

    def __init__(
        self,
        name: str,
        *,
        model: str = "K10CR1",
        stage: str | None = None,
        clock: Clock | None = None,
        seed: int = 0,
        defaults: AptDefaults = DEFAULTS,
        start_position: float | None = None,
        stop_short_counts: int | None = None,
    ) -> None:
        super().__init__(name, clock=clock, seed=seed)
        model = model.upper()
        if model == "K10CR1":
            stage = "K10CR1"
        elif stage is None:
            stage = "PRM1-Z8"
        key = (model, stage.upper())
        if key not in PROFILES:
            known = ", ".join(f"{m}/{s}" for m, s in PROFILES)
            raise ValueError(f"unknown APT model/stage {model}/{stage}; known: {known}")
        profile = PROFILES[key]
        if start_position is not None:
            profile = replace(profile, start_position=float(start_position))
        if stop_short_counts is not None:
            profile = replace(profile, stop_short_counts=int(stop_short_counts))
        self.profile = profile
        self.defaults = defaults
        self._rng = random.Random(seed)
        self.serial_number = profile.serial_prefix * 1_000_000 + zlib.crc32(
            name.encode()) % 1_000_000
        self.stage = StageMechanics(
            self.clock,
            velocity=profile.velocity,
            acceleration=profile.acceleration,
            travel=profile.travel,
            home_velocity=defaults.power_up_home_velocity,
            start_position=profile.start_position,
        )
        # Controller registers, in device units as the host wrote them.
        self.enabled = False
        self.min_velocity_du = 0
        self.velocity_du = round(profile.velocity * profile.velocity_scale)
        self.acceleration_du = round(profile.acceleration * profile.acceleration_scale)
        self.home_direction = 2
        self.home_limit_switch = 1
        self.home_velocity_du = round(defaults.power_up_home_velocity
                                      * profile.velocity_scale)
        self.home_offset_counts = 0
        self.updates_on = False
        self.error_code: int | None = None
        self.identify_count = 0
        self._next_update = 0.0
        self._motion: str | None = None  # "move" | "home" | "offset" | "stop"
        self._settled_at = -math.inf  # end of the present move's settle window
        self._direction = 0
        self._pending: list[bytes] = []  # unsolicited frames for the next poll
        self._unsolicited_turn = 0

    # ------------------------------------------------------------------ units
    #: How far (stage units) a continuous move aims: beyond any travel, yet short enough
    #: that its profile keeps 10⁻⁷-unit resolution in double precision.
    CONTINUOUS_UNITS: ClassVar[float] = 1e9

    def _counts(self, units: float) -> int:
        return round(units * self.profile.counts_per_unit)

    def position_counts(self) -> int:
        """The controller's position counter now (a 32-bit register: it wraps)."""
        with self.lock:
            return (self._counts(self.stage.position()) + 2**31) % 2**32 - 2**31

    # ------------------------------------------------------------------ status
    def status_bits(self) -> int:
        with self.lock:
            st = self.stage
            bits = _CONNECTED
            if self.enabled:
                bits |= _ENABLED
            moving = st.is_moving() or self._motion == "offset"
            if moving:
                v = st.velocity_now()
                direction = (v > 0) - (v < 0) or self._direction
                bits |= _ACTIVE | (_MOVING_CW if direction >= 0 else _MOVING_CCW)
            elif self._settling():
                bits |= _ACTIVE  # profile done, position loop still settling
            else:
                bits |= _SETTLED
            if self._motion in ("home", "offset"):
                bits |= _HOMING
            elif st.homed:
                bits |= _HOMED
            if st.at_limit == "forward":
                bits |= _CW_LIMIT
            elif st.at_limit == "reverse":
                bits |= _CCW_LIMIT
            if self.error_code is not None:
                bits |= _ERROR | _MOTION_ERROR
            return bits

    def _status_packet(self) -> bytes:
        # <HlhHL: chan, position, velocity, reserved, status. The velocity word is left 0:
        # its scaling is not documented for these controllers.
        return struct.pack("<HlhHL", 1, self.position_counts(), 0, 0, self.status_bits())

    def status_update_frame(self) -> bytes:
        """The status-update frame this controller streams (backdoor for tests)."""
        with self.lock:
            return self._status_update_frame()

    def send_unsolicited(self, data: list[bytes]) -> None:
        """Backdoor for tests: put bytes on the wire with the next poll, unasked."""
        with self.lock:
            self._pending += data

    def _status_update_frame(self) -> bytes:
        if self.profile.stepper:
            data = struct.pack("<HllL", 1, self.position_counts(), 0, self.status_bits())
            return _long(_MOT_GET_STATUSUPDATE, data)
        return _long(_MOT_GET_DCSTATUSUPDATE, self._status_packet())

    def _rich_response(self, msg_id: int, code: int, notes: str) -> bytes:
        return _long(_HW_RICHRESPONSE,
                     struct.pack("<HH64s", msg_id, code, notes.encode("ascii")[:63]))

    # ------------------------------------------------------------------ time
    def _advance(self) -> list[bytes]:
        """Frames produced by motion that ended since the last look."""
        out: list[bytes] = []
        st = self.stage
        if self._motion == "home" and not st.is_homing():
            if not st.homed:  # homing was interrupted (stop)
                self._motion = None
            elif self.home_offset_counts:
                # Leave the switch by the offset, then call that zero.
                st.move_to(self.home_offset_counts / self.profile.counts_per_unit)
                self._motion = "offset"
                self._direction = 1 if self.home_offset_counts > 0 else -1
            else:
                self._motion = None
                out.append(_short(_MOT_MOVE_HOMED, 1, 0))
        if self._motion == "offset" and not st.is_moving():
            st.counter_offset = st.physical_position()
            st.homed = True
            self._motion = None
            out.append(_short(_MOT_MOVE_HOMED, 1, 0))
        elif (self._motion in ("move", "stop", "velocity") and not st.is_moving()
              and not self._settling()):
            # a continuous move ends only at a limit switch: it stopped
            kind = _MOT_MOVE_COMPLETED if self._motion == "move" else _MOT_MOVE_STOPPED
            self._motion = None
            out.append(_long(kind, self._status_packet()))
        return out

    def _settling(self) -> bool:
        """A move's profile has ended but its settle window has not."""
        return (self._motion == "move" and not self.stage.is_moving()
                and self.clock.now() < self._settled_at)

    def poll(self) -> list[bytes]:
        with self.lock:
            out = self._pending + self._advance()
            self._pending = []
            if self.updates_on:
                now = self.clock.now()
                if now >= self._next_update:
                    out.append(self._status_update_frame())
                    # One frame per look at most: a fast clock must not flood the link.
                    self._next_update = max(self._next_update + self.defaults.update_period_s,
                                            now)
            return out

    def on_connect(self) -> list[bytes]:
        super().on_connect()
        with self.lock:
            if self.connections <= 1:
                return []
            # What a previous session left in the FTDI buffer: the tail of a status
            # frame (partial data), some whole ones, a move-completed.
            frame = self._status_update_frame()
            stale = [frame[-5:]]
            stale += [frame] * self.defaults.stale_frames_on_reconnect
            stale.append(_long(_MOT_MOVE_COMPLETED, self._status_packet()))
            return stale

    # ------------------------------------------------------------------ faults
    def unsolicited_frame(self) -> bytes:
        with self.lock:
            self._unsolicited_turn += 1
            if self._unsolicited_turn % 2:
                return self._status_update_frame()
            return _long(_MOT_MOVE_COMPLETED, self._status_packet())

    def enter_error_state(self, code: str | None = None) -> None:
        with self.lock:
            value = int(code, 0) if code else self.defaults.error_code
            self.error_code = value
            self.stage.stop(immediate=True)
            self._motion = None
            self._pending.append(self._rich_response(0, value, "emulated motion error"))

    # ------------------------------------------------------------------ input
    def _handle_input(self, buf: bytearray) -> list[bytes]:
        out = self._advance()
        while len(buf) >= 6:
            msg_id, p1, p2, dest, source = struct.unpack_from("<HBBBB", buf)
            long = bool(dest & _LONG)
            if (dest & ~_LONG) != _DEV or source != _HOST:
                del buf[0]  # not a header addressed to us: resynchronise
                continue
            length = p1 | (p2 << 8) if long else 0
            if long and not 0 < length <= 255:
                del buf[0]
                continue
            if len(buf) < 6 + length:
                break
            data = bytes(buf[6:6 + length]) if long else None
            del buf[:6 + length]
            out += self._dispatch(msg_id, p1, p2, data)
        return out

    def _dispatch(self, msg_id: int, p1: int, p2: int, data: bytes | None) -> list[bytes]:
        handler = self._HANDLERS.get(msg_id)
        if handler is None:
            return []  # unknown messages are ignored, as by the firmware
        return handler(self, p1, p2, data)

    @staticmethod
    def _chan_value(data: bytes | None) -> tuple[int, int] | None:
        if data is None or len(data) != 6:
            return None
        return struct.unpack("<Hi", data)

    # identity and configuration
    def _req_info(self, p1, p2, data):
        p = self.profile
        space = bytearray(12)
        struct.pack_into("<H", space, 10, p.stage_id)
        fw = bytes([p.firmware[2], p.firmware[1], p.firmware[0], 0])
        notes = f"APT {p.controller} {p.stage} (emulated)".encode("ascii")
        payload = struct.pack("<l8sH4s48s12sHHH", self.serial_number,
                              p.controller.encode("ascii"), 16, fw, notes,
                              bytes(space), 1, 0, 1)
        return [_long(_HW_GET_INFO, payload)]

    def _identify(self, p1, p2, data):
        self.identify_count += 1
        return []

    def _start_updates(self, p1, p2, data):
        self.updates_on = True
        self._next_update = self.clock.now()
        return []

    def _stop_updates(self, p1, p2, data):
        self.updates_on = False
        return []

    def _set_enable(self, p1, p2, data):
        if p2 == 1:
            self.enabled = True
            self.error_code = None  # the emulator's recovery path, see module docs
        elif p2 == 2:
            self.enabled = False
            self.stage.stop(immediate=True)
            if self._motion is not None:
                self._motion = "stop"
        if self.defaults.replies_to_set_enable:
            return self._req_enable(p1, 0, None)
        return []

    def _req_enable(self, p1, p2, data):
        return [_short(_MOD_GET_CHANENABLESTATE, p1 or 1, 1 if self.enabled else 2)]

    def _set_poscounter(self, p1, p2, data):
        cv = self._chan_value(data)
        if cv is not None:
            self.stage.counter_offset = (self.stage.physical_position()
                                         - cv[1] / self.profile.counts_per_unit)
        return []

    def _req_poscounter(self, p1, p2, data):
        return [_long(_MOT_GET_POSCOUNTER, struct.pack("<Hi", p1 or 1, self.position_counts()))]

    def _set_velparams(self, p1, p2, data):
        if data is None or len(data) != 14:
            return []
        _chan, vmin, acc, vmax = struct.unpack("<Hiii", data)
        self.min_velocity_du, self.acceleration_du, self.velocity_du = vmin, acc, vmax
        # A zero velocity would never arrive; the tiny floor keeps the profile finite.
        self.stage.velocity = max(vmax / self.profile.velocity_scale, 1e-9)
        self.stage.acceleration = max(acc / self.profile.acceleration_scale, 1e-9)
        return []

    def _req_velparams(self, p1, p2, data):
        payload = struct.pack("<Hiii", p1 or 1, self.min_velocity_du, self.acceleration_du,
                              self.velocity_du)
        return [_long(_MOT_GET_VELPARAMS, payload)]

    def _set_homeparams(self, p1, p2, data):
        if data is None or len(data) != 14:
            return []
        _chan, direction, switch, vel, offset = struct.unpack("<HHHii", data)
        self.home_direction, self.home_limit_switch = direction, switch
        self.home_velocity_du, self.home_offset_counts = vel, offset
        # StageMechanics times homing from its start at one speed: a new speed mid-way
        # applies from now on, from where the stage is (not retroactively).
        homing = self.stage.is_homing()
        if homing:
            self.stage.stop(immediate=True)
        self.stage.home_velocity = vel / self.profile.velocity_scale
        if homing:
            self.stage.start_homing()
        return []

    def _req_homeparams(self, p1, p2, data):
        payload = struct.pack("<HHHii", p1 or 1, self.home_direction, self.home_limit_switch,
                              self.home_velocity_du, self.home_offset_counts)
        return [_long(_MOT_GET_HOMEPARAMS, payload)]

    def _req_statusbits(self, p1, p2, data):
        return [_long(_MOT_GET_STATUSBITS, struct.pack("<HL", p1 or 1, self.status_bits()))]

    def _req_statusupdate(self, p1, p2, data):
        data = struct.pack("<HllL", p1 or 1, self.position_counts(), 0, self.status_bits())
        return [_long(_MOT_GET_STATUSUPDATE, data)]

    def _req_dcstatusupdate(self, p1, p2, data):
        return [_long(_MOT_GET_DCSTATUSUPDATE, self._status_packet())]

    def _ignore(self, p1, p2, data):
        return []

    # motion
    def _refuse(self, msg_id: int) -> list[bytes] | None:
        """Why a motion command is not executed: error state (answered) or disabled."""
        if self.error_code is not None:
            return [self._rich_response(msg_id, self.error_code,
                                        "command refused: controller in error state")]
        if not self.enabled:
            return []
        return None

    def _start_move(self, target_counts: int) -> None:
        here = self.position_counts()
        direction = (target_counts > here) - (target_counts < here)
        short = self._rng.randint(0, self.profile.stop_short_counts) if direction else 0
        # The quirk: the stage settles a few counts before the target.
        end = target_counts - direction * short
        self._direction = direction
        duration = self.stage.move_to(end / self.profile.counts_per_unit)
        self._settled_at = self.clock.now() + duration + self.profile.settle_s
        self._motion = "move"

    def _move(self, msg_id: int, data: bytes | None, *, relative: bool) -> list[bytes]:
        refused = self._refuse(msg_id)
        if refused is not None:
            return refused
        cv = self._chan_value(data)
        if cv is not None:
            self._start_move(cv[1] + (self.position_counts() if relative else 0))
        return []

    def _move_absolute(self, p1, p2, data):
        return self._move(_MOT_MOVE_ABSOLUTE, data, relative=False)

    def _move_relative(self, p1, p2, data):
        return self._move(_MOT_MOVE_RELATIVE, data, relative=True)

    def _move_home(self, p1, p2, data):
        refused = self._refuse(_MOT_MOVE_HOME)
        if refused is not None:
            return refused
        self.stage.start_homing()
        self.stage.at_limit = None
        phys = self.stage.physical_position()
        self._direction = -1 if phys > 0 else 1
        self._motion = "home"
        return []

    def _move_velocity(self, p1, p2, data):
        refused = self._refuse(_MOT_MOVE_VELOCITY)
        if refused is not None:
            return refused
        direction = -1 if p2 == 2 else 1
        self._direction = direction
        self.stage.move_to(self.stage.position() + direction * self.CONTINUOUS_UNITS)
        self._motion = "velocity"
        return []

    def _move_stop(self, p1, p2, data):
        self.stage.stop(immediate=(p2 == 1))
        self._motion = "stop"
        return []

    _HANDLERS: ClassVar[dict] = {
        _HW_REQ_INFO: _req_info,
        _HW_START_UPDATEMSGS: _start_updates,
        _HW_STOP_UPDATEMSGS: _stop_updates,
        _MOD_IDENTIFY: _identify,
        _MOD_SET_CHANENABLESTATE: _set_enable,
        _MOD_REQ_CHANENABLESTATE: _req_enable,
        _MOT_SET_POSCOUNTER: _set_poscounter,
        _MOT_REQ_POSCOUNTER: _req_poscounter,
        _MOT_SET_VELPARAMS: _set_velparams,
        _MOT_REQ_VELPARAMS: _req_velparams,
        _MOT_SET_HOMEPARAMS: _set_homeparams,
        _MOT_REQ_HOMEPARAMS: _req_homeparams,
        _MOT_REQ_STATUSBITS: _req_statusbits,
        _MOT_REQ_STATUSUPDATE: _req_statusupdate,
        _MOT_REQ_DCSTATUSUPDATE: _req_dcstatusupdate,
        _MOT_ACK_DCSTATUSUPDATE: _ignore,
        _MOT_MOVE_HOME: _move_home,
        _MOT_MOVE_RELATIVE: _move_relative,
        _MOT_MOVE_ABSOLUTE: _move_absolute,
        _MOT_MOVE_STOP: _move_stop,
        _MOT_MOVE_VELOCITY: _move_velocity,
    }
