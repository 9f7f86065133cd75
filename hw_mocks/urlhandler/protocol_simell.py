"""pyserial URL handler ``simell://<name>?addresses=0&start=0&speed=100&seed=0``.

Options (applied when the named emulator is first created; reopening the URL reaches the
same bus):

- ``addresses``: the modules on the bus, one character 0-9/A-F each (default ``0``;
  ``addresses=012`` is three mounts);
- ``start``: physical power-up angles in degrees, one value or a comma list with one entry
  per module;
- ``speed=<factor>`` or ``step=<seconds>``: the emulator clock
  (:func:`hw_mocks.emulator.clock_from_options`);
- ``seed``: fault-injector seed (default 0).
"""

from __future__ import annotations

from hw_mocks.emulator import clock_from_options
from hw_mocks.firmware.elliptec import ElliptecEmulator
from hw_mocks.link import EmulatedSerial

__all__ = ["Serial", "make_emulator"]


def make_emulator(name: str, options: dict[str, str]) -> ElliptecEmulator:
    """Build the emulator a ``simell://`` URL describes."""
    addresses = options.get("addresses", "0")
    starts = None
    if "start" in options:
        values = [float(v) for v in options["start"].split(",")]
        if len(values) == 1:
            values *= len(addresses)
        if len(values) != len(addresses):
            raise ValueError(f"simell option 'start' needs 1 or {len(addresses)} entries, "
                             f"got {options['start']!r}")
        starts = values
    return ElliptecEmulator(name, addresses=addresses, start_positions=starts,
                            clock=clock_from_options(options),
                            seed=int(options.get("seed", 0)))


class Serial(EmulatedSerial):
    scheme = "simell"
    factory = staticmethod(make_emulator)
