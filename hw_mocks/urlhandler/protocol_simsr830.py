"""pyserial URL handler ``simsr830://<name>?chopper=137&world=sim&seed=0`` — an emulated
SR830 lock-in amplifier (:class:`hw_mocks.firmware.sr830.Sr830Emulator`) behind a URL.

Options (applied when the named instance is first created; reopening the URL reaches the
same instrument, as reconnecting a cable does):

``baud``
    The rate the lock-in's Setup menu is set to (default 9600); a link opened at another
    rate hears nothing.
``speed`` / ``step``
    Emulator clock (:func:`hw_mocks.emulator.clock_from_options`).
``clock``
    ``host``: emulated time paced by the host (:class:`hw_mocks.clock.HostPacedClock`)
    instead of the wall clock. The driver's waits advance it (the bench opens the driver
    with :func:`host_sleep` as its waiting function), as do the bytes on the wire, so the
    output filter's state and the noise it has accumulated at each reading follow from the
    host's commands and waits, not from how fast the machine ran them: a seeded run reads
    the same values on a quiet and on a loaded machine. Not with ``speed``/``step``. A
    host on the far side of a pty cannot pace it (:func:`hw_mocks.pty_server.serve_url`
    serves such a URL on the wall clock).
``sleep``
    With ``clock=host``, ``sleep=0``: the driver's waits advance the emulated clock without
    sleeping on the host (tests: the same readings as a paced run, none of its wall time).
``seed``
    Seeds the fault injector and the input noise.
``chopper``
    Frequency (Hz) of the chopper reference driving REF IN; absent: nothing connected.
``noise``
    White noise density at the input, V/√Hz rms (default 1e-8).
``outx``
    Output interface at power-up, 0 RS-232 or 1 GPIB (default 1: a driver must send
    ``OUTX 0`` first).
``agan``
    Duration of an auto gain in time constants (default 10).
``serial`` / ``model``
    What ``*IDN?`` reports (defaults ``00111``, ``SR830``).
``world``
    Name of a virtual bench: the input is the chopped photodiode signal at the detector
    (:mod:`hw_mocks.sim.photodiode`), with ``responsivity`` (A/W, default 0.4), ``gain``
    (transimpedance V/A, default 1e6) and optional ``aperture_mm`` (default: the world's
    power-meter head). Needs ``chopper``, or ``reference=pem``.
``reference``
    ``pem``: REF IN is driven by the world's photoelastic modulator, whose generator lights
    the photodiode (:class:`hw_mocks.sim.photodiode.ModulatedLockInBinding`: 1f and 2f on
    the input, the photodiode's DC on Aux In 1); no chopper.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from hw_mocks import registry
from hw_mocks.clock import Clock, HostPacedClock
from hw_mocks.emulator import clock_from_options
from hw_mocks.firmware.sr830 import Sr830Emulator
from hw_mocks.link import EmulatedSerial

__all__ = ["Serial", "host_sleep", "make_emulator"]

_KNOWN = {"baud", "speed", "step", "clock", "sleep", "seed", "chopper", "noise", "outx", "agan",
          "serial", "model", "world", "responsivity", "gain", "aperture_mm", "reference"}


def _clock(options: dict[str, str]) -> Clock:
    kind = options.get("clock")
    if kind is None:
        return clock_from_options(options)
    if kind != "host":
        raise ValueError(f"simsr830 clock={kind!r}: the only choice is 'host' (leave it out "
                         "for the wall clock)")
    if "speed" in options or "step" in options:
        raise ValueError("simsr830: clock=host paces emulated time by the host's waits; it "
                         "takes no speed= or step=")
    if options.get("sleep", "1") not in ("0", "1"):
        raise ValueError(f"simsr830 sleep={options['sleep']!r}: 0 (advance the clock "
                         "without sleeping) or 1 (the default)")
    return HostPacedClock()


def make_emulator(name: str, options: dict[str, str]) -> Sr830Emulator:
    """Build the emulator a ``simsr830://`` URL describes (and bind it to a world)."""
    unknown = set(options) - _KNOWN
    if unknown:
        raise ValueError(f"unknown simsr830 options {sorted(unknown)}; known {sorted(_KNOWN)}")
    chopper = options.get("chopper")
    emulator = Sr830Emulator(
        name,
        baudrate=int(options.get("baud", 9600)),
        reference_input_hz=float(chopper) if chopper is not None else None,
        input_noise_v_per_rthz=float(options.get("noise", 10e-9)),
        output_interface=int(options.get("outx", 1)),
        agan_time_constants=float(options.get("agan", 10.0)),
        serial_number=options.get("serial", "00111"),
        model=options.get("model", "SR830"),
        clock=_clock(options),
        seed=int(options.get("seed", 0)),
    )
    if "world" in options:
        from hw_mocks.sim.photodiode import ChoppedPhotodiode, bind_lockin

        modulated = options.get("reference") == "pem"
        if options.get("reference") not in (None, "pem"):
            raise ValueError(f"simsr830 reference={options['reference']!r}: the only choice "
                             "is 'pem' (leave it out for a chopper)")
        if chopper is None and not modulated:
            raise ValueError("a simsr830 URL with world= needs chopper=<Hz> (the light is "
                             "chopped; the chopper's reference drives REF IN) or "
                             "reference=pem")
        aperture = options.get("aperture_mm")
        photodiode = ChoppedPhotodiode(
            responsivity_a_per_w=float(options.get("responsivity", 0.4)),
            transimpedance_v_per_a=float(options.get("gain", 1e6)),
            aperture_diameter_mm=float(aperture) if aperture is not None else None,
        )
        bind_lockin(emulator, options["world"], photodiode, modulated=modulated)
    return emulator


def host_sleep(url: str) -> Callable[[float], None] | None:
    """The waiting function for the driver of the SR830 that ``url`` names, when its
    emulator runs on a host-paced clock (``clock=host``): it sleeps as a real wait would
    (the run takes the time a real bench would) and then advances the emulator's clock by
    the same seconds. ``None`` for an emulator on the wall clock (the driver's own
    ``time.sleep`` is right there). Creates the emulator if it does not exist yet, as
    opening the URL would."""
    scheme, name, options = registry.parse_url(url)
    emulator = registry.get_or_create(scheme, name, make_emulator, options)
    clock = emulator.clock
    if not isinstance(clock, HostPacedClock):
        return None

    real = options.get("sleep", "1") != "0"

    def sleep(seconds: float) -> None:
        if real:
            time.sleep(seconds)
        clock.advance(max(float(seconds), 0.0))

    return sleep


class Serial(EmulatedSerial):
    scheme = "simsr830"
    factory = staticmethod(make_emulator)
