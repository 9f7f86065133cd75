"""Thorlabs SC10 shutter controller (with an SH05/SH1 shutter) over its ASCII serial port.

Why the SC10 and not a KSC101 K-Cube over APT: the SC10 speaks a small, self-contained
ASCII command set (a dozen keywords), is common on older optical benches, and needs
nothing of the APT binary stack (:mod:`drivers.apt_protocol`), so this driver stands on
its own and a bench without any APT device can still have a shutter.

Source: Thorlabs, *SC10 Optical Beam Shutter Controller* manual, document 8654-D02,
remote-operation chapter, table "Keywords (Commands and Queries)" (page 15 of the PDF as
published; read at https://www.manualslib.com/manual/2332123/Thorlabs-Sc10.html?page=15).
Confirmed there:

- all keywords are lower case; an incorrect keyword, format or out-of-range argument
  makes the unit "return an error string";
- ``id?`` returns the model number and firmware revision;
- ``ens`` **toggles** the enable ("Enables/Disables the shutter"); ``ens?`` returns ``0``
  (disabled) or ``1`` (enabled);
- ``mode=n``/``mode?``: 1 manual, 2 auto, 3 single, 4 repeat, 5 external gate;
  ``trig=0/1`` internal/external trigger; ``xto=0/1``; ``rep=n`` 1..99;
  ``open=n``/``shut=n`` open and close durations in ms, "6 digits or less";
- ``closed?`` returns ``1`` if the shutter is closed, ``0`` if open; ``interlock?``
  returns ``1`` if the interlock is tripped;
- ``baud=n``/``baud?``, ``save``, ``savp``, ``resp``.

Not in that table, taken from open-source drivers used with real units (**unconfirmed**
against the manual):

- serial settings 9600 baud, 8N1, no handshake (Micro-Manager's SC10 adapter defaults;
  InstrumentKit: ``baud=1`` selects 115200);
- CR terminator, the echo of every request and the ``"> "`` prompt (see
  :mod:`drivers.thorlabs_ascii_protocol`), and the error text ``Command error
  CMD_NOT_DEFINED``/``CMD_ARG_INVALID``;
- ``*idn?`` is answered like ``id?`` (D. Grier's IDL SC10 driver); the answer reads like
  ``THORLABS SC10 VERSION 1.07``. This driver asks ``id?``, which the manual lists;
- in manual mode the blade follows the enable: enabled = open (Micro-Manager's adapter
  opens and closes the shutter with ``ens`` in ``mode=1``);
- what a tripped interlock does to the enable: we assume it clears it (the blade closes)
  and that ``ens`` cannot enable until the interlock loop is closed again.

The ``ens`` trap: ``ens`` toggles, so sending it blindly can *open* a shutter that was
meant to close (if someone pressed the front-panel button, or a previous toggle's answer
was lost). This driver never sends ``ens`` without reading ``ens?`` first, never retries
it (a lost answer to ``ens`` is not an error by itself: the state read afterwards says
whether it toggled), and reads the state back (``ens?`` and ``closed?``) within a timeout.

Connection: a bare CR ends any half-typed line; ``id?`` must name an SC10. If the unit is
not in manual mode, the driver disables it first (blade closed) and then sets
``mode=1``: in the timed modes ``ens`` would start a timed sequence instead of opening.
Closing the device (:meth:`~drivers.base.Device.close`) closes the shutter first (best
effort) unless ``close_on_exit=False``: a released shutter must not leave the sample lit.
"""

from __future__ import annotations

import contextlib
import threading
import time

import serial

from drivers.base import DeviceIdentity, Shutter, ShutterState
from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceError,
    DeviceTimeout,
    ProtocolError,
    StateError,
)
from drivers.thorlabs_ascii_link import CommandRejected, PromptLink
from drivers.thorlabs_ascii_protocol import parse_flag, parse_int

__all__ = ["CommandRejected", "InterlockTripped", "Sc10Shutter"]

#: Operating modes (``mode=n``), manual 8654-D02.
MODES = {1: "manual", 2: "auto", 3: "single", 4: "repeat", 5: "external gate"}
MANUAL_MODE = 1


class InterlockTripped(StateError):
    """The SC10's interlock loop is open: the shutter cannot be opened."""


class Sc10Shutter(Shutter):
    """An SH05/SH1 shutter on a Thorlabs SC10 controller.

    Parameters
    ----------
    port
        A device path (``/dev/ttyUSB0``), a pyserial URL (``simsc10://x``) or an open
        ``serial.SerialBase`` (used as is; the caller set its baud rate).
    name
        Role name used in every error.
    baudrate
        9600 (the unit's default) or 115200 (after ``baud=1`` and ``save``).
    reply_timeout
        Seconds to wait for one answer.
    retries
        Extra attempts for queries after a timeout or a garbled answer (``ens`` is never
        retried).
    settle_timeout
        Seconds the blade may take to reach the commanded state after ``ens``.
    poll_interval
        Seconds between state reads while it settles.
    close_on_exit
        Close the shutter when the device is closed (default True).
    serial_number
        The serial number on the unit's label, for provenance (the SC10 does not report one).

    Raises
    ------
    ConnectionFailed
        The port cannot be opened, nothing answers, or what answers is no SC10.
    """

    BAUDRATES = (9600, 115200)

    def __init__(
        self,
        port: str | serial.SerialBase,
        *,
        name: str,
        baudrate: int = 9600,
        reply_timeout: float = 0.5,
        retries: int = 2,
        settle_timeout: float = 1.0,
        poll_interval: float = 0.01,
        close_on_exit: bool = True,
        serial_number: str = "",
    ) -> None:
        if baudrate not in self.BAUDRATES:
            raise ValueError(f"the SC10 runs at 9600 or 115200 baud, got {baudrate}")
        if not settle_timeout > 0 or not poll_interval >= 0:
            raise ValueError("settle_timeout must be > 0 and poll_interval >= 0")
        super().__init__(name)
        self.settle_timeout = float(settle_timeout)
        self.poll_interval = float(poll_interval)
        self.close_on_exit = bool(close_on_exit)
        self.serial_number = str(serial_number)
        #: Operating mode found at connect (before the driver set manual mode).
        self.mode_at_connect: int | None = None
        self._id_text = ""
        # A read-then-toggle sequence is atomic: a turn_off() from another thread must not
        # read the enable between a turn_on()'s ens? and its ens (a double toggle).
        self._sequence_lock = threading.RLock()
        self._link: PromptLink | None = PromptLink.open(
            port, device=name, baudrate=baudrate, reply_timeout=reply_timeout, retries=retries)
        try:
            self._connect(baudrate)
        except BaseException:
            # A failed constructor leaves nothing open that it opened itself.
            self._link.abandon()
            self._link = None
            raise

    # connection ---------------------------------------------------------------
    def _connect(self, baudrate: int) -> None:
        link = self._io("open")
        self._id_text = link.identify("id", "SC10", r"SC10", baudrate=baudrate)
        self.mode_at_connect = link.query("mode", lambda t: parse_int(t, 1, 5))
        if self.mode_at_connect != MANUAL_MODE:
            # In a timed mode the enable starts a sequence: stop it (blade closed) first.
            self._do_close_shutter()
            link.command("mode", MANUAL_MODE)
            mode = link.query("mode", lambda t: parse_int(t, 1, 5))
            if mode != MANUAL_MODE:
                raise ConnectionFailed(
                    f"the SC10 stays in {MODES[mode]} mode after mode=1", device=self.name,
                    command="mode=1", hint="set manual mode on the front panel")

    # public extras ------------------------------------------------------------
    @property
    def interlock_tripped(self) -> bool:
        """Whether the interlock loop is open (the shutter cannot open)."""
        self._check_open("interlock_tripped")
        return self._io("interlock?").query("interlock", parse_flag)

    @property
    def enabled(self) -> bool:
        """The controller's enable (``ens?``); in manual mode, the commanded blade state."""
        self._check_open("enabled")
        return self._io("ens?").query("ens", parse_flag)

    # Shutter hooks ------------------------------------------------------------
    def _do_identity(self) -> DeviceIdentity:
        words = self._id_text.split()
        firmware = words[-1] if len(words) >= 2 and words[-1][:1].isdigit() else ""
        return DeviceIdentity(
            vendor="Thorlabs", model="SC10", serial=self.serial_number or "not reported",
            firmware=firmware or self._id_text, extra={"id": self._id_text},
        )

    def _do_shutter_state(self) -> ShutterState:
        closed = self._io("closed?").query("closed", parse_flag)
        return ShutterState.CLOSED if closed else ShutterState.OPEN

    def _do_open_shutter(self) -> None:
        link = self._io("open_shutter")
        with self._sequence_lock:
            if link.query("interlock", parse_flag):
                raise self._interlock_error("open_shutter")
            if not link.query("ens", parse_flag):
                self._toggle_enable(link)
            self._settle(open_=True, command="open_shutter")

    def _do_close_shutter(self) -> None:
        link = self._io("close_shutter")
        try:
            with self._sequence_lock:
                if link.query("ens", parse_flag):
                    self._toggle_enable(link)
                self._settle(open_=False, command="close_shutter")
        except (DeviceTimeout, ProtocolError, ConnectionFailed) as err:
            # The blade's state is unknown: say so, in the words that keep people safe.
            raise type(err)(
                f"cannot confirm the shutter closed: {err.message}", device=self.name,
                command=err.command or "close_shutter",
                hint="block the beam by hand, then check the SC10's cable and power",
            ) from err

    def _do_close(self) -> None:
        if self._link is None:
            return
        try:
            if self.close_on_exit:
                with contextlib.suppress(DeviceError):
                    self._do_close_shutter()
        finally:
            self._link.close()
            self._link = None

    # helpers ------------------------------------------------------------------
    def _io(self, command: str) -> PromptLink:
        if self._link is None:
            raise StateError("device is closed", device=self.name, command=command)
        return self._link

    @staticmethod
    def _toggle_enable(link: PromptLink) -> None:
        """Send ``ens`` once. A lost or garbled answer is not fatal and never retried:
        the state read afterwards (:meth:`_settle`) tells whether it toggled."""
        with contextlib.suppress(DeviceTimeout, ProtocolError):
            link.command("ens")

    def _settle(self, *, open_: bool, command: str) -> None:
        """Read ``ens?`` and ``closed?`` until they show the wanted state, or raise."""
        link = self._io(command)
        deadline = time.monotonic() + self.settle_timeout
        while True:
            enabled = link.query("ens", parse_flag)
            closed = link.query("closed", parse_flag)
            if enabled == open_ and closed != open_:
                return
            if open_ and not enabled and link.query("interlock", parse_flag):
                raise self._interlock_error(command)
            if time.monotonic() >= deadline:
                wanted = "open" if open_ else "closed"
                raise ControllerError(
                    f"the shutter is not {wanted} {self.settle_timeout:g} s after ens "
                    f"(ens? {int(enabled)}, closed? {int(closed)})",
                    device=self.name, command=command,
                    hint=("block the beam by hand and check the shutter cable"
                          if not open_ else "check the shutter cable and the SC10's mode"),
                )
            time.sleep(self.poll_interval)

    def _interlock_error(self, command: str) -> InterlockTripped:
        return InterlockTripped(
            "the interlock is tripped; the shutter stays closed", device=self.name,
            command=command,
            hint="close the interlock loop (door, key switch or jumper), then open again",
        )
