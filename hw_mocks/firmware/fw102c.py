"""Firmware emulator of a Thorlabs FW102C (6 slots) / FW212C (12 slots) filter wheel.

Written from the keyword table of the FW102C manual (rev H, §5.2.3) and from what
open-source drivers record of real units, independently of ``drivers/``. The terminal
conventions (echo, ``"> "`` prompt, ``Command error`` answers) are in
:mod:`hw_mocks.firmware.thorlabs_prompt`.

Default behaviour, declared once:

- Power-up: 115200 baud, the saved wheel type (6 slots unless ``slots=12``), speed, trigger
  and sensor modes (``save`` stores them), the wheel at slot ``start`` (default 1).
- ``pos=n`` (1 ≤ n ≤ slot count, else ``CMD_ARG_INVALID``) echoes at once and turns the
  wheel the shorter way round at a constant rate: half a turn in 3 s at high speed
  (``speed=1``, as hispec observes), twice as long at normal speed (``speed=0``), plus
  :data:`SETTLE_S` to settle on the slot sensor. The prompt comes when the wheel stands at
  the slot; until then input waits unread (the unit is inside ``pos=``). A move to the
  slot already in the beam answers at once.
- While the wheel turns, the beam falls on the wheel between the apertures:
  :meth:`Fw102cEmulator.slot_at_beam` is ``None``.
- ``*idn?`` answers ``THORLABS FW102C/FW212C Filter Wheel version 1.07``.

Jam (what a real unit reports is not documented; two behaviours for the driver to face):

- ``silent``: the wheel stops part-way, between slots, and the unit never prompts: it
  stays inside ``pos=`` and answers nothing more until :meth:`Fw102cEmulator.clear_jam`
  (the obstruction is removed: the move completes and the late prompt comes) or a power
  cycle (:meth:`power_off`/:meth:`power_on`: the wheel finds the nearest slot).
- ``stall``: the motor gives up at the last slot it passed and the unit prompts as if the
  move had finished; ``pos?`` then reports that slot.

:meth:`Fw102cEmulator.jam` arms a jam for the next move (or the one running);
``ERROR_STATE`` faults arm a ``silent`` jam (``code="stall"`` for the other). The
unsolicited frame is a stray prompt.

Command set: every keyword of the FW102C manual's table, ``?`` (the keyword list) included
(:mod:`hw_mocks.firmware.thorlabs_prompt`); nothing of it is left out, and anything else is
answered ``Command error CMD_NOT_DEFINED`` as the unit answers an unknown keyword.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from hw_mocks.clock import Clock
from hw_mocks.firmware.thorlabs_prompt import CmdError, Handler, PromptFirmware

__all__ = ["Fw102cEmulator"]

IDENTITY = "THORLABS FW102C/FW212C Filter Wheel version 1.07"
#: Seconds per degree of rotation by speed mode (0 normal, 1 high).
SECONDS_PER_DEGREE = {1: 3.0 / 180.0, 0: 6.0 / 180.0}
#: Seconds to settle on the slot sensor after the turn.
SETTLE_S = 0.1
_BAUDS = {0: 9600, 1: 115200}


@dataclass(frozen=True)
class _Move:
    """A move under way: from slot ``start`` towards ``target``, ``direction`` ±1."""

    start: int
    target: int
    t0: float
    t_end: float
    direction: int
    jam: tuple[str, float] | None = None  # (mode, fraction of the way) if it will jam

    def jam_time(self) -> float:
        assert self.jam is not None
        return self.t0 + self.jam[1] * (self.t_end - self.t0 - SETTLE_S)


class Fw102cEmulator(PromptFirmware):
    """A filter wheel; see the module docstring for its behaviour.

    Parameters
    ----------
    name
        Instance name (URL host part).
    slots
        6 (FW102C) or 12 (FW212C): the saved wheel type.
    start
        The slot in the beam at power-up.
    speed_mode
        Saved speed mode: 1 high (default), 0 normal.
    """

    scheme = "simfw102c"
    baudrate = 115200

    def __init__(self, name: str, *, slots: int = 6, start: int = 1, speed_mode: int = 1,
                 clock: Clock | None = None, seed: int = 0) -> None:
        super().__init__(name, clock=clock, seed=seed)
        if slots not in (6, 12):
            raise ValueError(f"a Thorlabs wheel has 6 or 12 slots, got {slots}")
        if not 1 <= start <= slots:
            raise ValueError(f"start slot must be 1..{slots}, got {start}")
        if speed_mode not in (0, 1):
            raise ValueError(f"speed_mode must be 0 or 1, got {speed_mode}")
        self.saved = {"pcount": slots, "speed": speed_mode, "trig": 0, "sensors": 0,
                      "baud": 1}
        self.position = start
        #: Moves completed (for tests).
        self.moves = 0
        self._armed_jam: tuple[str, float] | None = None
        self._power_up()

    def _power_up(self) -> None:
        self.settings = dict(self.saved)
        self.baudrate = _BAUDS[self.settings["baud"]]
        self.position = min(self.position, self.settings["pcount"])
        self._move: _Move | None = None
        self.jammed: str | None = None
        self._prompt_due = False

    # backdoor -----------------------------------------------------------------
    def slot_at_beam(self) -> int | None:
        """The slot in the beam, or ``None`` while the wheel turns or is stuck between."""
        with self.lock:
            self._advance()
            if not self.powered or self._move is not None:
                return None
            return self.position

    def jam(self, mode: str = "silent", fraction: float = 0.5) -> None:
        """Jam the next move (or the running one) ``fraction`` of its way along."""
        if mode not in ("silent", "stall"):
            raise ValueError(f"jam mode must be 'silent' or 'stall', got {mode!r}")
        if not 0.0 < fraction < 1.0:
            raise ValueError("fraction must be in (0, 1)")
        with self.lock:
            if self._move is not None and self.jammed is None:
                self._move = replace(self._move, jam=(mode, fraction))
            else:
                self._armed_jam = (mode, fraction)

    def clear_jam(self) -> None:
        """Remove the obstruction: a silently jammed move completes from where it stopped."""
        with self.lock:
            move = self._move
            if move is None or move.jam is None or self.jammed != "silent":
                return
            remaining = (1.0 - move.jam[1]) * (move.t_end - move.t0 - SETTLE_S) + SETTLE_S
            now = self.clock.now()
            self._move = replace(move, t0=now, t_end=now + remaining, jam=None)
            self.jammed = None

    def power_on(self) -> None:
        with self.lock:
            if self._move is not None:  # the wheel finds the nearest slot on its sensor
                self.position = self._nearest_slot()
            super().power_on()

    def unsolicited_frame(self) -> bytes:
        return b"> "

    def enter_error_state(self, code: str | None = None) -> None:
        self.jam("stall" if code == "stall" else "silent")

    # motion -------------------------------------------------------------------
    def busy(self) -> bool:
        self._advance()
        return self._move is not None

    def move_duration_s(self, start: int, target: int) -> float:
        """Seconds from ``pos=`` to the prompt for a free move."""
        steps = self._steps(start, target)
        if steps == 0:
            return 0.0
        degrees = abs(steps) * 360.0 / self.settings["pcount"]
        return degrees * SECONDS_PER_DEGREE[self.settings["speed"]] + SETTLE_S

    def _steps(self, start: int, target: int) -> int:
        """Signed slot count of the shorter way round (ties turn forward)."""
        count = self.settings["pcount"]
        forward = (target - start) % count
        return forward if forward <= count - forward else forward - count

    def _advance(self) -> None:
        """Bring the move up to the clock's time (a wheel without power stands still)."""
        if self._move is None or not self.powered:
            return
        move = self._move
        now = self.clock.now()
        if move.jam is not None and self.jammed is None and now >= move.jam_time():
            mode, fraction = move.jam
            if mode == "silent":
                self.jammed = "silent"
                return
            # stall: the motor gives up at the last slot it passed; the unit believes the
            # move finished and prompts at the planned time.
            passed = math.floor(fraction * abs(self._steps(move.start, move.target)))
            self.position = self._wrap(move.start + move.direction * passed)
            self.jammed = "stall"
        if self.jammed == "silent":
            return
        if now >= move.t_end:
            if self.jammed != "stall":
                self.position = move.target
            self._move = None
            self.jammed = None
            self.moves += 1
            self._prompt_due = True

    def _finished(self) -> list[bytes]:
        self._advance()
        if self._prompt_due:
            self._prompt_due = False
            return [b"> "]
        return []

    def _nearest_slot(self) -> int:
        move = self._move
        assert move is not None
        steps = abs(self._steps(move.start, move.target))
        fraction = move.jam[1] if move.jam is not None and self.jammed else 0.5
        return self._wrap(move.start + move.direction * round(fraction * steps))

    def _wrap(self, slot: int) -> int:
        return (slot - 1) % self.settings["pcount"] + 1

    # keywords -----------------------------------------------------------------
    def _handlers(self) -> dict[str, Handler]:
        return {
            "*idn?": lambda arg: IDENTITY,
            "pos": self._pos,
            "pos?": lambda arg: str(self.position),
            "pcount": self._pcount,
            "pcount?": lambda arg: str(self.settings["pcount"]),
            "speed": lambda arg: self._set("speed", arg),
            "speed?": lambda arg: str(self.settings["speed"]),
            "trig": lambda arg: self._set("trig", arg),
            "trig?": lambda arg: str(self.settings["trig"]),
            "sensors": lambda arg: self._set("sensors", arg),
            "sensors?": lambda arg: str(self.settings["sensors"]),
            "baud": lambda arg: self._set("baud", arg),
            "baud?": lambda arg: str(self.settings["baud"]),
            "save": self._save,
        }

    def _pos(self, arg: str | None) -> None:
        target = self._int_arg(arg, 1, self.settings["pcount"])
        steps = self._steps(self.position, target)
        jam, self._armed_jam = self._armed_jam, None
        if steps == 0:
            return
        now = self.clock.now()
        self._move = _Move(self.position, target, now,
                           now + self.move_duration_s(self.position, target),
                           1 if steps > 0 else -1, jam)

    def _pcount(self, arg: str | None) -> None:
        value = self._int_arg(arg, 6, 12)
        if value not in (6, 12):
            raise CmdError("CMD_ARG_INVALID")
        self.settings["pcount"] = value
        self.position = min(self.position, value)

    def _set(self, key: str, arg: str | None) -> None:
        self.settings[key] = self._int_arg(arg, 0, 1)

    def _save(self, arg: str | None) -> None:
        self._no_arg(arg)
        self.saved = dict(self.settings)
