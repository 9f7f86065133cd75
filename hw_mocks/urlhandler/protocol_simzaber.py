"""pyserial URL handler ``simzaber://<name>?device=1&axes=1&kind=rotary&speed=100&seed=0``.

Options (applied when the named emulator is first created; reopening the URL reaches the
same controller):

- ``device``: daisy-chain address 1..99 (default 1);
- ``axes``: number of axes 1..9 (default: one per ``kind`` entry, else 1);
- ``kind``: ``rotary`` (degrees, default) or ``linear`` (millimetres), or a comma list with
  one entry per axis (``kind=rotary,linear``); a single entry applies to every axis;
- ``start``: physical power-up position(s), comma list like ``kind``;
- ``checksum=1`` / ``alerts=1``: power-up ``comm.checksum`` / ``comm.alert``;
- ``speed=<factor>`` or ``step=<seconds>``: the emulator clock
  (:func:`hw_mocks.emulator.clock_from_options`);
- ``seed``: fault-injector seed (default 0).
"""

from __future__ import annotations

from hw_mocks.emulator import clock_from_options
from hw_mocks.firmware.zaber import ZaberEmulator
from hw_mocks.link import EmulatedSerial

__all__ = ["Serial", "make_emulator"]


def _per_axis(text: str, count: int, name: str) -> list[str]:
    items = [item.strip() for item in text.split(",")]
    if len(items) == 1:
        return items * count
    if len(items) != count:
        raise ValueError(f"simzaber option {name!r} needs 1 or {count} entries, got {text!r}")
    return items


def make_emulator(name: str, options: dict[str, str]) -> ZaberEmulator:
    """Build the emulator a ``simzaber://`` URL describes."""
    kinds_text = options.get("kind", "rotary")
    default_axes = len(kinds_text.split(","))
    axes = int(options.get("axes", default_axes))
    kinds = _per_axis(kinds_text, axes, "kind")
    starts = None
    if "start" in options:
        starts = [float(v) for v in _per_axis(options["start"], axes, "start")]
    return ZaberEmulator(
        name,
        device=int(options.get("device", 1)),
        kinds=kinds,
        start_positions=starts,
        checksum=options.get("checksum", "0") not in ("0", "", "false"),
        alerts=options.get("alerts", "0") not in ("0", "", "false"),
        clock=clock_from_options(options),
        seed=int(options.get("seed", 0)),
    )


class Serial(EmulatedSerial):
    scheme = "simzaber"
    factory = staticmethod(make_emulator)
