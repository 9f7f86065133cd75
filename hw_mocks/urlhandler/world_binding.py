"""Links whose emulator joins the virtual bench named by the URL's ``world=`` option.

A shutter or filter-wheel emulator (re)created after its world was configured (a port
reopened after an emulated power cycle) is put back into that world's light path each
time its URL is opened. The binding happens after the emulator registry has released its
lock: the world takes its own lock and, holding it, reads the registry, so the two locks
are always taken in that order.
"""

from __future__ import annotations

from typing import ClassVar

from hw_mocks import registry
from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.link import EmulatedSerial

__all__ = ["WorldBoundSerial", "bind_to_world"]


def bind_to_world(emulator: FirmwareEmulator, world_name: str | None, part: str) -> None:
    """Put ``emulator`` into world ``world_name``'s light path as ``part`` (``"shutter"``
    or ``"filter_wheel"``); nothing if no world of that name exists yet (one configured
    later names the emulator in its own table)."""
    if part not in ("shutter", "filter_wheel"):
        raise ValueError(f"part must be 'shutter' or 'filter_wheel', got {part!r}")
    if not world_name:
        return
    world = registry.find_world(world_name)
    if world is None:
        return
    if part == "shutter":
        world.bind_shutter(emulator)
    else:
        world.bind_filter_wheel(emulator)


class WorldBoundSerial(EmulatedSerial):
    """An emulator link that binds its emulator to the ``world=`` bench when opened."""

    #: Where the emulator sits in the world's light path.
    world_part: ClassVar[str] = ""

    def open(self) -> None:
        super().open()
        world_name = registry.parse_url(self.portstr)[2].get("world")
        bind_to_world(self.emulator, world_name, self.world_part)
