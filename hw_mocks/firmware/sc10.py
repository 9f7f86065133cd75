"""Firmware emulator of a Thorlabs SC10 shutter controller with an SH05 shutter.

Written from the keyword table of the SC10 manual (document 8654-D02) and from what
open-source drivers record of real units, independently of ``drivers/``. The terminal
conventions (echo, ``"> "`` prompt, ``Command error`` answers) are in
:mod:`hw_mocks.firmware.thorlabs_prompt`.

Default behaviour, declared once:

- Power-up: 9600 baud, manual mode (``mode=1``), internal trigger, disabled, blade closed,
  open/shut times 10 ms, repeat count 1; the saved settings (``savp``) are what a power
  cycle restores (mode, trigger, times, repeat count); ``save`` stores ``xto`` and
  ``baud``, and a stored baud rate takes effect at the next power-up.
- ``ens`` **toggles** the enable; ``ens?`` answers ``1``/``0``. The blade follows the
  mode (a blade change takes no time; an SH05 moves in milliseconds):

  - manual: open while enabled;
  - auto: while enabled, open for ``open`` ms then shut for ``shut`` ms, repeatedly;
  - single: once enabled, open for ``open`` ms, then closed (the enable stays set);
  - repeat: like auto for ``rep`` cycles, then closed;
  - external gate: open while enabled and the gate input (backdoor) is high.

  With ``trig=1`` (external trigger) the timed modes wait for a trigger that never comes
  unless :meth:`Sc10Emulator.external_trigger` fires it.
- ``closed?`` answers ``1`` while the blade is closed; ``interlock?`` ``1`` while the
  interlock loop is open. Tripping the interlock clears the enable (the blade closes);
  ``ens`` is ignored while it is tripped (assumed: the manual says only that
  ``interlock?`` reports it); closing the loop again leaves the unit disabled.
- ``id?`` and ``*idn?`` answer ``THORLABS SC10 VERSION 1.07``.
- Out-of-range arguments (``mode=9``, ``rep=0``, ``open=1234567``) answer
  ``CMD_ARG_INVALID``; unknown keywords, arguments to ``ens`` and upper case answer
  ``CMD_NOT_DEFINED``.

Faults: the injector's rules (drop, delay, garbage...) act on the answers; "does not
answer" is :meth:`power_off` or a ``DROP`` rule; ``ERROR_STATE`` trips the interlock; the
unsolicited frame is a stray prompt.

Command set: every keyword of the SC10 manual's table, ``?`` (the keyword list) included
(:mod:`hw_mocks.firmware.thorlabs_prompt`); nothing of it is left out, and anything else is
answered ``Command error CMD_NOT_DEFINED`` as the unit answers an unknown keyword.
"""

from __future__ import annotations

from hw_mocks.clock import Clock
from hw_mocks.firmware.thorlabs_prompt import CmdError, Handler, PromptFirmware

__all__ = ["Sc10Emulator"]

IDENTITY = "THORLABS SC10 VERSION 1.07"
_MANUAL, _AUTO, _SINGLE, _REPEAT, _GATE = 1, 2, 3, 4, 5
_BAUDS = {0: 9600, 1: 115200}


class Sc10Emulator(PromptFirmware):
    """An SC10 controller; see the module docstring for its behaviour.

    Parameters
    ----------
    name
        Instance name (URL host part).
    mode
        Operating mode at power-up (1..5).
    interlock_tripped
        Whether the interlock loop is open at power-up.
    """

    scheme = "simsc10"
    baudrate = 9600

    def __init__(self, name: str, *, mode: int = _MANUAL, interlock_tripped: bool = False,
                 clock: Clock | None = None, seed: int = 0) -> None:
        super().__init__(name, clock=clock, seed=seed)
        if mode not in (_MANUAL, _AUTO, _SINGLE, _REPEAT, _GATE):
            raise ValueError(f"SC10 mode must be 1..5, got {mode}")
        self.saved = {"mode": mode, "trig": 0, "open": 10, "shut": 10, "rep": 1}
        self.saved_mode_info = {"xto": 0, "baud": 0}
        self.interlock = bool(interlock_tripped)
        #: Backdoor: the external gate input (gate mode) is high.
        self.gate_input = False
        self._power_up()

    def _power_up(self) -> None:
        self.settings = dict(self.saved)
        self.xto = self.saved_mode_info["xto"]
        self.baud_setting = self.saved_mode_info["baud"]
        self.baudrate = _BAUDS[self.baud_setting]
        self.enabled = False
        self._sequence_start: float | None = None

    # backdoor -----------------------------------------------------------------
    def light_passes(self) -> bool:
        """Whether the blade is open now (what the virtual bench asks)."""
        with self.lock:
            return self.powered and self._blade_open()

    def press_enable_button(self) -> None:
        """The front-panel enable key: toggles like ``ens`` (someone at the bench)."""
        with self.lock:
            self._toggle()

    def trip_interlock(self) -> None:
        with self.lock:
            self.interlock = True
            self.enabled = False
            self._sequence_start = None

    def restore_interlock(self) -> None:
        """Close the interlock loop again; the unit stays disabled."""
        with self.lock:
            self.interlock = False

    def external_trigger(self) -> None:
        """A trigger pulse on the trigger input (external-trigger timed modes)."""
        with self.lock:
            if self.enabled and self.settings["trig"] == 1:
                self._sequence_start = self.clock.now()

    def unsolicited_frame(self) -> bytes:
        return b"> "

    def enter_error_state(self, code: str | None = None) -> None:
        self.trip_interlock()

    # blade --------------------------------------------------------------------
    def _toggle(self) -> None:
        if self.interlock:
            return  # a tripped interlock holds the unit disabled
        self.enabled = not self.enabled
        internal = self.settings["trig"] == 0
        self._sequence_start = self.clock.now() if self.enabled and internal else None

    def _blade_open(self) -> bool:
        if not self.enabled or self.interlock:
            return False
        mode = self.settings["mode"]
        if mode == _MANUAL:
            return True
        if mode == _GATE:
            return self.gate_input
        if self._sequence_start is None:
            return False  # external trigger: waiting for a pulse
        open_s, shut_s = self.settings["open"] * 1e-3, self.settings["shut"] * 1e-3
        elapsed = self.clock.now() - self._sequence_start
        if mode == _SINGLE:
            return elapsed < open_s
        period = open_s + shut_s
        cycle, phase = divmod(elapsed, period) if period > 0 else (0.0, elapsed)
        if mode == _REPEAT and cycle >= self.settings["rep"]:
            return False
        return phase < open_s

    # keywords -----------------------------------------------------------------
    def _handlers(self) -> dict[str, Handler]:
        return {
            "id?": self._identity,
            "*idn?": self._identity,
            "ens": self._ens,
            "ens?": lambda arg: str(int(self.enabled)),
            "closed?": lambda arg: str(int(not self._blade_open())),
            "interlock?": lambda arg: str(int(self.interlock)),
            "mode": lambda arg: self._set("mode", arg, 1, 5),
            "mode?": lambda arg: str(self.settings["mode"]),
            "trig": lambda arg: self._set("trig", arg, 0, 1),
            "trig?": lambda arg: str(self.settings["trig"]),
            "open": lambda arg: self._set("open", arg, 1, 999999),
            "open?": lambda arg: str(self.settings["open"]),
            "shut": lambda arg: self._set("shut", arg, 1, 999999),
            "shut?": lambda arg: str(self.settings["shut"]),
            "rep": lambda arg: self._set("rep", arg, 1, 99),
            "rep?": lambda arg: str(self.settings["rep"]),
            "xto": self._xto,
            "xto?": lambda arg: str(self.xto),
            "baud": self._baud,
            "baud?": lambda arg: str(self.baud_setting),
            "savp": self._savp,
            "save": self._save,
            "resp": self._resp,
        }

    def _identity(self, arg: str | None) -> str:
        return IDENTITY

    def _ens(self, arg: str | None) -> None:
        self._no_arg(arg)
        self._toggle()

    def _set(self, key: str, arg: str | None, low: int, high: int) -> None:
        value = self._int_arg(arg, low, high)
        if key == "mode" and value != self.settings["mode"]:
            # A mode change stops whatever sequence ran (assumed, not documented).
            self.enabled = False
            self._sequence_start = None
        self.settings[key] = value

    def _xto(self, arg: str | None) -> None:
        self.xto = self._int_arg(arg, 0, 1)

    def _baud(self, arg: str | None) -> None:
        self.baud_setting = self._int_arg(arg, 0, 1)

    def _savp(self, arg: str | None) -> None:
        self._no_arg(arg)
        self.saved = dict(self.settings)

    def _save(self, arg: str | None) -> None:
        self._no_arg(arg)
        self.saved_mode_info = {"xto": self.xto, "baud": self.baud_setting}

    def _resp(self, arg: str | None) -> None:
        self._no_arg(arg)
        if self.enabled:
            raise CmdError("CMD_ARG_INVALID")  # assumed: settings load only when disabled
        self.settings = dict(self.saved)
