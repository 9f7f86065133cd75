"""``simapt://<name>?model=K10CR1&stage=PRM1-Z8&speed=100&seed=0`` — an emulated APT
controller (:class:`hw_mocks.firmware.apt.AptEmulator`) behind a pyserial URL.

Options (applied when the named instance is first created):

``model``
    ``K10CR1`` (default) or ``KDC101``.
``stage``
    Stage on a KDC101: ``PRM1-Z8`` (default) or ``MTS25-Z8``.
``speed`` / ``step``
    Emulator clock: ``speed`` times the wall clock, or ``step`` seconds per reading.
``seed``
    Seed of the fault injector and of the stop-short quirk.
``start``
    Physical power-up position (deg or mm), overriding the profile.
``stop_short``
    Largest number of counts a move stops short (0 disables the quirk).
"""

from __future__ import annotations

from hw_mocks.emulator import clock_from_options
from hw_mocks.firmware.apt import AptEmulator
from hw_mocks.link import EmulatedSerial

__all__ = ["Serial", "make_emulator"]


def make_emulator(name: str, options: dict[str, str]) -> AptEmulator:
    """Build the emulator a ``simapt://`` URL describes."""
    start = options.get("start")
    short = options.get("stop_short")
    return AptEmulator(
        name,
        model=options.get("model", "K10CR1"),
        stage=options.get("stage"),
        clock=clock_from_options(options),
        seed=int(options.get("seed", 0)),
        start_position=float(start) if start is not None else None,
        stop_short_counts=int(short) if short is not None else None,
    )


class Serial(EmulatedSerial):
    scheme = "simapt"
    factory = staticmethod(make_emulator)
