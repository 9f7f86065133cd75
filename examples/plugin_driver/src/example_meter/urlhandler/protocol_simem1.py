"""pyserial URL handler ``simem1://<name>?world=sim&seed=0&serial=EM0001`` — an emulated
EM-1 power meter (:class:`example_meter.emulator.Em1Emulator`).

Options apply when the named meter is first created; reopening the URL reaches the same
meter, as reconnecting a cable does: ``world`` (the virtual bench whose light it reads),
``seed`` (noise and fault injector), ``serial`` (what ``*IDN?`` reports).
"""

from __future__ import annotations

from example_meter.emulator import Em1Emulator
from hw_mocks.link import EmulatedSerial

__all__ = ["Serial"]

_KNOWN = {"world", "seed", "serial"}


def make_emulator(name: str, options: dict[str, str]) -> Em1Emulator:
    unknown = set(options) - _KNOWN
    if unknown:
        raise ValueError(f"unknown simem1 options {sorted(unknown)}; known {sorted(_KNOWN)}")
    return Em1Emulator(name, serial=options.get("serial", "EM0001"),
                       world=options.get("world") or None, seed=int(options.get("seed", 0)))


class Serial(EmulatedSerial):
    scheme = "simem1"
    factory = staticmethod(make_emulator)
