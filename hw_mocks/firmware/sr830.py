"""Firmware emulator of a Stanford Research SR830 DSP lock-in amplifier on RS-232.

Written from the manual (Stanford Research Systems, *Model SR830 DSP Lock-In Amplifier*,
Revision 2.5, 10/2011), independently of ``drivers/`` (it imports nothing from there, so a
misreading shared by the driver and the emulator cannot pass unnoticed).

The wire (manual ch. 5)
-----------------------
Commands are four-character mnemonics (``*`` + three letters for common commands), ``?``
for queries, comma-separated parameters; case and embedded spaces do not matter; a line
ends in CR or LF and may hold several commands separated by ``;`` (p. 5-1). Each query
answers one line ending in CR (p. 5-2) — sent only if the output interface is RS-232
(``OUTX 0``); with ``OUTX 1`` (GPIB) the answers go to the other connector and nothing
comes back on this line (p. 5-19). An unknown command sets CMD (bit 5) in the standard
event status byte, a parameter out of range or not allowed now sets EXE (bit 4); a failed
query answers nothing. ``AGAN`` keeps the interpreter busy (IFC clear); lines received
meanwhile wait in the input queue and run afterwards (p. 5-2), so an RS-232 ``*STB?``
asked during an auto gain is answered when it is over.

The whole remote command set of the manual's command list (pp. 5-4 to 5-23) is
interpreted; a mnemonic not in it sets CMD and answers nothing, as the instrument does.

* Reference and phase: ``PHAS FMOD FREQ RSLP HARM SLVL``. ``HARM i``: 1 ≤ i ≤ 19999 with
  i·f ≤ 102 kHz (both ``HARM`` and ``FREQ`` refuse what breaks it, EXE); the emulator
  detects the input component at i × the reference. ``SLVL`` 4 mV…5 V in 2 mV steps.
* Input and filter: ``ISRC IGND ICPL ILIN``. Gain and time constant: ``SENS RMOD OFLT
  OFSL SYNC`` — ``SENS`` 0…26 = 2 nV … 1 V rms in 1-2-5 steps, ``OFLT`` 0…19 = 10 µs …
  30 ks in 1-3 steps (> 30 s refused above a 200 Hz detection frequency; a frequency or
  harmonic change that crosses 200 Hz latches RANGE, and one that leaves τ > 30 s above
  it cuts τ to 30 s and latches TC), ``OFSL`` 0…3 = 6…24 dB/oct (p. 5-6).
* Display and output: ``DDEF`` (CH1: X, R, X noise, Aux In 1, 2; CH2: Y, θ, Y noise, Aux
  In 3, 4; ratio none or by an Aux In in volts), ``FPOP``, ``OEXP`` (offset −105…105 %,
  expand ×1/×10/×100 as index 0…2), ``AOFF``. Aux I/O: ``OAUX?`` (the rear inputs,
  :attr:`Sr830Emulator.aux_inputs_v`, read through the 16-bit A/D: clipped at ±10.5 V and
  rounded to 21 V / 2¹⁶, :meth:`Sr830Emulator.aux_input_reading`), ``AUXV`` (±10.5 V,
  1 mV).
* Setup: ``OUTX OVRM KCLK ALRM SSET RSET`` (nine setups; recalling an empty one is
  refused). Auto functions: ``AGAN ARSV APHS AOFF``.
* Data storage (:mod:`hw_mocks.firmware.sr830_storage`, on the emulator clock): ``SRAT
  SEND TRIG TSTR STRT PAUS REST STRD``. Data transfer: ``OUTP? OUTR? SNAP? OAUX? SPTS?
  TRCA? TRCB? TRCL? FAST``. ``TRCA?`` ends every point with a comma; ``TRCB?`` sends IEEE
  single floats (little-endian) and ``TRCL?`` 16-bit mantissa + 16-bit exponent pairs,
  both without a terminator.
* Interface and status: ``*RST *IDN? LOCL OVRM *CLS *ESE *ESR? *SRE *STB? *PSC ERRE
  ERRS? LIAE LIAS?`` (status queries take the optional bit number). The serial poll
  byte's SCN bit is clear while a scan stores points; IFC is clear only while ``AGAN``
  runs (then nothing is answered); ``*PSC 1`` clears the enable registers at power-on.

Not emulated (accepted and kept, without effect on the measurement): the dynamic reserve
(``RMOD``, ``ARSV`` changes nothing), the synchronous filter, line notches, input
grounding and the current inputs' gain (``ISRC 2/3`` read the same input in the units of
the selected input), the expand's effect (only the rear analog outputs would show it),
front-panel outputs, key click and alarm, local/remote lockout. ``FAST`` streaming goes
to the GPIB connector on a real unit, so on this RS-232 line it sends nothing. The QRY
(output queue overflow), URQ (front panel) and MAV bits are never set, and FILTR
overloads are not modelled.

The measurement model (documented emulator choices, not calibrations)
-------------------------------------------------------------------
* The input is an :class:`InputSignal` supplied by whoever binds the emulator (a test, or
  :mod:`hw_mocks.sim.photodiode` for the virtual bench): the rms amplitude and phase of the
  Fourier component at the modulation frequency, and a DC part. The lock-in reports rms
  values of the component at the reference frequency (p. 3-3: a 2 V pk-pk square wave
  reads 1.273/√2 V); DC does not reach X and Y.
* Reference: internal oscillator (``FREQ``, 1 kHz at reset) or REF IN (``FMOD 0``), where
  :attr:`Sr830Emulator.reference_input_hz` is what is connected there (a chopper's
  reference output; ``None``: nothing, the reference is unlocked and UNLK latches). A
  signal contributes only if it is modulated at the detection frequency (``frequency_hz``
  ``None`` means "whatever the lock-in references", like the SR830's own sine output
  looped back).
* Output filter: ``n`` = slope/6 cascaded single-pole stages of time constant τ on the
  emulator clock, updated exactly for an input held constant between updates. The input
  is sampled whenever a query is executed and held over the interval since the previous
  update (a change is taken to have happened at the start of the interval).
* Noise: seeded white Gaussian noise of density ``input_noise_v_per_rthz`` (V/√Hz rms)
  drives both filter chains, scaled so that the output's standard deviation is
  density·√ENBW with ENBW = 1/(4τ), 1/(8τ), 3/(32τ), 5/(64τ) for 6…24 dB/oct (p. 3-25).
  Only the last 50 τ are simulated (older noise has decayed below 1e-15).
* Overloads (latched in ``LIAS?``): OUTPT when |X|, |Y| or R exceeds the full scale; the
  reading is then clipped at ±109 % of full scale (the output voltage limit of 10.9 V for
  10 V full scale, p. 2-10). INPUT when the input's peak (√2·rms, plus DC with DC coupling
  ``ICPL 1``) exceeds :data:`INPUT_LIMIT_V` — a single input range, not the SR830's
  reserve-dependent one. FILTR is not modelled.
* ``AGAN`` picks the smallest full scale with R ≤ 0.8 × full scale from the noiseless
  output, and keeps the interpreter busy for ``agan_time_constants`` × τ (at least 50 ms);
  above τ = 1 s it does nothing, as the manual says (p. 5-11).
* Power-up and ``*RST`` settings (1 V, 100 ms, 12 dB/oct, internal 1 kHz, phase 0, AC
  coupling, harmonic 1, sine trigger, 1 V sine out, input A floating, no notch, normal
  reserve, CH1 X and CH2 Y with no ratio, no offsets, storage at 1 Hz in loop mode, an
  empty buffer) follow the manual's standard settings (p. 4-4) as far as they could be
  checked (the reserve and the storage defaults could not be, and are emulator
  choices); the output interface is a retained setting and powers up as
  ``output_interface`` (default GPIB, the quirk that makes a program that skips ``OUTX 0``
  hear nothing).
* Fault injection: :meth:`Sr830Emulator.enter_error_state` latches an ``ERRS?`` bit (code
  ``"0"``…``"7"``, default ``"6"`` DSP error) or, with ``"power_cycle"``, restarts the
  instrument (standard settings, PON latched). The SR830 sends nothing unsolicited; the
  "unsolicited" frame is a stray carriage return (line noise on the cable).
"""

from __future__ import annotations

import copy
import math
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hw_mocks.clock import Clock, HostPacedClock
from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.firmware.sr830_storage import (
    BUFFER_POINTS,
    STRD_DELAY_S,
    TRIGGERED_RATE,
    DataStorage,
)

__all__ = ["INPUT_LIMIT_V", "InputSignal", "Sr830Emulator"]

SENSITIVITIES_V = tuple(float(f"{m}e{e}") for e in range(-9, 0) for m in (2, 5, 10))
TIME_CONSTANTS_S = tuple(float(f"{m}e{e}") for e in range(-5, 5) for m in (1, 3))
POLES_BY_OFSL = (1, 2, 3, 4)
#: Equivalent noise bandwidth × τ by number of poles (manual p. 3-25).
ENBW_TIMES_TAU = {1: 1 / 4, 2: 1 / 8, 3: 3 / 32, 4: 5 / 64}
#: Peak input that overloads the input stage (emulator choice: 1 V rms sine).
INPUT_LIMIT_V = math.sqrt(2.0)
#: Output clipping, in full scales (10.9 V output limit for 10 V full scale).
OUTPUT_CLIP = 1.09
_MAX_LINE = 256
_MEMORY_TAUS = 50.0
_SUBSTEPS_PER_TAU = 16

#: Aux In range and A/D step (manual, specifications: four inputs, 16-bit, ±10.5 V,
#: "1/3 mV resolution": 21 V over 2¹⁶ codes).
AUX_IN_LIMIT_V = 10.5
AUX_IN_STEP_V = 2.0 * AUX_IN_LIMIT_V / 2**16

#: Highest detection frequency (``HARM i`` × ``FREQ``), Hz.
MAX_DETECTION_HZ = 102000.0
MAX_HARMONIC = 19999
#: Time constants above 30 s need a detection frequency at or below 200 Hz.
_LONG_TC_INDEX = TIME_CONSTANTS_S.index(30.0)
_RANGE_HZ = 200.0
_SETUP_SLOTS = 9

_CMD_RE = re.compile(r"(\*[A-Z]{3}|[A-Z]{4})(\?)?(.*)", re.DOTALL)
_NUMBER_RE = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:E[+-]?\d+)?")

# Status bits.
_ESR_INP, _ESR_EXE, _ESR_CMD, _ESR_PON = 0x01, 0x10, 0x20, 0x80
_LIA_INPUT, _LIA_OUTPUT, _LIA_UNLOCK = 0x01, 0x04, 0x08
_LIA_RANGE, _LIA_TC, _LIA_TRIG = 0x10, 0x20, 0x40
#: Plain index settings: mnemonic → (attribute, highest index); query and set alike.
_INDEX_SETTINGS = {
    "OUTX": ("outx", 1),
    "FMOD": ("fmod", 1),
    "ICPL": ("icpl", 1),
    "SENS": ("sens", len(SENSITIVITIES_V) - 1),
    "RSLP": ("rslp", 2),
    "ISRC": ("isrc", 3),
    "IGND": ("ignd", 1),
    "ILIN": ("ilin", 3),
    "RMOD": ("rmod", 2),
    "SYNC": ("sync", 1),
    "OVRM": ("ovrm", 1),
    "LOCL": ("locl", 2),
    "KCLK": ("kclk", 1),
    "ALRM": ("alrm", 1),
    "*PSC": ("psc", 1),
    "FAST": ("fast", 2),
}
#: Settings saved by ``SSET`` and restored by ``RSET`` / ``*RST`` (not the interface).
_SETUP_FIELDS = ("fmod", "freq", "phase", "harm", "rslp", "slvl", "isrc", "ignd", "icpl",
                 "ilin", "sens", "rmod", "oflt", "ofsl", "sync", "ddef", "fpop", "oexp",
                 "auxv", "kclk", "alrm")


@dataclass(frozen=True)
class InputSignal:
    """What reaches the lock-in's input.

    ``ac_rms_v`` and ``phase_deg``: rms amplitude and phase (relative to the reference) of
    the component at ``frequency_hz`` (``None``: at whatever frequency the lock-in
    references). ``dc_v``: the unmodulated part, rejected by the demodulator.
    ``noise_v_per_rthz``: white noise density at the input (``None``: the emulator's).
    """

    ac_rms_v: float = 0.0
    phase_deg: float = 0.0
    frequency_hz: float | None = None
    dc_v: float = 0.0
    noise_v_per_rthz: float | None = None
    #: Further components ``(n, rms V, phase deg)`` at n × the fundamental (the
    #: fundamental being ``frequency_hz``, or the reference frequency when that is
    #: ``None``): what ``HARM n`` detects, e.g. the 2f term of a modulated polarimeter.
    harmonics: tuple[tuple[int, float, float], ...] = ()


class _BadCommand(Exception):
    """Raised inside the interpreter; ``bit`` goes to the standard event status byte."""

    def __init__(self, bit: int) -> None:
        super().__init__(bit)
        self.bit = bit


def _cascade_matrix(x: float, poles: int) -> np.ndarray:
    """Exact state transition of ``poles`` identical single-pole stages over ``x`` = dt/τ.

    For a constant input u, the deviations e = s − u obey e' = M e with
    M[i, j] = e^{−x} x^{i−j}/(i−j)! for j ≤ i (stage i is fed by stage i−1).
    """
    m = np.zeros((poles, poles))
    decay = math.exp(-x)
    for i in range(poles):
        for k in range(i + 1):
            m[i, i - k] = decay * x**k / math.factorial(k)
    return m


_NOISE_GAIN: dict[int, tuple[np.ndarray, float]] = {}


def _noise_model(poles: int) -> tuple[np.ndarray, float]:
    """Sub-step transition matrix and the stationary output variance per unit input
    variance for noise held constant over τ/16 sub-steps (solved once per pole count)."""
    if poles not in _NOISE_GAIN:
        # imported here, once per pole count: scipy.linalg costs a noticeable part of a
        # second to import, which an emulated bench whose lock-in never reads noise saves
        from scipy.linalg import solve_discrete_lyapunov

        a = _cascade_matrix(1.0 / _SUBSTEPS_PER_TAU, poles)
        b = (np.eye(poles) - a) @ np.ones(poles)
        p = solve_discrete_lyapunov(a, np.outer(b, b))
        _NOISE_GAIN[poles] = (a, float(p[-1, -1]))
    return _NOISE_GAIN[poles]


def _non_normalised(value: float) -> bytes:
    """One ``TRCL?`` point: mantissa in [−32767, 32767] and the exponent + 124."""
    if value == 0.0 or not math.isfinite(value):
        return struct.pack("<hh", 0, 124)
    mantissa, exponent = math.frexp(value)  # value = mantissa · 2**exponent, |m| in [0.5, 1)
    m = round(mantissa * 2**15)
    if abs(m) > 32767:
        m //= 2
        exponent += 1
    return struct.pack("<hh", m, exponent - 15 + 124)


def _fmt(value: float) -> str:
    """A reply number the way the manual's examples look (``-1.01026``,
    ``-1.234567e-009``): six significant digits, three-digit exponents when small/large."""
    if value == 0.0:
        return "0"
    if 1e-3 <= abs(value) < 1e6:
        return f"{value:.6g}"
    mantissa, exponent = f"{value:.6e}".split("e")
    power = int(exponent)
    return f"{mantissa}e{'-' if power < 0 else '+'}{abs(power):03d}"


class Sr830Emulator(FirmwareEmulator):
    """An SR830 with its input fed by :attr:`input_signal` (or :meth:`set_input`).

    Parameters
    ----------
    name
        Instance name (URL host part).
    baudrate
        The rate its Setup menu is set to (a link opened at another rate sees nothing).
    reference_input_hz
        Frequency of what drives REF IN (a chopper); ``None``: nothing connected.
    input_noise_v_per_rthz
        White noise density at the input, V/√Hz rms.
    output_interface
        ``0`` RS-232 or ``1`` GPIB at power-up (retained setting; see the module).
    agan_time_constants
        How long ``AGAN`` keeps the interpreter busy, in time constants.
    serial_number, model, firmware
        What ``*IDN?`` reports.
    """

    scheme = "simsr830"
    baudrate = 9600

    def __init__(
        self,
        name: str,
        *,
        baudrate: int = 9600,
        reference_input_hz: float | None = None,
        input_noise_v_per_rthz: float = 10e-9,
        output_interface: int = 1,
        agan_time_constants: float = 10.0,
        serial_number: str = "00111",
        model: str = "SR830",
        firmware: str = "1.07",
        clock: Clock | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__(name, clock=clock, seed=seed)
        if output_interface not in (0, 1):
            raise ValueError("output_interface must be 0 (RS-232) or 1 (GPIB)")
        if input_noise_v_per_rthz < 0:
            raise ValueError("input_noise_v_per_rthz must be >= 0")
        self.baudrate = int(baudrate)
        self.reference_input_hz = reference_input_hz
        self.input_noise_v_per_rthz = float(input_noise_v_per_rthz)
        self.agan_time_constants = float(agan_time_constants)
        self.idn = f"Stanford_Research_Systems,{model},s/n{serial_number},ver{firmware}"
        self.outx = output_interface
        #: Callable giving the input now; ``None`` uses the constant set by :meth:`set_input`.
        self.input_signal: Callable[[], InputSignal] | None = None
        self.bound_world: str | None = None
        self._constant = InputSignal()
        self._rng = np.random.default_rng(seed)
        self._rx_lines: list[bytes] = []
        #: Voltages at the rear-panel Aux In 1…4 (``OAUX?``, ``SNAP?`` 5…8, ratios).
        self.aux_inputs_v = [0.0, 0.0, 0.0, 0.0]
        self.storage = DataStorage()
        self._setups: dict[int, dict[str, object]] = {}
        self.psc = 1
        self.locl = 0  # LOCL: 0 local, 1 remote, 2 local lockout
        self.ovrm = 0
        self.fast = 0
        self._busy_until = -math.inf
        #: Replies the SR830 sent to its GPIB connector instead (``OUTX 1``), for tests.
        self.replies_to_gpib = 0
        self.ese = self.sre = self.erre = self.liae = 0
        self.esr = _ESR_PON
        self.errs = 0
        self.lias = 0
        self.kclk = self.alrm = 1
        self._standard_settings()
        self._d = np.zeros((2, 4))  # noiseless stage outputs (X chain, Y chain)
        self._z = np.zeros((2, 4))  # noise part of the stage outputs
        self._t_last = self.clock.now()
        self._noise_carry = 0.0

    # backdoor -------------------------------------------------------------------
    def set_input(self, ac_rms_v: float = 0.0, *, phase_deg: float = 0.0,
                  frequency_hz: float | None = None, dc_v: float = 0.0,
                  noise_v_per_rthz: float | None = None) -> None:
        """Feed a constant signal (and forget a bound :attr:`input_signal`)."""
        with self.lock:
            self._advance()  # the old input held until now
            self.input_signal = None
            self._constant = InputSignal(ac_rms_v, phase_deg, frequency_hz, dc_v,
                                         noise_v_per_rthz)

    @property
    def time_constant_s(self) -> float:
        return TIME_CONSTANTS_S[self.oflt]

    @property
    def poles(self) -> int:
        return POLES_BY_OFSL[self.ofsl]

    @property
    def full_scale_v(self) -> float:
        return SENSITIVITIES_V[self.sens]

    def detection_frequency_hz(self) -> float:
        """The reference frequency (0 when the external reference is missing); ``FREQ?``.
        The lock-in detects at :attr:`harm` times this."""
        if self.fmod == 1:
            return self.freq
        return float(self.reference_input_hz or 0.0)

    def locked(self) -> bool:
        return self.fmod == 1 or bool(self.reference_input_hz)

    def target_xy(self, signal: InputSignal | None = None) -> tuple[float, float]:
        """The noiseless X, Y the filter converges to for the present input."""
        signal = self._signal() if signal is None else signal
        if not self.locked():
            return 0.0, 0.0
        f_ref = self.detection_frequency_hz()
        f_det = self.harm * f_ref
        fundamental = f_ref if signal.frequency_hz is None else signal.frequency_hz
        x = y = 0.0
        for n, rms, phase in ((1, signal.ac_rms_v, signal.phase_deg), *signal.harmonics):
            if abs(n * fundamental - f_det) > 1e-6 * f_det:
                continue  # modulated at another frequency: averaged away
            phi = math.radians(phase - self.phase)
            x += rms * math.cos(phi)
            y += rms * math.sin(phi)
        return x, y

    def outputs(self) -> tuple[float, float]:
        """X, Y now (noise included, not clipped)."""
        with self.lock:
            self._advance()
            n = self.poles
            return (float(self._d[0, n - 1] + self._z[0, n - 1]),
                    float(self._d[1, n - 1] + self._z[1, n - 1]))

    def is_busy(self) -> bool:
        with self.lock:
            return self.clock.now() < self._busy_until

    # FirmwareEmulator -------------------------------------------------------------
    def _handle_input(self, buf: bytearray) -> list[bytes]:
        while True:
            ends = [i for i in (buf.find(b"\r"), buf.find(b"\n")) if i >= 0]
            if not ends:
                if len(buf) > _MAX_LINE:  # the input queue overflows: the line is lost
                    buf.clear()
                    self.esr |= _ESR_INP
                break
            end = min(ends)
            line = bytes(buf[:end])
            del buf[: end + 1]
            if line.strip():
                self._rx_lines.append(line)
        return self._run_queue()

    def poll(self) -> list[bytes]:
        with self.lock:
            clock = self.clock
            if self._rx_lines and isinstance(clock, HostPacedClock):
                # The host waits for an answer held back by AGAN: on a host-paced clock
                # its waiting is what lets the auto gain finish.
                clock.run_to(self._busy_until)
            return self._run_queue()

    def unsolicited_frame(self) -> bytes:
        """The SR830 sends nothing by itself: a stray CR (line noise) stands in."""
        return b"\r"

    def enter_error_state(self, code: str | None = None) -> None:
        """Latch an ``ERRS?`` bit (``"0"``…``"7"``, default ``"6"``, DSP error) or, with
        ``"power_cycle"``, restart: standard settings, PON latched, filters emptied."""
        with self.lock:
            if code == "power_cycle":
                self._standard_settings()
                if self.psc:  # *PSC 1: the enable registers are cleared at power-on
                    self.ese = self.sre = self.erre = self.liae = 0
                self._d[:] = 0.0
                self._z[:] = 0.0
                self._t_last = self.clock.now()
                self._busy_until = -math.inf
                self._rx_lines.clear()
                self.esr |= _ESR_PON
                return
            try:
                bit = int(code) if code is not None else 6
            except ValueError:
                raise ValueError(f"SR830 error state code must be an ERRS bit 0-7 or "
                                 f"'power_cycle', got {code!r}") from None
            if not 0 <= bit <= 7:
                raise ValueError(f"ERRS bit must be 0-7, got {bit}")
            self.errs |= 1 << bit

    # interpreter ------------------------------------------------------------------
    def _standard_settings(self) -> None:
        """``*RST`` and power-up: the manual's standard settings (p. 4-4) as far as they
        were checked; the communication settings (OUTX, OVRM, baud rate) are kept."""
        self.fmod = 1
        self.freq = 1000.0
        self.phase = 0.0
        self.harm = 1
        self.rslp = 0  # sine
        self.slvl = 1.0
        self.isrc = 0  # A
        self.ignd = 0  # float
        self.icpl = 0
        self.ilin = 0  # no line notch
        self.sens = 26
        self.rmod = 1  # normal reserve
        self.oflt = 8
        self.ofsl = 1
        self.sync = 0
        self.ddef = [[0, 0], [0, 0]]  # CH1 X, CH2 Y, no ratio
        self.fpop = [0, 0]  # front-panel outputs follow the displays
        self.oexp = [[0.0, 0], [0.0, 0], [0.0, 0]]  # X, Y, R: offset %, expand index
        self.auxv = [0.0, 0.0, 0.0, 0.0]
        self.storage = DataStorage()

    def _run_queue(self) -> list[bytes]:
        replies: list[bytes] = []
        while self._rx_lines and self.clock.now() >= self._busy_until:
            line = self._rx_lines.pop(0)
            for text in self._execute_line(line):
                if self.outx == 0:
                    # Binary traces (TRCB?, TRCL?) go out as they are, without terminator.
                    replies.append(text if isinstance(text, bytes)
                                   else text.encode("ascii") + b"\r")
                else:
                    self.replies_to_gpib += 1
        return replies

    def _execute_line(self, line: bytes) -> list[str | bytes]:
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            self.esr |= _ESR_CMD
            return []
        answers: list[str | bytes] = []
        parts = text.split(";")
        for position, part in enumerate(parts):
            command = "".join(part.split()).upper()
            if not command:
                continue
            if self.clock.now() < self._busy_until:
                # AGAN started earlier on this line: the rest waits its turn.
                self._rx_lines.insert(0, ";".join(parts[position:]).encode("ascii"))
                break
            try:
                answer = self._execute(command)
            except _BadCommand as bad:
                self.esr |= bad.bit
                continue
            if answer is not None:
                answers.append(answer)
        return answers

    def _execute(self, command: str) -> str | bytes | None:
        match = _CMD_RE.fullmatch(command)
        if match is None:
            raise _BadCommand(_ESR_CMD)
        mnemonic, query, rest = match.group(1), bool(match.group(2)), match.group(3)
        args = rest.split(",") if rest else []
        handler = getattr(self, "_cmd_" + mnemonic.replace("*", "star_"), None)
        if handler is None and mnemonic in _INDEX_SETTINGS:
            attribute, high = _INDEX_SETTINGS[mnemonic]
            self._advance()
            return self._setting(query, args, attribute, high)
        if handler is None:
            raise _BadCommand(_ESR_CMD)
        self._advance()
        return handler(query, args)

    # argument helpers
    @staticmethod
    def _number(text: str) -> float:
        if not _NUMBER_RE.fullmatch(text):
            raise _BadCommand(_ESR_CMD)
        value = float(text)
        if not math.isfinite(value):  # "1e999": a number the instrument cannot hold
            raise _BadCommand(_ESR_EXE)
        return value

    def _index(self, args: list[str], high: int, position: int = 0) -> int:
        if len(args) <= position:
            raise _BadCommand(_ESR_CMD)
        value = self._number(args[position])
        if value != int(value) or not 0 <= value <= high:
            raise _BadCommand(_ESR_EXE)
        return int(value)

    def _setting(self, query: bool, args: list[str], attribute: str, high: int) -> str | None:
        if query:
            if args:
                raise _BadCommand(_ESR_CMD)
            return str(getattr(self, attribute))
        if len(args) != 1:
            raise _BadCommand(_ESR_CMD)
        setattr(self, attribute, self._index(args, high))
        return None

    def _register_read(self, query: bool, args: list[str], attribute: str, *,
                       clears: bool) -> str:
        if not query or len(args) > 1:
            raise _BadCommand(_ESR_CMD)
        value = getattr(self, attribute)
        if args:
            bit = self._index(args, 7)
            if clears:
                setattr(self, attribute, value & ~(1 << bit))
            return str((value >> bit) & 1)
        if clears:
            setattr(self, attribute, 0)
        return str(value)

    def _enable(self, query: bool, args: list[str], attribute: str) -> str | None:
        if query:
            if len(args) > 1:
                raise _BadCommand(_ESR_CMD)
            value = getattr(self, attribute)
            return str((value >> self._index(args, 7)) & 1) if args else str(value)
        if len(args) == 1:
            setattr(self, attribute, self._index(args, 255))
        elif len(args) == 2:
            bit, on = self._index(args, 7), self._index(args, 1, 1)
            value = getattr(self, attribute)
            setattr(self, attribute, value | (1 << bit) if on else value & ~(1 << bit))
        else:
            raise _BadCommand(_ESR_CMD)
        return None

    # common and status commands
    def _cmd_star_IDN(self, query: bool, args: list[str]) -> str:
        if not query or args:
            raise _BadCommand(_ESR_CMD)
        return self.idn

    def _cmd_star_RST(self, query: bool, args: list[str]) -> None:
        if query or args:
            raise _BadCommand(_ESR_CMD)
        self._standard_settings()  # also resets the data buffer

    def _cmd_star_CLS(self, query: bool, args: list[str]) -> None:
        if query or args:
            raise _BadCommand(_ESR_CMD)
        self.esr = self.errs = self.lias = 0

    def _cmd_star_ESR(self, query: bool, args: list[str]) -> str:
        return self._register_read(query, args, "esr", clears=True)

    def _cmd_ERRS(self, query: bool, args: list[str]) -> str:
        return self._register_read(query, args, "errs", clears=True)

    def _cmd_LIAS(self, query: bool, args: list[str]) -> str:
        return self._register_read(query, args, "lias", clears=True)

    def _cmd_star_STB(self, query: bool, args: list[str]) -> str:
        if not query or len(args) > 1:
            raise _BadCommand(_ESR_CMD)
        # SCN (no scan in progress) and IFC (answering means idle).
        byte = 0x02 | (0 if self.storage.scanning else 0x01)
        if self.errs & self.erre:
            byte |= 0x04
        if self.lias & self.liae:
            byte |= 0x08
        if self.esr & self.ese:
            byte |= 0x20
        if byte & self.sre & 0x3F:
            byte |= 0x40
        if args:
            return str((byte >> self._index(args, 7)) & 1)
        return str(byte)

    def _cmd_star_ESE(self, query: bool, args: list[str]) -> str | None:
        return self._enable(query, args, "ese")

    def _cmd_star_SRE(self, query: bool, args: list[str]) -> str | None:
        return self._enable(query, args, "sre")

    def _cmd_ERRE(self, query: bool, args: list[str]) -> str | None:
        return self._enable(query, args, "erre")

    def _cmd_LIAE(self, query: bool, args: list[str]) -> str | None:
        return self._enable(query, args, "liae")

    # reference
    def _real(self, query: bool, args: list[str], now: float, low: float,
              high: float) -> str | float:
        """A real-valued setting: its query's reply (text), or the value asked for (a
        float within ``low``…``high``; EXE otherwise)."""
        if query:
            if args:
                raise _BadCommand(_ESR_CMD)
            return _fmt(now)
        if len(args) != 1:
            raise _BadCommand(_ESR_CMD)
        value = self._number(args[0])
        if not low <= value <= high:
            raise _BadCommand(_ESR_EXE)
        return value

    def _cmd_FREQ(self, query: bool, args: list[str]) -> str | None:
        value = self._real(query, args, self.detection_frequency_hz(), 0.001,
                           MAX_DETECTION_HZ / self.harm)  # i·f ≤ 102 kHz
        if isinstance(value, str):
            return value
        if self.fmod != 1:
            raise _BadCommand(_ESR_EXE)  # set only with the internal reference
        before = self.harm * self.detection_frequency_hz()
        self.freq = float(f"{value:.5g}") if value >= 1.0 else round(value, 4)
        self._detection_changed(before)
        return None

    def _cmd_PHAS(self, query: bool, args: list[str]) -> str | None:
        value = self._real(query, args, self.phase, -360.0, 729.99)
        if isinstance(value, str):
            return value
        wrapped = (round(value, 2) + 180.0) % 360.0 - 180.0
        self.phase = 180.0 if wrapped == -180.0 else wrapped
        return None

    # input, gain and filter
    def _cmd_OFLT(self, query: bool, args: list[str]) -> str | None:
        if not query and len(args) == 1:
            index = self._index(args, len(TIME_CONSTANTS_S) - 1)
            if TIME_CONSTANTS_S[index] > 30.0 and self.detection_frequency_hz() > 200.0:
                raise _BadCommand(_ESR_EXE)  # > 30 s only below 200 Hz (p. 5-6)
        return self._setting(query, args, "oflt", len(TIME_CONSTANTS_S) - 1)

    def _cmd_OFSL(self, query: bool, args: list[str]) -> str | None:
        old = self.poles
        answer = self._setting(query, args, "ofsl", 3)
        new = self.poles
        if new > old:  # added stages start from the last stage's output
            self._d[:, old:new] = self._d[:, old - 1:old]
            self._z[:, old:new] = self._z[:, old - 1:old]
        return answer

    # data
    def aux_input_reading(self, channel: int) -> float:
        """Aux In ``channel`` (1…4) as the SR830's A/D converts it: the voltage at the
        rear input clipped to ±10.5 V and rounded to the 16-bit step (21 V / 2¹⁶ ≈
        0.32 mV). A steady input reads the same code every time; a mean of readings does
        not average the rounding away."""
        volts = max(-AUX_IN_LIMIT_V, min(AUX_IN_LIMIT_V, self.aux_inputs_v[channel - 1]))
        return round(volts / AUX_IN_STEP_V) * AUX_IN_STEP_V

    def _reading(self) -> dict[int, float]:
        """The ``SNAP?`` codes' values now: X, Y, R less their offsets (``OEXP``), θ from
        the unoffset X and Y, Aux In 1…4, the reference frequency, the two displays."""
        n = self.poles
        x = float(self._d[0, n - 1] + self._z[0, n - 1])
        y = float(self._d[1, n - 1] + self._z[1, n - 1])
        full_scale = self.full_scale_v
        clip = OUTPUT_CLIP * full_scale
        theta = math.degrees(math.atan2(y, x)) if (x or y) else 0.0
        offset = [percent / 100.0 * full_scale for percent, _ in self.oexp]
        values = {
            1: max(-clip, min(clip, x - offset[0])),
            2: max(-clip, min(clip, y - offset[1])),
            3: max(-clip, min(clip, math.hypot(x, y) - offset[2])),
            4: theta,
            5: self.aux_input_reading(1), 6: self.aux_input_reading(2),
            7: self.aux_input_reading(3), 8: self.aux_input_reading(4),
            9: self.detection_frequency_hz(),
        }
        values[10], values[11] = self._displays(values)
        return values

    def _displays(self, values: dict[int, float] | None = None) -> tuple[float, float]:
        """CH1 and CH2 as ``DDEF`` selects them: X, R, X noise, Aux In 1, 2 (CH1); Y, θ,
        Y noise, Aux In 3, 4 (CH2); divided by the ratio input in volts if one is set."""
        values = self._reading() if values is None else values
        signal = self._signal()
        noise = (self.input_noise_v_per_rthz if signal.noise_v_per_rthz is None
                 else signal.noise_v_per_rthz)
        clip = OUTPUT_CLIP * self.full_scale_v
        shown = []
        for channel, (quantity, ratio) in enumerate(self.ddef):
            first_aux = 5 + 2 * channel
            sources = (values[1 + channel], values[3 + channel], noise,
                       values[first_aux], values[first_aux + 1])
            value = sources[quantity]
            if ratio:
                divisor = values[first_aux + ratio - 1]
                value = value / divisor if abs(divisor) >= 1e-3 else math.copysign(clip, value)
            shown.append(value)
        return shown[0], shown[1]

    def _cmd_SNAP(self, query: bool, args: list[str]) -> str:
        if not query or not 2 <= len(args) <= 6:
            raise _BadCommand(_ESR_CMD)
        codes = [self._index(args, 11, i) for i in range(len(args))]
        if 0 in codes:
            raise _BadCommand(_ESR_EXE)
        values = self._reading()
        return ",".join(_fmt(values[c]) for c in codes)

    def _cmd_OUTP(self, query: bool, args: list[str]) -> str:
        if not query or len(args) != 1:
            raise _BadCommand(_ESR_CMD)
        code = self._index(args, 4)
        if code == 0:
            raise _BadCommand(_ESR_EXE)
        return _fmt(self._reading()[code])

    def _cmd_AGAN(self, query: bool, args: list[str]) -> None:
        if query or args:
            raise _BadCommand(_ESR_CMD)
        tau = self.time_constant_s
        if tau > 1.0:
            return  # "AGAN does nothing if the time constant is greater than 1 second"
        r = math.hypot(*self.target_xy())
        self.sens = next((i for i, fs in enumerate(SENSITIVITIES_V) if r <= 0.8 * fs),
                         len(SENSITIVITIES_V) - 1)
        self._busy_until = self.clock.now() + max(self.agan_time_constants * tau, 0.05)

    def _cmd_OUTR(self, query: bool, args: list[str]) -> str:
        if not query or len(args) != 1:
            raise _BadCommand(_ESR_CMD)
        channel = self._index(args, 2)
        if channel == 0:
            raise _BadCommand(_ESR_EXE)
        return _fmt(self._displays()[channel - 1])

    def _cmd_OAUX(self, query: bool, args: list[str]) -> str:
        if not query or len(args) != 1:
            raise _BadCommand(_ESR_CMD)
        return _fmt(self.aux_input_reading(self._channel_arg(args, 4)))

    def _cmd_AUXV(self, query: bool, args: list[str]) -> str | None:
        def parse(a: list[str]) -> float:
            volts = self._number(a[1])
            if not -10.5 <= volts <= 10.5:
                raise _BadCommand(_ESR_EXE)
            return round(volts, 3)  # 1 mV resolution
        return self._per_channel(query, args, self.auxv, 4, 2, show=_fmt, parse=parse)

    # harmonic and sine output
    def _cmd_HARM(self, query: bool, args: list[str]) -> str | None:
        if query:
            return self._setting(query, args, "harm", MAX_HARMONIC)
        before = self.harm * self.detection_frequency_hz()
        if len(args) != 1:
            raise _BadCommand(_ESR_CMD)
        harm = self._index(args, MAX_HARMONIC)
        if harm < 1 or harm * self.detection_frequency_hz() > MAX_DETECTION_HZ:
            raise _BadCommand(_ESR_EXE)
        self.harm = harm
        self._detection_changed(before)
        return None

    def _detection_changed(self, before_hz: float) -> None:
        """RANGE when the detection frequency crosses 200 Hz; above it a time constant
        over 30 s is cut to 30 s, latching TC (LIA status bits 4 and 5)."""
        now_hz = self.harm * self.detection_frequency_hz()
        if (before_hz > _RANGE_HZ) != (now_hz > _RANGE_HZ):
            self.lias |= _LIA_RANGE
        if now_hz > _RANGE_HZ and self.oflt > _LONG_TC_INDEX:
            self.oflt = _LONG_TC_INDEX
            self.lias |= _LIA_TC

    def _cmd_SLVL(self, query: bool, args: list[str]) -> str | None:
        volts = self._real(query, args, self.slvl, 0.004, 5.0)
        if isinstance(volts, str):
            return volts
        self.slvl = round(round(volts / 0.002) * 0.002, 3)  # 2 mV resolution
        return None

    # displays and outputs
    def _channel_arg(self, args: list[str], high: int) -> int:
        channel = self._index(args, high)
        if channel == 0:
            raise _BadCommand(_ESR_EXE)
        return channel

    def _per_channel(self, query: bool, args: list[str], values: list, channels: int,
                     set_count: int, parse, show) -> str | None:
        """``XXXX? i`` answers ``show(values[i − 1])``; ``XXXX i,…`` (``set_count``
        parameters) stores ``parse(args)`` there; i = 1…``channels``."""
        if query:
            if len(args) != 1:
                raise _BadCommand(_ESR_CMD)
            return show(values[self._channel_arg(args, channels) - 1])
        if len(args) != set_count:
            raise _BadCommand(_ESR_CMD)
        channel = self._channel_arg(args, channels)
        values[channel - 1] = parse(args)
        return None

    def _cmd_DDEF(self, query: bool, args: list[str]) -> str | None:
        return self._per_channel(
            query, args, self.ddef, 2, 3, show=lambda v: f"{v[0]},{v[1]}",
            parse=lambda a: [self._index(a, 4, 1), self._index(a, 2, 2)])

    def _cmd_FPOP(self, query: bool, args: list[str]) -> str | None:
        return self._per_channel(query, args, self.fpop, 2, 2, show=str,
                                 parse=lambda a: self._index(a, 1, 1))

    def _cmd_OEXP(self, query: bool, args: list[str]) -> str | None:
        def parse(a: list[str]) -> list:
            percent = self._number(a[1])
            if not -105.0 <= percent <= 105.0:
                raise _BadCommand(_ESR_EXE)
            return [round(percent, 2), self._index(a, 2, 2)]
        return self._per_channel(query, args, self.oexp, 3, 3,
                                 show=lambda v: f"{v[0]:.2f},{v[1]}", parse=parse)

    def _cmd_AOFF(self, query: bool, args: list[str]) -> None:
        if query or len(args) != 1:
            raise _BadCommand(_ESR_CMD)
        channel = self._channel_arg(args, 3)
        expand = self.oexp[channel - 1][1]
        self.oexp[channel - 1] = [0.0, expand]
        raw = self._reading()[channel]  # X, Y or R with no offset
        percent = max(-105.0, min(105.0, 100.0 * raw / self.full_scale_v))
        self.oexp[channel - 1] = [round(percent, 2), expand]

    def _cmd_APHS(self, query: bool, args: list[str]) -> None:
        if query or args:
            raise _BadCommand(_ESR_CMD)
        theta = self._reading()[4]
        wrapped = (round(self.phase + theta, 2) + 180.0) % 360.0 - 180.0
        self.phase = 180.0 if wrapped == -180.0 else wrapped

    def _cmd_ARSV(self, query: bool, args: list[str]) -> None:
        if query or args:
            raise _BadCommand(_ESR_CMD)
        # The dynamic reserve is not modelled: nothing to adjust.

    # setup
    def _cmd_SSET(self, query: bool, args: list[str]) -> None:
        if query or len(args) != 1:
            raise _BadCommand(_ESR_CMD)
        slot = self._channel_arg(args, _SETUP_SLOTS)
        self._setups[slot] = {name: copy.deepcopy(getattr(self, name))
                              for name in _SETUP_FIELDS}

    def _cmd_RSET(self, query: bool, args: list[str]) -> None:
        if query or len(args) != 1:
            raise _BadCommand(_ESR_CMD)
        slot = self._channel_arg(args, _SETUP_SLOTS)
        if slot not in self._setups:
            raise _BadCommand(_ESR_EXE)  # nothing saved there
        for name, value in self._setups[slot].items():
            setattr(self, name, copy.deepcopy(value))

    # data storage
    def _storage_setting(self, query: bool, args: list[str], name: str,
                         high: int) -> str | None:
        if query:
            if args:
                raise _BadCommand(_ESR_CMD)
            return str(getattr(self.storage, name))
        if len(args) != 1:
            raise _BadCommand(_ESR_CMD)
        value = self._index(args, high)
        if value != getattr(self.storage, name) and name != "tstr":
            self.storage.reset()
        setattr(self.storage, name, value)
        return None

    def _cmd_SRAT(self, query: bool, args: list[str]) -> str | None:
        return self._storage_setting(query, args, "srat", TRIGGERED_RATE)

    def _cmd_SEND(self, query: bool, args: list[str]) -> str | None:
        return self._storage_setting(query, args, "send", 1)

    def _cmd_TSTR(self, query: bool, args: list[str]) -> str | None:
        return self._storage_setting(query, args, "tstr", 1)

    def _start_storage(self, at: float) -> None:
        self.storage.start(at)
        for t in self.storage.due(self.clock.now()):  # a point at the start itself
            self._filter_to(t, self._signal())
            self.storage.store(*self._displays())

    def _cmd_STRT(self, query: bool, args: list[str]) -> None:
        if query or args:
            raise _BadCommand(_ESR_CMD)
        self._start_storage(self.clock.now())

    def _cmd_STRD(self, query: bool, args: list[str]) -> None:
        if query or args:
            raise _BadCommand(_ESR_CMD)
        self.storage.reset()
        self._start_storage(self.clock.now() + STRD_DELAY_S)

    def _cmd_PAUS(self, query: bool, args: list[str]) -> None:
        if query or args:
            raise _BadCommand(_ESR_CMD)
        self.storage.pause()

    def _cmd_REST(self, query: bool, args: list[str]) -> None:
        if query or args:
            raise _BadCommand(_ESR_CMD)
        self.storage.reset()

    def _cmd_TRIG(self, query: bool, args: list[str]) -> None:
        if query or args:
            raise _BadCommand(_ESR_CMD)
        storage = self.storage
        acted = False
        if storage.tstr and storage.state in ("idle", "paused"):
            self._start_storage(self.clock.now())
            acted = True
        if storage.scanning and storage.srat == TRIGGERED_RATE:
            storage.store(*self._displays())
            acted = True
        if acted:
            self.lias |= _LIA_TRIG

    # data transfer
    def _cmd_SPTS(self, query: bool, args: list[str]) -> str:
        if not query or args:
            raise _BadCommand(_ESR_CMD)
        return str(len(self.storage.points))

    def _trace(self, query: bool, args: list[str]) -> list[float]:
        if not query or len(args) != 3:
            raise _BadCommand(_ESR_CMD)
        channel = self._channel_arg(args, 2)
        start = self._index(args, BUFFER_POINTS, 1)
        count = self._index(args, BUFFER_POINTS, 2)
        points = self.storage.trace(channel, start, count)
        if points is None:
            raise _BadCommand(_ESR_EXE)  # beyond the points stored
        return points

    def _cmd_TRCA(self, query: bool, args: list[str]) -> str:
        # Every point is followed by a comma, the last one included.
        return "".join(_fmt(value) + "," for value in self._trace(query, args))

    def _cmd_TRCB(self, query: bool, args: list[str]) -> bytes:
        # IEEE 754 single precision, little-endian (PC byte order), no terminator.
        points = self._trace(query, args)
        return struct.pack(f"<{len(points)}f", *points)

    def _cmd_TRCL(self, query: bool, args: list[str]) -> bytes:
        # Non-normalised: a 16-bit mantissa m and a 16-bit exponent e (both little-endian
        # integers), value = m · 2**(e − 124).
        return b"".join(_non_normalised(value) for value in self._trace(query, args))

    # physics ------------------------------------------------------------------------
    def _signal(self) -> InputSignal:
        return self.input_signal() if self.input_signal is not None else self._constant

    def _advance(self) -> None:
        """Run the output filters from the last update to now; latch overloads."""
        now = self.clock.now()
        if now < self._t_last:
            return
        signal = self._signal()
        for t in self.storage.due(now):  # buffer points fall due on the way to now
            self._filter_to(t, signal)
            self.storage.store(*self._displays())
        self._filter_to(now, signal)
        self._latch_overloads(signal)

    def _filter_to(self, now: float, signal: InputSignal) -> None:
        """Advance the output filters to ``now`` with ``signal`` held constant."""
        dt = now - self._t_last
        if dt < 0:
            return
        self._t_last = now
        n, tau = self.poles, self.time_constant_s
        ux, uy = self.target_xy(signal)
        u = np.array([[ux], [uy]])
        if dt > 0:
            m = _cascade_matrix(dt / tau, n)
            self._d[:, :n] = u + (self._d[:, :n] - u) @ m.T
            density = (self.input_noise_v_per_rthz if signal.noise_v_per_rthz is None
                       else signal.noise_v_per_rthz)
            self._advance_noise(dt, n, tau, density)

    def _latch_overloads(self, signal: InputSignal) -> None:
        """Overloads and unlock, latched until read (LIAS?) or cleared (*CLS)."""
        n = self.poles
        ac = abs(signal.ac_rms_v) + sum(abs(rms) for _, rms, _ in signal.harmonics)
        peak = math.sqrt(2.0) * ac + (abs(signal.dc_v) if self.icpl else 0.0)
        if peak > INPUT_LIMIT_V:
            self.lias |= _LIA_INPUT
        x = self._d[0, n - 1] + self._z[0, n - 1]
        y = self._d[1, n - 1] + self._z[1, n - 1]
        full_scale = self.full_scale_v
        if abs(x) > full_scale or abs(y) > full_scale or math.hypot(x, y) > full_scale:
            self.lias |= _LIA_OUTPUT
        if not self.locked():
            self.lias |= _LIA_UNLOCK

    def _advance_noise(self, dt: float, n: int, tau: float, density: float) -> None:
        if density <= 0.0:
            self._z[:] = 0.0
            return
        span = dt
        if dt > _MEMORY_TAUS * tau:  # what came before has decayed away
            self._z[:, :n] = 0.0
            span = _MEMORY_TAUS * tau
        # Whole sub-steps only; the remainder carries over to the next update.
        self._noise_carry = min(self._noise_carry, 1.0) + span * _SUBSTEPS_PER_TAU / tau
        steps = int(self._noise_carry)
        self._noise_carry -= steps
        if steps == 0:
            return
        a, unit_variance = _noise_model(n)
        sigma_out = density * math.sqrt(ENBW_TIMES_TAU[n] / tau)
        sigma_in = sigma_out / math.sqrt(unit_variance)
        z = self._z[:, :n]
        at = a.T
        for w in self._rng.normal(0.0, sigma_in, size=(steps, 2, 1)):
            z = w + (z - w) @ at
        self._z[:, :n] = z
