"""Newport SMC100 (CC/PP) single-axis motion controller driver.

Serial settings: 57600 baud, 8N1, CR LF terminator, ASCII (Newport *SMC100CC & SMC100PP
Single-Axis Motion Controller/Driver User's Manual*; hvl_ccb and QMI use 57600 — several
drivers on GitHub wrongly use CONEX-CC's 921600). Flow control: none by default. A comment
in one open-source driver says the SMC100 uses XON/XOFF (**unverified** against the manual).
We leave it off on purpose: this driver sends one short request at a time and waits for its
answer, so it can never fill the controller's input buffer, and with XON/XOFF on a single
noise byte 0x13 on the line would freeze the host's output until a 0x11 happened to arrive,
a stall no timeout or retry can clear. ``xonxoff=True`` turns it on for a setup that needs
it.

Protocol rules this driver follows (see :mod:`drivers.smc100_protocol`):

- Motion and set commands (``OR``, ``PA``, ``PR``, ``ST``, ``MM``, ``VA``, ``AC``) are not
  answered. Each is followed by a ``TE`` query: ``@`` means accepted, a letter means
  refused, and it becomes a :class:`~drivers.errors.ControllerError` whose ``code`` is
  the letter (subclasses add the matching :class:`StateError` / :class:`LimitError`).
- ``TE`` is *not* idempotent (reading clears the latch), so it is never retried; the
  latch is cleared once at connect so that later letters belong to our commands.
- Idempotent queries (``TS``, ``TP``, ``TH``, ``VA?``, ``AC?``, ``SL?``, ``SR?``, ``ID?``,
  ``VE``) are retried ``retries`` times after a timeout or a garbled reply, with stale
  input discarded before every request.
- Replies to other commands or addresses (a late reply after a timeout; a neighbour on
  the RS-485 chain) and line noise are skipped while waiting for ours.
- Every wait has a timeout: a reply waits ``reply_timeout`` s; a reset waits
  ``reset_timeout`` s (the controller answers nothing while it reboots).

Status: ``TS`` gives the controller state and the positioner error bits; the end-of-run
bits become ``at_forward_limit``/``at_reverse_limit``, the other bits become
``AxisStatus.error`` (and a :class:`ControllerError` while waiting).

Homing: ``OR`` is only accepted in NOT REFERENCED. Homing an axis that is already
referenced (or disabled) resets the controller first (``RS``), waits for it to answer
again, re-applies the velocity and acceleration set through this driver (a reset
restores the stored ones), then sends ``OR``.

Units: the controller works in the stage's own units (degrees for rotation stages,
millimetres for linear ones); no scaling happens here.
"""

from __future__ import annotations

import math
import re
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
    NotHomedError,
    ProtocolError,
    StateError,
)
from drivers.smc100_protocol import (
    CommandErrorCode,
    Phase,
    Smc100Status,
    format_command,
    match_reply,
    parse_error_code,
    parse_number,
    parse_status,
)
from drivers.transport import SerialChannel, open_serial

__all__ = [
    "CommandRefused",
    "NotReferencedError",
    "Smc100Axis",
    "TargetOutOfLimits",
]


class CommandRefused(ControllerError, StateError):
    """The controller refused a command in its present state (``TE`` D, E, I–M)."""


class NotReferencedError(ControllerError, NotHomedError):
    """The controller refused a command because it is not referenced (``TE`` H)."""


class TargetOutOfLimits(ControllerError, LimitError):
    """The controller refused a target beyond its software limits (``TE`` G, N)."""


_STATE_LETTERS = frozenset("DEIJKLM")
_LIMIT_LETTERS = frozenset("GN")
#: Largest line we accept before declaring the stream garbage.
_MAX_LINE = 256

T = TypeVar("T")
#: Any controller's reply to anything: skipped as stale or foreign, not counted as noise.
_ANY_REPLY = re.compile(rb"\d{1,2}[A-Z]{2}[\x20-\x7e]*\r\n")


class Smc100Axis(MotionAxis):
    """One axis on a Newport SMC100 controller.

    Parameters
    ----------
    port
        A device path (``/dev/ttyUSB0``), a pyserial URL (``simsmc://x``) or an open
        ``serial.SerialBase`` (used as is; the caller set its baud rate).
    name
        Role name used in every error.
    address
        RS-485 controller address 1..31.
    kind
        :class:`AxisKind` (or ``"rotary"``/``"linear"``): degrees or millimetres.
    soft_limits
        ``(low, high)`` in axis units; ``None`` reads the controller's software limits
        (``SL?``/``SR?``).
    position_tolerance, poll_interval
        See :class:`MotionAxis`.
    reply_timeout
        Seconds to wait for one reply line.
    retries
        Extra attempts for idempotent queries after a timeout or garbled reply.
    reset_timeout
        Seconds a reset (``RS``) may take before the controller answers again.
    xonxoff
        Software flow control when opening ``port`` from a path or URL (default off; see
        the module docstring).

    Raises
    ------
    ConnectionFailed
        The port cannot be opened or no SMC100 answers at ``address``.
    """

    BAUDRATE = 57600

    def __init__(
        self,
        port: str | serial.SerialBase,
        *,
        name: str,
        address: int = 1,
        kind: AxisKind | str = AxisKind.ROTARY,
        soft_limits: tuple[float, float] | None = None,
        position_tolerance: float = 0.01,
        poll_interval: float = 0.01,
        reply_timeout: float = 0.5,
        retries: int = 2,
        reset_timeout: float = 15.0,
        xonxoff: bool = False,
    ) -> None:
        if isinstance(kind, str):
            try:
                kind = AxisKind[kind.upper()]
            except KeyError:
                raise ValueError(f"kind must be 'rotary' or 'linear', got {kind!r}") from None
        format_command(address, "TS")  # validates the address before anything opens
        if not reply_timeout > 0 or not reset_timeout > 0:
            raise ValueError("timeouts must be > 0")
        retries = retry_count(retries)
        super().__init__(
            name, kind=kind, soft_limits=soft_limits or (-math.inf, math.inf),
            position_tolerance=position_tolerance, poll_interval=poll_interval,
        )
        self.address = address
        self.reply_timeout = float(reply_timeout)
        self.retries = int(retries)
        self.reset_timeout = float(reset_timeout)
        # One exchange (request and its reply, or a command and its TE) at a time: a
        # stop() from another thread must not read the reply a poll is waiting for.
        self._io_lock = threading.RLock()
        #: Replies skipped while waiting for ours (stale, foreign or noise), for diagnosis.
        self.skipped_lines = 0
        #: A command error left in the latch before we connected (``None`` if clean).
        self.error_at_connect: CommandErrorCode | None = None
        self._velocity_set: float | None = None
        self._acceleration_set: float | None = None
        self._channel: SerialChannel | None = None
        self._last_ts: Smc100Status | None = None
        raw = open_serial(port, device=name, baudrate=self.BAUDRATE, xonxoff=xonxoff)
        try:
            self._channel = SerialChannel(raw, device=name)
            self._connect(read_limits=soft_limits is None)
        except BaseException:
            # A failed constructor leaves nothing open that it opened itself.
            self._channel = None
            if not isinstance(port, serial.SerialBase):
                raw.close()
            raise

    # connection ---------------------------------------------------------------
    def _connect(self, *, read_limits: bool) -> None:
        try:
            self._status_query()
        except (DeviceTimeout, ProtocolError) as err:
            raise ConnectionFailed(
                f"no SMC100 answers at address {self.address}",
                device=self.name, command=self._text("TS"),
                hint="check the address, the cable, the baud rate (57600) and the power",
            ) from err
        # Clear a latched error from before our time, so later TE letters are ours.
        self.error_at_connect = self._read_error("TE")
        if read_limits:
            low = self._number_query("SL", "?")
            high = self._number_query("SR", "?")
            self.soft_limits = (low, high)

    # wire ---------------------------------------------------------------------
    def _text(self, command: str, value: float | str | None = None) -> str:
        return format_command(self.address, command, value).decode("ascii").strip()

    def _chan(self, command: str) -> SerialChannel:
        if self._channel is None:
            raise StateError("device is closed", device=self.name, command=command)
        return self._channel

    def _send(self, command: str, value: float | str | None = None) -> str:
        """Discard stale input and write one request; return its text for errors."""
        request = format_command(self.address, command, value)
        text = request.decode("ascii").strip()
        channel = self._chan(text)
        channel.discard_input()
        channel.write(request, command=text)
        return text

    def _read_line(self, deadline: float, text: str) -> bytes:
        return self._chan(text).read_line(
            b"\r\n", timeout=max(deadline - time.monotonic(), 0.0), command=text,
            max_bytes=_MAX_LINE)

    def _read_reply(self, command: str, text: str, timeout: float | None = None) -> str:
        """Read lines until the reply to ``command`` arrives; return its value."""
        timeout = self.reply_timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        noise: list[bytes] = []
        while True:
            try:
                line = self._read_line(deadline, text)
            except DeviceTimeout as err:
                if noise:  # silence after line noise: name the noise as the cause
                    raise ProtocolError(
                        f"no valid reply; received line noise {noise[:3]!r}",
                        device=self.name, command=text,
                    ) from err
                raise
            try:
                value = match_reply(line, self.address, command)
            except ProtocolError as err:
                raise ProtocolError(err.message, device=self.name, command=text) from err
            if value is not None:
                return value
            self.skipped_lines += 1
            if not _ANY_REPLY.fullmatch(line):
                noise.append(line)

    def _ask(self, command: str, value: str | None = None,
             parse: Callable[[str], T] = str,  # type: ignore[assignment]  # T is str when parse is left out; mypy cannot tie a default to a type variable
             *, attempts: int | None = None, timeout: float | None = None) -> T:
        """An idempotent query, retried after a timeout or a garbled reply.

        Returns ``parse(value_text)``; stale input is discarded before every attempt.
        """
        attempts = self.retries + 1 if attempts is None else attempts
        last: DeviceError | None = None
        text = self._text(command, value)
        for _ in range(attempts):
            try:
                with self._io_lock:
                    self._send(command, value)
                    return parse(self._read_reply(command, text, timeout))
            except (DeviceTimeout, ProtocolError) as err:
                last = err
        assert last is not None
        suffix = f" (after {attempts} attempts)" if attempts > 1 else ""
        raise type(last)(last.message + suffix, device=self.name, command=text,
                         hint=last.hint or "check the connection and the controller",
                         ) from last

    def _read_error(self, text: str) -> CommandErrorCode | None:
        """Read the TE latch once (never retried: reading clears it)."""
        try:
            with self._io_lock:
                sent = self._send("TE")
                return parse_error_code(self._read_reply("TE", sent))
        except ProtocolError as err:
            raise ProtocolError(f"unreadable error reply after {text}: {err.message}",
                                device=self.name, command=text,
                                hint="the command's outcome is unknown; check status()",
                                ) from err
        except DeviceTimeout as err:
            raise DeviceTimeout(f"no TE reply after {text}", device=self.name,
                                command=text,
                                hint="the command's outcome is unknown; check status()",
                                ) from err

    def _command(self, command: str, value: float | str | None = None) -> None:
        """An unanswered command, checked with TE; raises the mapped error if refused."""
        with self._io_lock:
            text = self._send(command, value)
            code = self._read_error(text)
        if code is not None:
            raise self._refusal(code, text)

    def _refusal(self, code: CommandErrorCode, text: str) -> ControllerError:
        letter = code.letter
        message = f"controller refused the command: {code.meaning} (TE {letter})"
        if letter == "H":
            return NotReferencedError(message, code=letter, device=self.name, command=text,
                                      hint="home() the axis first")
        if letter in _LIMIT_LETTERS:
            return TargetOutOfLimits(message, code=letter, device=self.name, command=text,
                                     hint="check the controller's SL/SR software limits")
        if letter in _STATE_LETTERS:
            return CommandRefused(message, code=letter, device=self.name, command=text,
                                  hint="wait for the motion to end, or enable/home the axis")
        return ControllerError(message, code=letter, device=self.name, command=text)

    def _status_query(self) -> Smc100Status:
        self._last_ts = self._ask("TS", parse=parse_status)
        return self._last_ts

    def _number_query(self, command: str, value: str | None = None) -> float:
        return self._ask(command, value, parse_number)

    # public extras ------------------------------------------------------------
    def controller_status(self) -> Smc100Status:
        """The raw decoded ``TS``: controller state and positioner error bits."""
        self._check_open("controller_status")
        return self._status_query()

    @property
    def setpoint(self) -> float:
        """The controller's set-point (``TH``): where the present move ends."""
        self._check_open("setpoint")
        return self._number_query("TH")

    def reset(self) -> None:
        """Reset the controller (``RS``, like a power cycle) and wait until it answers.

        The axis is NOT REFERENCED afterwards. Velocity and acceleration set through this
        driver are re-applied.
        """
        self._check_open("reset")
        self._reset()

    # MotionAxis hooks ---------------------------------------------------------
    def _do_identity(self) -> DeviceIdentity:
        stage: str = self._ask("ID", "?")
        version: str = self._ask("VE")
        model, _, serial_number = stage.partition("_")
        return DeviceIdentity(
            vendor="Newport",
            model=f"SMC100 with {model or 'unknown stage'}",
            serial=serial_number or stage or "unknown",
            firmware=version,
            extra={"address": str(self.address), "stage": stage},
        )

    def _do_status(self) -> AxisStatus:
        ts = self._status_query()
        position = self._number_query("TP")
        faults = ts.fault_errors
        error = None
        if faults:
            error = f"positioner error: {', '.join(faults)} (TS {ts.error_bits:04X})"
        elif ts.state == 0x10:
            error = ts.info.name
        return AxisStatus(
            position=position,
            is_moving=ts.is_moving,
            is_homed=ts.is_referenced,
            is_enabled=ts.is_enabled,
            is_homing=ts.is_homing,
            at_forward_limit=ts.at_positive_limit,
            at_reverse_limit=ts.at_negative_limit,
            error=error,
        )

    def _do_get_position(self) -> float:
        return self._number_query("TP")

    def _raise_status_error(self, status: AxisStatus, command: str) -> None:
        bits = self._last_ts.error_bits if self._last_ts is not None else None
        raise ControllerError(
            status.error or "controller error", code=bits, device=self.name,
            command=command,
            hint="enable() clears a fault in DISABLE; home() again after a homing fault",
        )

    def _do_enable(self) -> None:
        ts = self._status_query()
        if ts.phase is Phase.DISABLE:
            self._command("MM", "1")
        # NOT REFERENCED: homing switches the motor on; READY/MOVING: already enabled.

    def _do_disable(self) -> None:
        ts = self._status_query()
        if ts.phase is Phase.MOVING:
            self._do_stop()
            self._wait_phase(lambda s: s.phase is not Phase.MOVING, "disable")
            ts = self._status_query()
        if ts.phase is Phase.READY:
            self._command("MM", "0")
        elif ts.phase is not Phase.DISABLE:
            raise CommandRefused(
                f"cannot disable in state {ts.info.name}", code=None, device=self.name,
                command="disable", hint="disable works on a referenced axis",
            )

    def _do_home(self) -> None:
        ts = self._status_query()
        if ts.phase is Phase.HOMING:
            return  # already on its way
        if ts.phase in (Phase.MOVING, Phase.TRACKING):
            self._do_stop()
            self._wait_phase(lambda s: not s.is_moving, "home")
            ts = self._status_query()
        if ts.phase is Phase.CONFIGURATION:
            self._send("PW", "0")  # leaving configuration writes flash: a deaf window
            self._wait_answering("PW0")
        elif ts.phase is not Phase.NOT_REFERENCED:
            self._reset()
        self._command("OR")

    def _do_move_absolute(self, target: float) -> None:
        self._command("PA", target)

    def _do_move_relative(self, delta: float, target: float) -> None:
        self._command("PR", delta)

    def _do_stop(self) -> None:
        with self._io_lock:
            text = self._send("ST")
            code = self._read_error(text)
        # After a stop, relative moves count from where the axis comes to rest.
        self._target = None
        if code is not None and code.letter not in _STATE_LETTERS | {"H"}:
            raise self._refusal(code, text)

    def _do_get_velocity(self) -> float:
        return self._number_query("VA", "?")

    def _do_set_velocity(self, value: float) -> None:
        self._command("VA", value)
        self._velocity_set = value

    def _do_get_acceleration(self) -> float:
        return self._number_query("AC", "?")

    def _do_set_acceleration(self, value: float) -> None:
        self._command("AC", value)
        self._acceleration_set = value

    def _do_close(self) -> None:
        if self._channel is not None:
            self._channel.close()
            self._channel = None

    # helpers ------------------------------------------------------------------
    def _reset(self) -> None:
        with self._io_lock:
            self._send("RS")  # answers nothing, and nothing at all while it reboots
        self._wait_answering("RS")
        self._target = None
        if self._velocity_set is not None:
            self._command("VA", self._velocity_set)
        if self._acceleration_set is not None:
            self._command("AC", self._acceleration_set)

    def _wait_answering(self, text: str) -> Smc100Status:
        """Poll TS until the controller answers again after a deaf window."""
        deadline = time.monotonic() + self.reset_timeout
        while True:
            try:
                # Short polls: every request sent while it is deaf is simply lost.
                status = self._ask("TS", parse=parse_status, attempts=1,
                                   timeout=min(self.reply_timeout, 0.1))
            except (DeviceTimeout, ProtocolError) as err:
                if time.monotonic() >= deadline:
                    raise DeviceTimeout(
                        f"controller did not answer within {self.reset_timeout:g} s "
                        f"after {text}", device=self.name, command=text,
                        hint="power-cycle the controller",
                    ) from err
                continue
            # Drop whatever the reboot left in the latch.
            self._read_error("TE")
            return status

    def _wait_phase(self, done: Callable[[Smc100Status], bool], command: str,
                    timeout: float = 30.0) -> Smc100Status:
        deadline = time.monotonic() + timeout
        while True:
            status = self._status_query()
            if done(status):
                return status
            if time.monotonic() >= deadline:
                raise DeviceTimeout(f"still {status.info.name} after {timeout:g} s",
                                    device=self.name, command=command)
            time.sleep(self.poll_interval)
