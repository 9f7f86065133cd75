"""pyserial URL handler ``simsc10://<name>?mode=1&interlock=0&world=sim&seed=0`` — an
emulated Thorlabs SC10 shutter controller (:class:`hw_mocks.firmware.sc10.Sc10Emulator`).

Options (applied when the named emulator is first created; reopening the URL reaches the
same controller):

- ``mode``: operating mode at power-up, 1..5 (default 1, manual);
- ``interlock``: 1 if the interlock loop is open at power-up (default 0);
- ``speed=<factor>`` or ``step=<seconds>``: the emulator clock (timed modes);
- ``seed``: fault-injector seed (default 0);
- ``world``: the virtual bench whose light this shutter gates (bound on every open).
"""

from __future__ import annotations

from hw_mocks.emulator import clock_from_options
from hw_mocks.firmware.sc10 import Sc10Emulator
from hw_mocks.urlhandler.world_binding import WorldBoundSerial

__all__ = ["Serial"]

_KNOWN = {"mode", "interlock", "speed", "step", "seed", "world"}


def _make(name: str, options: dict[str, str]) -> Sc10Emulator:
    unknown = set(options) - _KNOWN
    if unknown:
        raise ValueError(f"unknown simsc10 options {sorted(unknown)}; known {sorted(_KNOWN)}")
    return Sc10Emulator(
        name,
        mode=int(options.get("mode", 1)),
        interlock_tripped=options.get("interlock", "0") not in ("0", ""),
        clock=clock_from_options(options),
        seed=int(options.get("seed", 0)),
    )


class Serial(WorldBoundSerial):
    scheme = "simsc10"
    factory = staticmethod(_make)
    world_part = "shutter"
