"""pyserial URL handler ``simsr830://<name>?chopper=137&world=sim&seed=0`` — an emulated
SR830 lock-in amplifier (:class:`hw_mocks.firmware.sr830.Sr830Emulator`) behind a URL.

Options (applied when the named instance is first created; reopening the URL reaches the
same instrument, as reconnecting a cable does):

``baud``
    The rate the lock-in's Setup menu is set to (default 9600); a link opened at another
    rate hears nothing.
``speed`` / ``step``
    Emulator clock (:func:`hw_mocks.emulator.clock_from_options`).
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
    power-meter head). Needs ``chopper``.
"""

from __future__ import annotations

from hw_mocks.emulator import clock_from_options
from hw_mocks.firmware.sr830 import Sr830Emulator
from hw_mocks.link import EmulatedSerial

__all__ = ["Serial", "make_emulator"]

_KNOWN = {"baud", "speed", "step", "seed", "chopper", "noise", "outx", "agan", "serial",
          "model", "world", "responsivity", "gain", "aperture_mm"}


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
        clock=clock_from_options(options),
        seed=int(options.get("seed", 0)),
    )
    if "world" in options:
        from hw_mocks.sim.photodiode import ChoppedPhotodiode, bind_lockin

        if chopper is None:
            raise ValueError("a simsr830 URL with world= needs chopper=<Hz> (the light is "
                             "chopped; the chopper's reference drives REF IN)")
        aperture = options.get("aperture_mm")
        photodiode = ChoppedPhotodiode(
            responsivity_a_per_w=float(options.get("responsivity", 0.4)),
            transimpedance_v_per_a=float(options.get("gain", 1e6)),
            aperture_diameter_mm=float(aperture) if aperture is not None else None,
        )
        bind_lockin(emulator, options["world"], photodiode)
    return emulator


class Serial(EmulatedSerial):
    scheme = "simsr830"
    factory = staticmethod(make_emulator)
