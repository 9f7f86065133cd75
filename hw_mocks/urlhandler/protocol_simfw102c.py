"""pyserial URL handler ``simfw102c://<name>?slots=6&start=1&wheel_speed=1&world=sim`` — an
emulated Thorlabs FW102C/FW212C filter wheel (:class:`hw_mocks.firmware.fw102c.Fw102cEmulator`).

Options (applied when the named emulator is first created; reopening the URL reaches the
same wheel):

- ``slots``: 6 (FW102C, default) or 12 (FW212C);
- ``start``: the slot in the beam at power-up (default 1);
- ``wheel_speed``: saved speed mode, 1 high (default) or 0 normal;
- ``speed=<factor>`` or ``step=<seconds>``: the emulator clock (``speed=20`` turns the
  wheel twenty times faster than the real one);
- ``seed``: fault-injector seed (default 0);
- ``world``: the virtual bench whose light passes this wheel (bound on every open; the
  world's ``[simulation.filter_wheel]`` table says which filter sits in which slot).
"""

from __future__ import annotations

from hw_mocks.emulator import clock_from_options
from hw_mocks.firmware.fw102c import Fw102cEmulator
from hw_mocks.urlhandler.world_binding import WorldBoundSerial

__all__ = ["Serial"]

_KNOWN = {"slots", "start", "wheel_speed", "speed", "step", "seed", "world"}


def _make(name: str, options: dict[str, str]) -> Fw102cEmulator:
    unknown = set(options) - _KNOWN
    if unknown:
        raise ValueError(f"unknown simfw102c options {sorted(unknown)}; known {sorted(_KNOWN)}")
    return Fw102cEmulator(
        name,
        slots=int(options.get("slots", 6)),
        start=int(options.get("start", 1)),
        speed_mode=int(options.get("wheel_speed", 1)),
        clock=clock_from_options(options),
        seed=int(options.get("seed", 0)),
    )


class Serial(WorldBoundSerial):
    scheme = "simfw102c"
    factory = staticmethod(_make)
    world_part = "filter_wheel"
