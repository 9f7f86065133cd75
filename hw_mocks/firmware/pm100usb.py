"""SCPI model of a Thorlabs PM100USB power meter console with a silicon photodiode head.

This is the instrument's *firmware*: it receives complete SCPI messages (the USBTMC layer
in :mod:`hw_mocks.usb.backend` strips the bulk framing) and returns the response
messages. It imports nothing from ``drivers/``, so a shared misunderstanding of the
protocol cannot pass the tests on both sides.

Command subset (Thorlabs *PM100USB Operation Manual* (2020), ch. 7 "Computer Interface";
QMI ``pm100d.py``, pylablib ``GenericPM``)::

    *IDN?  *RST  *CLS  *OPC?
    SYSTem:ERRor[:NEXT]?                     -> <code>,"<message>"   (FIFO, 10 entries)
    SYSTem:SENSor:IDN?                       -> name,serial,cal,type,subtype,flags
    [SENSe:]CORRection:WAVelength <nm>|MIN|MAX|DEF   and  ...WAVelength? [MIN|MAX]
    [SENSe:]POWer[:DC]:RANGe:AUTO <bool>     and  ...AUTO?
    [SENSe:]POWer[:DC]:RANGe[:UPPer] <W>     and  ...RANGe?
    [SENSe:]AVERage:COUNt <n>                and  ...COUNt?
    [SENSe:]CORRection:COLLect:ZERO[:INITiate] | :ABORt | :STATe? | :MAGNitude?
    MEASure[:SCALar]:POWer?   READ?   CONFigure[:SCALar]:POWer   CONFigure?
    INITiate[:IMMediate]      FETCh?  MEASure[:SCALar]:CURRent?

Not emulated (the rest of the manual's ch. 7 command list; each answered as the console
answers a header it does not know: error -113 "Undefined header" queued, nothing sent,
listed in :data:`NOT_EMULATED_HEADERS`): ``*ESE *ESR? *SRE *STB? *TST? *WAI`` (the status
byte is kept for the USBTMC layer's READ_STATUS_BYTE only), the ``STATus`` subsystem,
``SYSTem:BEEPer``, ``SYSTem:DATE``/``TIME``, ``SYSTem:LFRequency``, ``SYSTem:VERSion?``,
``DISPlay`` brightness and contrast, ``CALibration:STRing?``, ``ABORt``, the input
filter (``INPut:PDIode:FILTer``), beam diameter and loss corrections
(``CORRection:BEAMdiameter``, ``CORRection:LOSS``), the photodiode responsivity query
(``CORRection:POWer:PDIode:RESPonse?``), current/voltage/energy/frequency/density/
resistance/temperature measurements and their ``CONFigure``/``MEASure`` forms, the peak
detector and the thermopile accelerator (a photodiode head has neither).

Syntax follows SCPI-99 §6 as far as a bench needs it: keywords in short or long form,
case-insensitive, ``[SENSe]`` optional, numeric suffix ``1`` accepted, several commands
per message separated by ``;`` (each parsed from the root), numbers in NR1/NR2/NR3.
Errors go to the queue with their standard SCPI codes (-100 command error, -104 data
type error, -108 parameter not allowed, -109 missing parameter, -113 undefined header,
-200 execution error, -221 settings conflict, -222 data out of range, -224 illegal
parameter value, -230 data stale, -350 queue overflow, -410 query INTERRUPTED, -420 query
UNTERMINATED); a query that fails sends no response, as IEEE 488.2 requires.

Measurement model (documented emulator choices, not a calibration):

* The light comes from the virtual bench through :attr:`Pm100usbFirmware.optical_power_w`,
  a callable ``f(wavelength_nm) -> W`` asked for the power of the light at its own
  wavelength :attr:`light_wavelength_nm` (a number, a callable the bench answers at each
  reading, or ``None``: the light is at the wavelength the meter is set to).
* The photodiode converts it to current ``I = R(λ_light)·P + I_dark`` with a silicon-like
  responsivity ``R(λ) = η(λ)·λ/1239.84 A/W`` (photon energy hc/λ; ``η`` a smooth
  illustrative quantum efficiency). The console displays ``(I − I_zero)/R(λ_set)``, so a
  wrong wavelength setting scales the reading by ``R(λ_light)/R(λ_set)``.
* Each sample carries Gaussian noise ``σ_I = sqrt(noise_floor_a² + (relative_noise·R·P)²)``;
  an ``AVER:COUN n`` reading is the mean of ``n`` samples (σ/√n).
* Which noise: alone, the readings draw from one seeded stream, in order. Bound to a
  virtual bench (:meth:`hw_mocks.sim.world.VirtualBench.bind_power_meter`), each reading's
  noise is keyed to the bench state it reads (:attr:`Pm100usbFirmware.noise_state`: stage
  positions and the light at the sample) — seed, state, which visit of that state (a
  state is visited anew each time the readings' state changes to it) and which reading of
  the visit, hashed together into one key per reading (ADR 0111). Readings taken while
  the bench rests between runs (a server polling the meter) then leave a run's readings
  unchanged: the run moves the bench to each point, a new visit, and draws the same
  values however many readings came before. ``I_dark`` stays in the reading until a dark
  zero measures it (:meth:`zero_samples` samples); ``*RST`` forgets
  the zero ("no way of resetting the zero value other than full device reset").
* Zeroing runs :attr:`zero_duration_s` on the emulator clock; ``ZERO:STAT?`` answers 1
  while it runs and 0 when done (the convention most open drivers poll for).
* Measurement time, range quantisation and over-range are not modelled.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections import Counter, deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass

import numpy as np

from hw_mocks.clock import Clock
from hw_mocks.emulator import FirmwareEmulator

__all__ = [
    "ERROR_MESSAGES",
    "NOT_EMULATED_HEADERS",
    "Pm100usbFirmware",
    "ScpiError",
    "SensorHead",
    "parse_scpi_number",
    "silicon_responsivity_a_per_w",
]

#: Examples of the manual's headers this model answers as undefined (see the module).
NOT_EMULATED_HEADERS = (
    "*ESE 4", "*ESR?", "*SRE 16", "*STB?", "*TST?", "*WAI", "STAT:OPER?", "SYST:BEEP",
    "SYST:DATE?", "SYST:TIME?", "SYST:LFR?", "SYST:VERS?", "DISP:BRIG?", "CAL:STR?",
    "ABOR", "INP:PDI:FILT:LPAS:STAT?", "CORR:BEAM?", "CORR:LOSS?",
    "CORR:POW:PDI:RESP?", "MEAS:VOLT?", "MEAS:ENER?", "MEAS:FREQ?", "MEAS:PDEN?",
    "MEAS:TEMP?", "CONF:ENER", "PEAK:THR?", "INP:THER:ACC?",
)

#: Standard SCPI-99 error messages used by this model (SCPI-99 Vol. 2, §21.8).
ERROR_MESSAGES: dict[int, str] = {
    0: "No error",
    -100: "Command error",
    -104: "Data type error",
    -108: "Parameter not allowed",
    -109: "Missing parameter",
    -113: "Undefined header",
    -200: "Execution error",
    -221: "Settings conflict",
    -222: "Data out of range",
    -224: "Illegal parameter value",
    -230: "Data corrupt or stale",
    -300: "Device-specific error",
    -350: "Queue overflow",
    -410: "Query INTERRUPTED",
    -420: "Query UNTERMINATED",
}

_ERROR_QUEUE_LENGTH = 10
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)


class ScpiError(Exception):
    """A command failed; ``code`` is the SCPI error number that goes to the queue."""

    def __init__(self, code: int, detail: str = "") -> None:
        super().__init__(code, detail)
        self.code = code
        self.detail = detail


def parse_scpi_number(text: str) -> float:
    """An SCPI ``<DECIMAL NUMERIC PROGRAM DATA>`` (NR1, NR2 or NR3) as a float.

    Raises :class:`ScpiError` (-104, data type error) for anything else, including
    ``nan``/``inf`` spellings that Python's ``float`` would accept.
    """
    text = text.strip()
    if not _NUMBER.fullmatch(text):
        raise ScpiError(-104, f"not a number: {text!r}")
    value = float(text)
    if not math.isfinite(value):
        raise ScpiError(-222, f"number out of range: {text!r}")
    return value


def silicon_responsivity_a_per_w(wavelength_nm: float) -> float:
    """Illustrative silicon photodiode responsivity in A/W.

    ``R = η·λ/1239.84`` with λ in nm (1239.84 nm·V = hc/e, so λ/1239.84 is the
    responsivity of a detector with unit quantum efficiency). The quantum efficiency
    ``η(λ) = 0.85·(1 − exp(−(λ − 300)/150)) / (1 + exp((λ − 1050)/25))`` rises through
    the blue and collapses at silicon's band edge near 1100 nm; it is a smooth stand-in
    for a calibration table, giving about 0.13 A/W at 400 nm and 0.6 A/W near 950 nm.
    """
    wl = float(wavelength_nm)
    eta = 0.85 * (1.0 - math.exp(-(wl - 300.0) / 150.0)) / (1.0 + math.exp((wl - 1050.0) / 25.0))
    return max(eta, 1e-6) * wl / 1239.84


@dataclass(frozen=True)
class SensorHead:
    """What ``SYST:SENS:IDN?`` reports, and the head's wavelength range."""

    name: str = "S120C"
    serial: str = "200611301"
    calibration: str = "21-Jun-2024"
    sensor_type: int = 1        # photodiode
    subtype: int = 2            # single photodiode with temperature sensor (model choice)
    flags: int = 289
    wavelength_min_nm: float = 400.0
    wavelength_max_nm: float = 1100.0
    default_wavelength_nm: float = 635.0
    max_power_w: float = 0.05

    def idn(self) -> str:
        return ",".join(
            [self.name, self.serial, self.calibration, str(self.sensor_type),
             str(self.subtype), str(self.flags)]
        )


# --------------------------------------------------------------------------- SCPI syntax

def _parse_pattern(pattern: str) -> tuple[tuple[str, str, bool], ...]:
    """``"[SENSe]:CORRection:WAVelength"`` → ((short, long, optional), ...)."""
    nodes = []
    for part in pattern.replace("[:", ":[").split(":"):
        optional = part.startswith("[")
        name = part.strip("[]")
        short = "".join(c for c in name if not c.islower())
        nodes.append((short.upper(), name.upper(), optional))
    return tuple(nodes)


def _match(nodes: tuple[tuple[str, str, bool], ...], tokens: list[str]) -> bool:
    if not nodes:
        return not tokens
    short, long, optional = nodes[0]
    if tokens:
        token = tokens[0]
        # A numeric suffix selects a channel/sensor; the PM100USB has only number 1.
        stem = token.rstrip("0123456789")
        suffix = token[len(stem):]
        if suffix in ("", "1") and stem in (short, long) and _match(nodes[1:], tokens[1:]):
            return True
    return optional and _match(nodes[1:], tokens)


@dataclass(frozen=True)
class _Command:
    nodes: tuple[tuple[str, str, bool], ...]
    query: bool
    handler: Callable[[list[str]], str | None]


# --------------------------------------------------------------------------- the model

class Pm100usbFirmware(FirmwareEmulator):
    """The console's SCPI firmware and its photodiode head.

    Parameters
    ----------
    name
        Instance name (``simusb://<name>``).
    serial
        Console serial number (``*IDN?`` field 3 and the USB iSerialNumber string).
    clock
        Emulator clock; zeroing duration is measured on it.
    seed
        Seeds the fault injector and the sensor noise generator.
    sensor
        The sensor head that is plugged in.
    """

    scheme = "simusb"
    firmware_version = "1.7.0"

    def __init__(
        self,
        name: str,
        *,
        serial: str = "P2000000",
        clock: Clock | None = None,
        seed: int = 0,
        sensor: SensorHead | None = None,
    ) -> None:
        super().__init__(name, clock=clock, seed=seed)
        self.serial = serial
        self.sensor = sensor if sensor is not None else SensorHead()
        self._rng = np.random.default_rng(seed)
        self._seed = int(seed)
        #: The bench state a reading reads (set by a virtual bench): each reading's noise is
        #: keyed to it (the module's docstring); ``None``: one stream, in reading order.
        self.noise_state: Callable[[], Hashable] | None = None
        self._visits: Counter[int] = Counter()
        self._visit: list[int] | None = None  # [state digest, visit number, readings]
        #: The virtual bench's light: ``f(wavelength_nm) -> power in W at the sensor``.
        self.optical_power_w: Callable[[float], float] = lambda _wl: 0.0
        #: Wavelength of the incident light (nm), or a callable giving it at each reading
        #: (a bench whose light changes colour: a filter wheel); ``None``: whatever the
        #: meter is set to.
        self.light_wavelength_nm: float | Callable[[], float] | None = None
        #: Dark current of the photodiode (A): the offset that zeroing removes.
        self.dark_current_a = 2.0e-9
        #: Per-sample current noise floor (A) and relative (signal-proportional) noise.
        self.noise_floor_a = 1.0e-10
        self.relative_noise = 1.0e-4
        #: Samples averaged during a dark zero, and its duration on the emulator clock.
        self.zero_samples = 1000
        self.zero_duration_s = 0.3
        #: Backdoor: a zero that never finishes (tests the driver's timeout).
        self.zero_stuck = False
        #: Every SCPI program message unit received, for tests.
        self.commands: list[str] = []
        self._last_reply = b""
        self._errors: deque[tuple[int, str]] = deque()
        self._table = self._build_table()
        self._reset_settings()

    # -- state ------------------------------------------------------------------------
    def _reset_settings(self) -> None:
        self.wavelength_nm = self.sensor.default_wavelength_nm
        self.auto_range = True
        self.range_w = self.sensor.max_power_w
        self.average_count = 1
        self.zero_current_a = 0.0
        self._zero_started: float | None = None
        self._zero_pending_a = 0.0
        self._fetched: float | None = None

    def responsivity_a_per_w(self, wavelength_nm: float) -> float:
        """The head's responsivity (A/W) at ``wavelength_nm``."""
        return silicon_responsivity_a_per_w(wavelength_nm)

    def true_power_w(self) -> float:
        """Optical power the bench delivers now (W), at the light's wavelength."""
        return float(self.optical_power_w(self._light_wavelength()))

    def _light_wavelength(self) -> float:
        wl = self.light_wavelength_nm
        if callable(wl):
            wl = wl()
        if wl is None:
            return self.wavelength_nm
        return float(wl)

    def _sample_current_a(self, n: int) -> float:
        """Mean photocurrent of ``n`` samples (A), with the noise model."""
        light = self._light_wavelength()
        signal = self.responsivity_a_per_w(light) * max(self.true_power_w(), 0.0)
        sigma = math.hypot(self.noise_floor_a, self.relative_noise * signal)
        return signal + self.dark_current_a + float(self._noise().normal(0.0, sigma / math.sqrt(n)))

    def _noise(self) -> np.random.Generator:
        """The generator of the next reading's noise (see the module's docstring)."""
        if self.noise_state is None:
            return self._rng
        # repr: stable across processes (hash() of a str is salted per process)
        digest = int.from_bytes(hashlib.blake2b(repr(self.noise_state()).encode(),
                                                digest_size=8).digest(), "little")
        if self._visit is None or self._visit[0] != digest:
            self._visits[digest] += 1
            self._visit = [digest, self._visits[digest], 0]
        visit = self._visit
        visit[2] += 1
        # one 128-bit key hashed from every part (seed, state, visit, reading), not the
        # parts as separate seed words: each reading's generator is as unrelated to the
        # others as a hash makes it, with no reliance on how SeedSequence mixes words that
        # repeat from seed to seed (the states of one plan do)
        key = hashlib.blake2b(f"{self._seed}|{digest}|{visit[1]}|{visit[2]}".encode(),
                              digest_size=16).digest()
        return np.random.default_rng(int.from_bytes(key, "little"))

    def _measure_power_w(self) -> float:
        current = self._sample_current_a(self.average_count)
        return (current - self.zero_current_a) / self.responsivity_a_per_w(self.wavelength_nm)

    def _zero_running(self) -> bool:
        if self._zero_started is None:
            return False
        if self.zero_stuck or self.clock.now() - self._zero_started < self.zero_duration_s:
            return True
        self.zero_current_a = self._zero_pending_a
        self._zero_started = None
        return False

    # -- error queue ------------------------------------------------------------------
    def push_error(self, code: int, detail: str = "") -> None:
        """Append an error to the queue (SCPI: a full queue ends in -350)."""
        with self.lock:
            text = ERROR_MESSAGES.get(code, "Device-specific error")
            if detail:
                text = f"{text};{detail}"
            if len(self._errors) >= _ERROR_QUEUE_LENGTH:
                self._errors[-1] = (-350, ERROR_MESSAGES[-350])
                return
            self._errors.append((code, text))

    @property
    def error_queue(self) -> list[tuple[int, str]]:
        with self.lock:
            return list(self._errors)

    # -- hooks for the USBTMC layer ---------------------------------------------------
    def query_interrupted(self) -> None:
        """A new message arrived before the previous response was read (IEEE 488.2)."""
        self.push_error(-410)

    def query_unterminated(self) -> None:
        """The host asked for a response although no query was sent (IEEE 488.2)."""
        self.push_error(-420)

    def status_byte(self) -> int:
        """IEEE 488.2 status byte: bit 2 = error/event queue not empty."""
        with self.lock:
            return 0x04 if self._errors else 0x00

    # -- FirmwareEmulator -------------------------------------------------------------
    def _handle_input(self, buf: bytearray) -> list[bytes]:
        """``buf`` holds one complete USBTMC message (possibly several lines)."""
        text = bytes(buf).decode("ascii", errors="replace")
        buf.clear()
        replies: list[str] = []
        for line in text.replace("\r", "\n").split("\n"):
            for unit in line.split(";"):
                unit = unit.strip()
                if unit:
                    reply = self._execute(unit)
                    if reply is not None:
                        replies.append(reply)
        if not replies:
            return []
        self._last_reply = (";".join(replies) + "\n").encode("ascii")
        return [self._last_reply]

    def unsolicited_frame(self) -> bytes:
        # USBTMC has no unsolicited bulk-IN data; the nearest thing is a stale response
        # left in the output queue, which is what an UNSOLICITED fault delivers.
        return self._last_reply or b"0\n"

    def enter_error_state(self, code: str | None = None) -> None:
        number = -300
        if code is not None:
            try:
                number = int(code)
            except ValueError:
                number = -300
        self.push_error(number, "" if code is None else f"injected {code}")

    # -- execution --------------------------------------------------------------------
    def _execute(self, unit: str) -> str | None:
        self.commands.append(unit)
        header, _, rest = unit.partition(" ")
        header = header.strip()
        args = [a.strip() for a in rest.split(",")] if rest.strip() else []
        query = header.endswith("?")
        if query:
            header = header[:-1]
        try:
            command = self._lookup(header, query)
            return command.handler(args)
        except ScpiError as err:
            self.push_error(err.code, err.detail)
            return None

    def _lookup(self, header: str, query: bool) -> _Command:
        upper = header.upper()
        if upper.startswith("*"):
            for cmd in self._table:
                if cmd.query == query and cmd.nodes[0][1] == upper:
                    return cmd
            raise ScpiError(-113, header)
        tokens = [t for t in upper.lstrip(":").split(":")]
        if not all(tokens):
            raise ScpiError(-100, header)
        for cmd in self._table:
            if cmd.query == query and _match(cmd.nodes, tokens):
                return cmd
        raise ScpiError(-113, header + ("?" if query else ""))

    def _build_table(self) -> list[_Command]:
        entries: list[tuple[str, bool, Callable[[list[str]], str | None]]] = [
            ("*IDN", True, self._idn),
            ("*RST", False, self._rst),
            ("*CLS", False, self._cls),
            ("*OPC", True, self._no_args(lambda: "1")),
            ("SYSTem:ERRor[:NEXT]", True, self._no_args(self._next_error)),
            ("SYSTem:SENSor:IDN", True, self._no_args(self.sensor_idn)),
            ("[SENSe]:CORRection:WAVelength", False, self._set_wavelength),
            ("[SENSe]:CORRection:WAVelength", True, self._get_wavelength),
            ("[SENSe]:POWer[:DC]:RANGe:AUTO", False, self._set_auto_range),
            ("[SENSe]:POWer[:DC]:RANGe:AUTO", True,
             self._no_args(lambda: "1" if self.auto_range else "0")),
            ("[SENSe]:POWer[:DC]:RANGe[:UPPer]", False, self._set_range),
            ("[SENSe]:POWer[:DC]:RANGe[:UPPer]", True, self._no_args(self._get_range)),
            ("[SENSe]:AVERage[:COUNt]", False, self._set_average),
            ("[SENSe]:AVERage[:COUNt]", True, self._no_args(lambda: str(self.average_count))),
            ("[SENSe]:CORRection:COLLect:ZERO[:INITiate]", False, self._no_args(self._zero)),
            ("[SENSe]:CORRection:COLLect:ZERO:ABORt", False, self._no_args(self._zero_abort)),
            ("[SENSe]:CORRection:COLLect:ZERO:STATe", True,
             self._no_args(lambda: "1" if self._zero_running() else "0")),
            ("[SENSe]:CORRection:COLLect:ZERO:MAGNitude", True,
             self._no_args(self._zero_magnitude)),
            ("MEASure[:SCALar]:POWer", True, self._no_args(self._meas_power)),
            ("MEASure[:SCALar]:CURRent", True, self._no_args(self._meas_current)),
            ("READ", True, self._no_args(self._read)),
            ("CONFigure[:SCALar]:POWer", False, self._no_args(lambda: None)),
            ("CONFigure", True, self._no_args(lambda: "POW")),
            ("INITiate[:IMMediate]", False, self._no_args(self._initiate)),
            ("FETCh", True, self._no_args(self._fetch)),
        ]
        return [_Command(_parse_pattern(p), q, h) for p, q, h in entries]

    @staticmethod
    def _no_args(fn: Callable[[], str | None]) -> Callable[[list[str]], str | None]:
        def handler(args: list[str]) -> str | None:
            if args:
                raise ScpiError(-108, ",".join(args))
            return fn()
        return handler

    @staticmethod
    def _one_arg(args: list[str]) -> str:
        if not args:
            raise ScpiError(-109)
        if len(args) > 1:
            raise ScpiError(-108, ",".join(args[1:]))
        return args[0]

    def _busy_check(self) -> None:
        if self._zero_running():
            raise ScpiError(-221, "zero adjustment in progress")

    # -- handlers ---------------------------------------------------------------------
    def _idn(self, args: list[str]) -> str:
        if args:
            raise ScpiError(-108)
        return f"Thorlabs,PM100USB,{self.serial},{self.firmware_version}"

    def sensor_idn(self) -> str:
        return self.sensor.idn()

    def _rst(self, args: list[str]) -> None:
        if args:
            raise ScpiError(-108)
        self._reset_settings()

    def _cls(self, args: list[str]) -> None:
        if args:
            raise ScpiError(-108)
        self._errors.clear()

    def _next_error(self) -> str:
        code, text = self._errors.popleft() if self._errors else (0, ERROR_MESSAGES[0])
        return f"{code:+d},\"{text}\""

    def _number_or_keyword(self, arg: str, lo: float, hi: float, default: float) -> float:
        keyword = arg.upper()
        if keyword in ("MIN", "MINIMUM"):
            return lo
        if keyword in ("MAX", "MAXIMUM"):
            return hi
        if keyword in ("DEF", "DEFAULT"):
            return default
        value = parse_scpi_number(arg)
        if not lo <= value <= hi:
            raise ScpiError(-222, f"{value:g} outside [{lo:g}, {hi:g}]")
        return value

    def _set_wavelength(self, args: list[str]) -> None:
        s = self.sensor
        self._busy_check()
        self.wavelength_nm = self._number_or_keyword(
            self._one_arg(args), s.wavelength_min_nm, s.wavelength_max_nm,
            s.default_wavelength_nm,
        )

    def _get_wavelength(self, args: list[str]) -> str:
        if len(args) > 1:
            raise ScpiError(-108)
        value = self.wavelength_nm
        if args:
            keyword = args[0].upper()
            if keyword in ("MIN", "MINIMUM"):
                value = self.sensor.wavelength_min_nm
            elif keyword in ("MAX", "MAXIMUM"):
                value = self.sensor.wavelength_max_nm
            else:
                raise ScpiError(-224 if keyword else -109, args[0])
        return f"{value:.6E}"

    def _set_auto_range(self, args: list[str]) -> None:
        word = self._one_arg(args).upper()
        if word in ("1", "ON"):
            self.auto_range = True
        elif word in ("0", "OFF"):
            self.auto_range = False
        else:
            raise ScpiError(-104, word)

    def _set_range(self, args: list[str]) -> None:
        self.range_w = self._number_or_keyword(
            self._one_arg(args), 1e-9, self.sensor.max_power_w, self.sensor.max_power_w)
        self.auto_range = False

    def _get_range(self) -> str:
        if self.auto_range:
            # Auto-ranging picks the smallest decade that holds the signal.
            p = max(abs(self.true_power_w()), 1e-9)
            decade = 10.0 ** math.ceil(math.log10(p))
            return f"{min(decade, self.sensor.max_power_w):.6E}"
        return f"{self.range_w:.6E}"

    def _set_average(self, args: list[str]) -> None:
        value = self._number_or_keyword(self._one_arg(args), 1, 10000, 1)
        if value != int(value):
            raise ScpiError(-222, f"count must be an integer, got {value:g}")
        self.average_count = int(value)

    def _zero(self) -> None:
        self._busy_check()
        # The zero is whatever the head sees now: correct only with the light blocked.
        self._zero_pending_a = self._sample_current_a(self.zero_samples)
        self._zero_started = self.clock.now()

    def _zero_abort(self) -> None:
        self._zero_started = None

    def _zero_magnitude(self) -> str:
        return f"{self.zero_current_a / self.responsivity_a_per_w(self.wavelength_nm):.6E}"

    def _meas_power(self) -> str:
        self._busy_check()
        return f"{self._measure_power_w():.6E}"

    def _meas_current(self) -> str:
        self._busy_check()
        return f"{self._sample_current_a(self.average_count) - self.zero_current_a:.6E}"

    def _initiate(self) -> None:
        self._busy_check()
        self._fetched = self._measure_power_w()

    def _fetch(self) -> str:
        if self._fetched is None:
            raise ScpiError(-230, "no measurement initiated")
        return f"{self._fetched:.6E}"

    def _read(self) -> str:
        self._initiate()
        return self._fetch()
