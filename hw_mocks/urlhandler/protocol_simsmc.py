"""pyserial URL handler ``simsmc://<name>?address=1&kind=rotary&speed=100&seed=0``.

Options (applied when the named emulator is first created; reopening the URL reaches
the same controller):

- ``address``: RS-485 address 1..31 (default 1);
- ``kind``: ``rotary`` (degrees, default) or ``linear`` (millimetres);
- ``speed=<factor>`` or ``step=<seconds>``: the emulator clock
  (:func:`hw_mocks.emulator.clock_from_options`);
- ``seed``: fault-injector seed (default 0); ``start``: physical power-up position;
- ``reset_busy``/``pw0_busy``: lengths of the "busy, no reply" windows in clock seconds;
- ``settle``: how long a move stays MOVING after its profile ends (clock seconds);
- ``sl``/``sr``: the software limits stored in the controller (default the stage
  model's, ±170° for the rotary stage), e.g. ``sr=181`` for a detector arm that must
  reach the straight-through beam.
"""

from __future__ import annotations

from hw_mocks.emulator import FirmwareEmulator, clock_from_options
from hw_mocks.firmware.smc100 import STAGE_MODELS, Smc100Emulator
from hw_mocks.link import EmulatedSerial

__all__ = ["Serial"]


def _make(name: str, options: dict[str, str]) -> FirmwareEmulator:
    extra = {}
    if "start" in options:
        extra["start_position"] = float(options["start"])
    if "reset_busy" in options:
        extra["reset_busy_s"] = float(options["reset_busy"])
    if "pw0_busy" in options:
        extra["pw0_busy_s"] = float(options["pw0_busy"])
    if "settle" in options:
        extra["settle_s"] = float(options["settle"])
    limits = None
    if "sl" in options or "sr" in options:
        model = STAGE_MODELS[options.get("kind", "rotary")]
        limits = (float(options.get("sl", model.software_limits[0])),
                  float(options.get("sr", model.software_limits[1])))
    return Smc100Emulator(
        name,
        address=int(options.get("address", 1)),
        kind=options.get("kind", "rotary"),
        clock=clock_from_options(options),
        seed=int(options.get("seed", 0)),
        software_limits=limits,
        **extra,
    )


class Serial(EmulatedSerial):
    scheme = "simsmc"
    factory = staticmethod(_make)
