"""Stanford Research Systems SR830 (and SR810) DSP lock-in amplifier over RS-232.

Source of every protocol fact: Stanford Research Systems, *Model SR830 DSP Lock-In
Amplifier* manual, Revision 2.5 (10/2011): chapter 5 "Remote Programming" — RS-232
communications and command syntax (p. 5-1), interface ready and status (p. 5-2),
reference and phase ``FMOD``/``FREQ`` (p. 5-4), gain and time constant ``SENS``/``OFLT``/
``OFSL`` (p. 5-6), auto functions ``AGAN`` (p. 5-11), data transfer ``OUTP?``/``SNAP?``
(p. 5-15), interface ``OUTX``/``*IDN?``/``*RST`` (p. 5-19), status reporting and status
byte definitions (pp. 5-20 to 5-23); chapter 3 "What does a lock-in measure?" (p. 3-3) and
"Noise measurements" (p. 3-25, ENBW and the 99 % wait-time table). The table values and
bit meanings live in :mod:`drivers.sr830_protocol`.

Link
----
9600 baud by default (``baudrate=`` for another rate; the SR830's rate and parity are
front-panel settings of its Setup/Interface menu, so the host must match them), 8N1, no
flow control. Commands end in a linefeed; replies end in a carriage return. The SR830
sends replies to the interface selected with ``OUTX`` (a retained setting), so the driver
sends ``OUTX 0`` (RS-232) first, as the manual asks "at the beginning of every program".

Rules this driver follows
-------------------------
- Queries that change nothing (``*IDN?``, ``FREQ?``, ``FMOD?``, ``OFLT?``, ``SENS?``,
  ``OFSL?``, ``SNAP?``) are retried ``retries`` times after a timeout or an unreadable
  reply. Queries that clear what they read (``*ESR?``, ``ERRS?``, ``LIAS?``) are asked
  once.
- Replies carry no echo, so a reply that arrives after its timeout would be taken for the
  answer to the next query. After any failed exchange the driver therefore waits until the
  line has been quiet for ``reply_timeout`` (at most four times that) and drops what came,
  before it asks again; every reply is also checked for the shape its query produces
  (count of values, integer range). A reply later than about twice ``reply_timeout`` can
  still be mistaken; that is the protocol's limit, not a hang.
- Every setting is followed by ``*ESR?`` and ``ERRS?``: EXE or CMD becomes
  :class:`CommandRejected` naming the command, PON (the lock-in restarted and lost its
  settings) and any error bit become :class:`~drivers.errors.ControllerError`. What was
  latched before the connection is kept in :attr:`Sr830LockIn.events_at_connect` and
  :attr:`Sr830LockIn.errors_at_connect` and does not fail later commands.
- ``AGAN`` occupies the SR830 until it ends; commands sent meanwhile wait in its input
  queue and RS-232 has no serial poll, so :meth:`Sr830LockIn.auto_gain` asks ``*STB? 1``
  (IFC, "no command execution in progress") with a long reply timeout: the answer comes
  when the auto gain is over. The manual says ``AGAN`` does nothing above τ = 1 s; the
  driver refuses it there.

Beyond the LockIn interface (the bench's needs): :attr:`Sr830LockIn.harmonic` (``HARM``,
1f/2f detection for polarimetry) and :meth:`Sr830LockIn.read_harmonics` (one settled
snapshot per harmonic, e.g. 1f and 2f of a photoelastic modulator on REF IN),
:attr:`Sr830LockIn.reference_slope` (``RSLP``),
:meth:`Sr830LockIn.configure_input` (``ISRC``, ``IGND``, ``ICPL``, ``ILIN``) and the data
buffer for fast scans (:meth:`Sr830LockIn.start_buffer`, ``trigger``, ``pause_buffer``,
``buffer_points``, :meth:`Sr830LockIn.read_buffer`: ``SRAT``/``SEND``/``STRT``, then binary
``TRCB?`` in chunks, manual pp. 5-13 to 5-17).

SR860/SR865 are not supported: their command set uses other index tables for sensitivity
and time constant and other status bits (not confirmed against their manual here), so the
constructor refuses them with :class:`~drivers.errors.UnsupportedFeature` rather than
misreading them. The SR810 shares the SR830 command set and is accepted.

Units: volts rms (the SR830 reports the rms of the Fourier component at the reference
frequency: a square wave of 2 V pk-pk reads 1.273/√2 = 0.90 V, manual p. 3-3), degrees,
seconds, hertz.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import serial

from drivers.base import (
    DeviceIdentity,
    LockIn,
    LockInReading,
    LockInStatus,
    ReferenceSource,
    retry_count,
)
from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceError,
    DeviceTimeout,
    ProtocolError,
    StateError,
    UnsupportedFeature,
)
from drivers.sr830_protocol import (
    FILTER_SLOPES_DB,
    INPUT_SOURCES,
    LINE_FILTERS,
    MAX_HARMONIC,
    REFERENCE_SLOPES,
    REPLY_TERMINATOR,
    SAMPLE_RATES_HZ,
    SENSITIVITIES_V,
    TIME_CONSTANTS_S,
    EventStatus,
    LiaStatus,
    Sr830Identity,
    command_text,
    decode_error_status,
    format_command,
    index_of,
    parse_float,
    parse_floats,
    parse_identity,
    parse_int,
    parse_status_byte,
    parse_trace_binary,
    reply_text,
)
from drivers.transport import SerialChannel, open_serial

__all__ = ["CommandRejected", "Sr830Input", "Sr830LockIn"]

#: Models that speak the SR830 command set.
SUPPORTED_MODELS = ("SR830", "SR810")
#: Longest reply line accepted before the stream is declared garbage.
_MAX_LINE = 512
#: The manual: "AGAN does nothing if the time constant is greater than 1 second".
_AGAN_MAX_TIME_CONSTANT_S = 1.0
#: Points the buffer holds per channel.
_BUFFER_POINTS = 16383
#: Points per ``TRCB?`` request (4 kB: a few seconds at 9600 baud).
_TRACE_CHUNK = 1024

T = TypeVar("T")


class CommandRejected(ControllerError, StateError):
    """The SR830 flagged a command as illegal (CMD) or unable to execute (EXE)."""


@dataclass(frozen=True)
class Sr830Input:
    """The signal input's configuration (``ISRC``, ``IGND``, ``ICPL``, ``ILIN``)."""

    source: str  # "A", "A-B", "I1M", "I100M"
    grounded: bool
    dc_coupled: bool
    line_filters: str  # "none", "line", "2xline", "both"


def _choice(value: str, table: tuple[str, ...], what: str) -> int:
    if not isinstance(value, str) or value not in table:
        raise ValueError(f"{what} must be one of {table}, got {value!r}")
    return table.index(value)


class Sr830LockIn(LockIn):
    """An SR830 (or SR810) on a serial port.

    Parameters
    ----------
    port
        A device path (``/dev/ttyUSB0``), a pyserial URL (``simsr830://lockin``) or an open
        ``serial.SerialBase`` (used as is; the caller chose its settings).
    name
        Role name used in every error.
    baudrate
        Serial rate when opening ``port`` from a path or URL (the SR830 offers 300 to
        19200; default 9600).
    reply_timeout
        Seconds to wait for one reply line.
    retries
        Extra attempts for queries that change nothing, after a timeout or garbled reply.
    auto_gain_timeout
        Seconds :meth:`auto_gain` may take.
    sleep
        Waiting function for :meth:`settle` and :meth:`auto_range`.

    Raises
    ------
    ConnectionFailed
        The port cannot be opened or nothing answers ``*IDN?``.
    UnsupportedFeature
        The instrument answers but is not an SR830/SR810.
    """

    sensitivities_v = SENSITIVITIES_V
    time_constants_s = TIME_CONSTANTS_S
    filter_slopes_db_per_oct = FILTER_SLOPES_DB
    DEFAULT_BAUDRATE = 9600

    def __init__(
        self,
        port: str | serial.SerialBase,
        *,
        name: str,
        baudrate: int = DEFAULT_BAUDRATE,
        reply_timeout: float = 0.5,
        retries: int = 2,
        auto_gain_timeout: float = 120.0,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if isinstance(baudrate, bool) or not isinstance(baudrate, int) or baudrate <= 0:
            raise ValueError(f"baudrate must be a positive integer, got {baudrate!r}")
        if not reply_timeout > 0 or not auto_gain_timeout > 0:
            raise ValueError("timeouts must be > 0")
        retries = retry_count(retries)
        super().__init__(name, sleep=sleep)
        self.reply_timeout = float(reply_timeout)
        self.retries = int(retries)
        self.auto_gain_timeout = float(auto_gain_timeout)
        # One exchange at a time (a query and its reply).
        self._io_lock = threading.RLock()
        #: Empty lines and unusable replies dropped while resynchronising, for diagnosis.
        self.dropped_bytes = 0
        #: ``*ESR?`` and ``ERRS?`` as found at connection (latched before our time).
        self.events_at_connect: EventStatus | None = None
        self.errors_at_connect: tuple[str, ...] = ()
        self.model: Sr830Identity | None = None
        self._channel: SerialChannel | None = None
        raw = open_serial(port, device=name, baudrate=baudrate)
        #: For the wire time of long binary replies (an open port keeps its own rate).
        self._baudrate = int(getattr(raw, "baudrate", None) or baudrate)
        try:
            self._channel = SerialChannel(raw, device=name)
            self._connect()
        except BaseException:
            # A failed constructor leaves nothing open that it opened itself.
            self._channel = None
            if not isinstance(port, serial.SerialBase):
                raw.close()
            raise

    # connection ---------------------------------------------------------------
    def _connect(self) -> None:
        # Direct the replies to RS-232 before the first query (OUTX is retained in the
        # instrument, and a unit last used over GPIB answers RS-232 queries nowhere).
        self._write("OUTX", 0)
        try:
            idn = self._ask("*IDN?", parse=parse_identity)
        except (DeviceTimeout, ProtocolError) as err:
            raise ConnectionFailed(
                "no SR830 answers *IDN?", device=self.name, command="*IDN?",
                hint="check the cable (straight DB-25), the baud rate and parity set in the "
                "lock-in's Setup menu, and that it is switched on",
            ) from err
        if idn.model.upper() not in SUPPORTED_MODELS:
            raise UnsupportedFeature(
                f"{idn.vendor} {idn.model} is not an SR830/SR810; its command set (index "
                "tables, status bits) differs", device=self.name, command="*IDN?",
                hint="use a driver for that model",
            )
        self.model = idn
        self._identity = DeviceIdentity(
            vendor="Stanford Research Systems" if "stanford" in idn.vendor.lower()
            else idn.vendor,
            model=idn.model, serial=idn.serial, firmware=idn.firmware,
        )
        # What was latched before our time: kept, then cleared by the reads.
        self.events_at_connect = EventStatus(self._ask_once("*ESR?", parse_status_byte))
        self.errors_at_connect = decode_error_status(self._ask_once("ERRS?",
                                                                    parse_status_byte))
        self._ask_once("LIAS?", parse_status_byte)

    # wire ---------------------------------------------------------------------
    def _chan(self, text: str) -> SerialChannel:
        if self._channel is None:
            raise StateError("device is closed", device=self.name, command=text)
        return self._channel

    def _write(self, mnemonic: str, *args: int | float) -> str:
        """Drop stale input and write one command line; return its text for errors."""
        request = format_command(mnemonic, *args)
        text = request.decode("ascii").strip()
        channel = self._chan(text)
        channel.discard_input()
        channel.write(request, command=text)
        return text

    def _read_reply(self, text: str, timeout: float | None = None) -> str:
        """The next non-empty reply line's text (empty lines are line noise)."""
        timeout = self.reply_timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        channel = self._chan(text)
        while True:
            line = channel.read_line(REPLY_TERMINATOR, timeout=max(deadline - time.monotonic(),
                                                                   0.0),
                                     command=text, max_bytes=_MAX_LINE)
            try:
                value = reply_text(line)
            except ProtocolError as err:
                raise ProtocolError(err.message, device=self.name, command=text) from err
            if value:
                return value
            self.dropped_bytes += len(line)

    def _resync(self, text: str) -> None:
        """Wait until the line is quiet for ``reply_timeout`` and drop what arrived (a late
        reply must not answer the next query)."""
        channel = self._chan(text)
        quiet = self.reply_timeout
        end = time.monotonic() + 4 * quiet
        last = time.monotonic()
        while time.monotonic() < end:
            got = channel.read_available(command=text)
            now = time.monotonic()
            if got:
                self.dropped_bytes += len(got)
                last = now
            elif now - last >= quiet:
                return
            time.sleep(min(0.005, quiet / 10))

    def _ask(self, mnemonic: str, *args: int | float,
             parse: Callable[[Any], T] = str,  # type: ignore[assignment]  # T is str when parse is left out; mypy cannot tie a default to a type variable
             attempts: int | None = None, read: Callable[[str], Any] | None = None) -> T:
        """A query that changes nothing, retried after a timeout or an unusable reply.
        ``read(text)`` reads the raw reply (default: one reply line)."""
        read = self._read_reply if read is None else read
        attempts = self.retries + 1 if attempts is None else attempts
        text = command_text(mnemonic, *args)
        last: DeviceError | None = None
        for _ in range(attempts):
            with self._io_lock:
                try:
                    self._write(mnemonic, *args)
                    reply = read(text)
                    try:
                        return parse(reply)
                    except ProtocolError as err:
                        raise ProtocolError(err.message, device=self.name,
                                            command=text) from err
                except (DeviceTimeout, ProtocolError) as err:
                    last = err
                    self._resync(text)
        assert last is not None
        suffix = f" (after {attempts} attempts)" if attempts > 1 else ""
        raise type(last)(last.message + suffix, device=self.name, command=text,
                         hint=last.hint or "check the connection and the lock-in",
                         ) from last

    def _ask_once(self, mnemonic: str, parse: Callable[[str], T], *args: int | float,
                  after: str | None = None, timeout: float | None = None) -> T:
        """A query that clears what it reads: asked once, never retried."""
        text = command_text(mnemonic, *args)
        context = after or text
        with self._io_lock:
            try:
                self._write(mnemonic, *args)
                reply = self._read_reply(text, timeout)
                return parse(reply)
            except ProtocolError as err:
                self._resync(text)
                raise ProtocolError(f"unreadable {text} reply: {err.message}",
                                    device=self.name, command=context,
                                    hint="the outcome is unknown; read the setting back",
                                    ) from err
            except DeviceTimeout as err:
                self._resync(text)
                raise DeviceTimeout(f"no {text} reply", device=self.name, command=context,
                                    hint="the outcome is unknown; read the setting back",
                                    ) from err

    def _command(self, mnemonic: str, *args: int | float) -> None:
        """A setting, then its check: ``*ESR?`` (EXE, CMD, PON) and ``ERRS?``."""
        with self._io_lock:
            text = self._write(mnemonic, *args)
            self._check(text)

    def _check(self, text: str) -> None:
        events = EventStatus(self._ask_once("*ESR?", parse_status_byte, after=text))
        errors = self._ask_once("ERRS?", parse_status_byte, after=text)
        if events.command_error or events.execution_error:
            raise CommandRejected(
                f"the lock-in rejected the command: {', '.join(events.texts)} "
                f"(*ESR {events.byte})", code=events.byte, device=self.name, command=text,
                hint="check the value against the manual's range for this command",
            )
        if events.power_on:
            raise ControllerError(
                "the lock-in restarted (power-on bit set): its settings are back at their "
                "power-up values", code=events.byte, device=self.name, command=text,
                hint="re-apply the bench profile's settings",
            )
        if events.queue_overflow:
            raise ControllerError(f"the lock-in's {', '.join(events.texts)}",
                                  code=events.byte, device=self.name, command=text)
        if errors:
            raise ControllerError(
                f"the lock-in reports {', '.join(decode_error_status(errors))} "
                f"(ERRS {errors})", code=errors, device=self.name, command=text,
                hint="power-cycle the lock-in; a self-test error that persists needs service",
            )

    # public extras ------------------------------------------------------------
    def check_errors(self) -> None:
        """Read and clear ``*ESR?``/``ERRS?``; raise what they report (see the module)."""
        self._check_open("check_errors")
        with self._io_lock:
            self._check("check_errors")

    def auto_gain(self, timeout: float | None = None) -> float:
        """Run the SR830's own auto gain (``AGAN``) and return the full scale it chose.

        Raises :class:`~drivers.errors.StateError` above τ = 1 s (where the SR830 ignores
        ``AGAN``) and :class:`~drivers.errors.DeviceTimeout` if it is not over within
        ``timeout`` s (default :attr:`auto_gain_timeout`).
        """
        self._check_open("auto_gain")
        timeout = self.auto_gain_timeout if timeout is None else float(timeout)
        if not timeout > 0:
            raise ValueError("timeout must be > 0")
        tau = self._do_get_time_constant_s()
        if tau > _AGAN_MAX_TIME_CONSTANT_S:
            raise StateError(
                f"auto gain does nothing at a time constant of {tau:g} s (> 1 s)",
                device=self.name, command="AGAN",
                hint="shorten the time constant, or use auto_range()",
            )
        deadline = time.monotonic() + timeout
        with self._io_lock:
            text = self._write("AGAN")
            while True:
                # Answered only once the SR830 executes commands again (IFC set).
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise DeviceTimeout(f"auto gain not over within {timeout:g} s",
                                        device=self.name, command=text,
                                        hint="raise the timeout; long time constants slow it")
                ready = self._ask_once("*STB?", lambda t: parse_int(t, 0, 1), 1,
                                       after=text, timeout=remaining)
                if ready:
                    break
            self._check(text)
        return self._do_get_sensitivity_v()

    # harmonic, reference trigger, input ------------------------------------------
    @property
    def harmonic(self) -> int:
        """Detection harmonic ``HARM`` (1 = the reference frequency itself)."""
        self._check_open("harmonic")
        return self._ask("HARM?", parse=lambda t: parse_int(t, 1, MAX_HARMONIC))

    @harmonic.setter
    def harmonic(self, value: int) -> None:
        self._check_open("harmonic")
        if isinstance(value, bool) or not isinstance(value, int) or not (
                1 <= value <= MAX_HARMONIC):
            raise ValueError(f"harmonic must be an integer 1 to {MAX_HARMONIC}, got {value!r}")
        # i·f > 102 kHz is refused by the SR830 itself (CommandRejected naming HARM).
        self._command("HARM", value)

    def read_harmonics(self, harmonics: tuple[int, ...] = (1, 2), *,
                       n_time_constants: float | None = None,
                       timeout: float = 60.0) -> dict[int, LockInReading]:
        """One settled snapshot per detection harmonic, the harmonic restored afterwards.

        With a photoelastic modulator on REF IN (``reference_source`` external), harmonics
        1 and 2 are its 1f and 2f terms (the Bessel-weighted circular and linear
        polarisation signals). The SR830 detects up to 102 kHz (``HARM`` i·f ≤ 102 kHz,
        manual p. 5-4): a 50 kHz head's 2f (100 kHz) fits; a higher harmonic or a faster
        head is refused by the instrument with :class:`CommandRejected` naming ``HARM``.
        Each harmonic change waits the present filter's 99 % settling time (:meth:`settle`,
        ``timeout`` each), or ``n_time_constants`` × τ: after a 99 % wait up to 1 % of the
        step between the two harmonics' outputs is still in the reading, which a
        polarimeter reduced to 10⁻³ has to wait out (e.g. 15 τ).
        """
        self._check_open("read_harmonics")
        if not harmonics:
            raise ValueError(f"{self.name}: give at least one harmonic")
        before = self.harmonic
        readings: dict[int, LockInReading] = {}
        try:
            for n in harmonics:
                self.harmonic = n
                self.settle(n_time_constants, timeout=timeout)
                readings[n] = self.snapshot()
        finally:
            if self.harmonic != before:
                self.harmonic = before
        return readings

    def read_aux_input(self, channel: int = 1) -> float:
        """The voltage at the rear-panel Aux In ``channel`` (1-4), volts (``OAUX?``, manual
        p. 5-13): e.g. a photodiode's DC output beside its AC signal on the input, the DC
        channel of a PEM polarimeter."""
        self._check_open("read_aux_input")
        if isinstance(channel, bool) or not isinstance(channel, int) or not 1 <= channel <= 4:
            raise ValueError(f"{self.name}: an aux input is 1 to 4, got {channel!r}")
        return self._ask("OAUX?", channel, parse=parse_float)

    @property
    def reference_slope(self) -> str:
        """What the external reference triggers on: ``"sine"``, ``"rising"`` or
        ``"falling"`` (TTL edges) — ``RSLP``."""
        self._check_open("reference_slope")
        index = self._ask("RSLP?", parse=lambda t: parse_int(t, 0, len(REFERENCE_SLOPES) - 1))
        return REFERENCE_SLOPES[index]

    @reference_slope.setter
    def reference_slope(self, value: str) -> None:
        self._check_open("reference_slope")
        self._command("RSLP", _choice(value, REFERENCE_SLOPES, "reference_slope"))

    @property
    def input_configuration(self) -> Sr830Input:
        """Input source, shield grounding, coupling and line notch filters."""
        self._check_open("input_configuration")
        return Sr830Input(
            source=INPUT_SOURCES[self._ask("ISRC?", parse=lambda t: parse_int(t, 0, 3))],
            grounded=bool(self._ask("IGND?", parse=lambda t: parse_int(t, 0, 1))),
            dc_coupled=bool(self._ask("ICPL?", parse=lambda t: parse_int(t, 0, 1))),
            line_filters=LINE_FILTERS[self._ask("ILIN?", parse=lambda t: parse_int(t, 0, 3))],
        )

    def configure_input(self, *, source: str | None = None, grounded: bool | None = None,
                        dc_coupled: bool | None = None,
                        line_filters: str | None = None) -> Sr830Input:
        """Set what is given (all validated before anything is sent); return the result.

        ``source``: ``"A"``, ``"A-B"``, ``"I1M"``, ``"I100M"`` (current input, 10⁶ or
        10⁸ V/A); ``line_filters``: ``"none"``, ``"line"``, ``"2xline"``, ``"both"``.
        """
        self._check_open("configure_input")
        settings: list[tuple[str, int]] = []
        if source is not None:
            settings.append(("ISRC", _choice(source, INPUT_SOURCES, "source")))
        for mnemonic, flag, what in (("IGND", grounded, "grounded"),
                                     ("ICPL", dc_coupled, "dc_coupled")):
            if flag is not None:
                if not isinstance(flag, bool):
                    raise TypeError(f"{what} must be True or False, got {flag!r}")
                settings.append((mnemonic, int(flag)))
        if line_filters is not None:
            settings.append(("ILIN", _choice(line_filters, LINE_FILTERS, "line_filters")))
        for mnemonic, index in settings:
            self._command(mnemonic, index)
        return self.input_configuration

    # data buffer ----------------------------------------------------------------
    def start_buffer(self, sample_rate_hz: float | None, *, loop: bool = False) -> None:
        """Clear the buffer and start storing CH1 and CH2 (X and Y unless the displays
        were changed on the instrument) at ``sample_rate_hz`` (one of
        :data:`~drivers.sr830_protocol.SAMPLE_RATES_HZ`, 62.5 mHz to 512 Hz) or, with
        ``None``, one point per :meth:`trigger`. One shot (stops when 16383 points are
        stored) unless ``loop``."""
        self._check_open("start_buffer")
        if sample_rate_hz is None:
            rate = 14
        else:
            matches = [i for i, r in enumerate(SAMPLE_RATES_HZ)
                       if math.isclose(r, sample_rate_hz, rel_tol=1e-9)]
            if not matches:
                raise ValueError(f"sample_rate_hz must be one of {SAMPLE_RATES_HZ} Hz or "
                                 f"None (per trigger), got {sample_rate_hz!r}")
            rate = matches[0]
        for mnemonic, *args in (("REST",), ("SRAT", rate), ("SEND", int(bool(loop))),
                                ("STRT",)):
            self._command(mnemonic, *args)

    def trigger(self) -> None:
        """``TRIG``: one buffer point (at a per-trigger rate)."""
        self._check_open("trigger")
        self._command("TRIG")

    def pause_buffer(self) -> None:
        self._check_open("pause_buffer")
        self._command("PAUS")

    def buffer_points(self) -> int:
        """Points stored so far (``SPTS?``)."""
        self._check_open("buffer_points")
        return self._ask("SPTS?", parse=lambda t: parse_int(t, 0, _BUFFER_POINTS))

    def read_buffer(self, channel: int, start: int = 0,
                    count: int | None = None) -> np.ndarray:
        """Points ``start`` … ``start + count − 1`` of display ``channel`` (1 or 2; all
        stored from ``start`` if ``count`` is None), read as binary (``TRCB?``) in
        chunks of :data:`_TRACE_CHUNK` points, each retried like any query."""
        self._check_open("read_buffer")
        if channel not in (1, 2) or isinstance(channel, bool):
            raise ValueError(f"channel must be 1 or 2, got {channel!r}")
        stored = self.buffer_points()
        if count is None:
            count = stored - start
        if not 0 <= start <= stored or not 0 <= count <= stored - start:
            raise ValueError(f"points {start} to {start + (count or 0) - 1} are not all "
                             f"stored ({stored} points)")
        out = np.empty(count)
        channel_port = self._chan("TRCB?")
        done = 0
        while done < count:
            n = min(_TRACE_CHUNK, count - done)
            # The wire time of 4n bytes at 10 bits a byte, with a factor two to spare.
            timeout = self.reply_timeout + 2 * 40 * n / self._baudrate

            def read(text: str, n: int = n, timeout: float = timeout) -> bytes:
                return channel_port.read_exact(4 * n, timeout=timeout, command=text)

            out[done:done + n] = self._ask(
                "TRCB?", channel, start + done, n, read=read,
                # mypy cannot solve _ask's type variable through a lambda with a default
                parse=lambda data, n=n: parse_trace_binary(data, n))  # type: ignore[misc]
            done += n
        return out

    # LockIn hooks ---------------------------------------------------------------
    def _do_identity(self) -> DeviceIdentity:
        assert self._identity is not None  # read at connection
        return self._identity

    def _do_get_reference_frequency_hz(self) -> float:
        frequency = self._ask("FREQ?", parse=parse_float)
        if frequency < 0:
            raise ProtocolError(f"negative reference frequency {frequency:g} Hz",
                                device=self.name, command="FREQ?")
        return frequency

    def _do_get_reference_source(self) -> ReferenceSource:
        mode = self._ask("FMOD?", parse=lambda t: parse_int(t, 0, 1))
        return ReferenceSource.INTERNAL if mode == 1 else ReferenceSource.EXTERNAL

    def _do_set_reference_source(self, source: ReferenceSource) -> None:
        self._command("FMOD", 1 if source is ReferenceSource.INTERNAL else 0)

    def _do_get_time_constant_s(self) -> float:
        index = self._ask("OFLT?", parse=lambda t: parse_int(t, 0, len(TIME_CONSTANTS_S) - 1))
        return TIME_CONSTANTS_S[index]

    def _do_set_time_constant_s(self, value: float) -> None:
        self._command("OFLT", index_of(TIME_CONSTANTS_S, value, "time constant"))

    def _do_get_filter_slope(self) -> int:
        index = self._ask("OFSL?", parse=lambda t: parse_int(t, 0, len(FILTER_SLOPES_DB) - 1))
        return FILTER_SLOPES_DB[index]

    def _do_set_filter_slope(self, db_per_oct: int) -> None:
        self._command("OFSL", FILTER_SLOPES_DB.index(db_per_oct))

    def _do_get_sensitivity_v(self) -> float:
        index = self._ask("SENS?", parse=lambda t: parse_int(t, 0, len(SENSITIVITIES_V) - 1))
        return SENSITIVITIES_V[index]

    def _do_set_sensitivity_v(self, value: float) -> None:
        self._command("SENS", index_of(SENSITIVITIES_V, value, "sensitivity"))

    def _do_snapshot(self) -> LockInReading:
        x, y, r, theta = self._ask("SNAP?", 1, 2, 3, 4, parse=lambda t: parse_floats(t, 4))
        if r < 0 or not -180.0 <= theta <= 180.0:
            raise ProtocolError(f"implausible snapshot R={r:g} V, theta={theta:g} deg",
                                device=self.name, command="SNAP? 1,2,3,4")
        return LockInReading(x_v=x, y_v=y, r_v=r, theta_deg=theta, timestamp=time.time())

    def _do_status(self) -> LockInStatus:
        lia = LiaStatus(self._ask_once("LIAS?", parse_status_byte))
        return LockInStatus(
            input_overload=lia.input_overload, filter_overload=lia.filter_overload,
            output_overload=lia.output_overload, reference_unlocked=lia.unlocked,
        )

    def _do_close(self) -> None:
        if self._channel is not None:
            self._channel.close()
            self._channel = None
