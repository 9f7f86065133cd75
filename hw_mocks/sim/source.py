"""The simulated light source (laser with a shutter) on the virtual bench.

Turning it on or off, or changing its power, changes the world that the simulated camera
and the power meter see. ``is_on`` means light reaches the sample (source on and its own
shutter open), as in :class:`drivers.base.LightSource`. A separate shutter or filter wheel
in the world's light path (an SC10 or FW102C emulator; see
:meth:`hw_mocks.sim.world.VirtualBench.light_at_sample`) can still block the light after it.

URL: ``simsource://<name>?world=sim`` with optional ``power_w``, ``wavelength_nm``,
``beam_radius_mm`` and ``max_power_w``, applied to the world's source when the device opens.
"""

from __future__ import annotations

from drivers.base import DeviceIdentity, LightSource
from hw_mocks import registry
from hw_mocks.sim.world import VirtualBench, get_world

__all__ = ["SimulatedSource", "open_from_url"]


class SimulatedSource(LightSource):
    """A collimated source whose state lives in a :class:`VirtualBench`.

    The power setpoint range is ``(0, world.source.max_power_w)`` W. Opening the device does
    not change whether the light is on; closing it turns the light off (a closed source must
    never leave the sample lit).
    """

    def __init__(self, name: str = "source", *, world: VirtualBench | None = None) -> None:
        super().__init__(name)
        self.world = world if world is not None else get_world("sim")
        self.power_range_w = (0.0, self.world.source.max_power_w)

    def _do_identity(self) -> DeviceIdentity:
        s = self.world.source
        return DeviceIdentity(
            vendor="scatterlab", model="SimSource", serial=f"SRC-{self.world.name}",
            firmware="1.0", extra={"wavelength_nm": f"{s.wavelength_nm:g}"},
        )

    def _do_set_on(self, on: bool) -> None:
        self.world.update_source(on=bool(on))

    def _do_is_on(self) -> bool:
        return self.world.source.on

    def _do_get_power_w(self) -> float:
        return self.world.source.power_w

    def _do_set_power_w(self, value: float) -> None:
        self.world.update_source(power_w=value)

    @property
    def wavelength_nm(self) -> float:
        """Emission wavelength (fixed for a laser)."""
        self._check_open("wavelength_nm")
        return self.world.source.wavelength_nm

    def _do_close(self) -> None:
        self.world.update_source(on=False)


def open_from_url(url: str, *, name: str | None = None) -> SimulatedSource:
    """Open ``simsource://<name>?world=sim[&power_w=..&wavelength_nm=..&beam_radius_mm=..]``."""
    scheme, host, options = registry.parse_url(url)
    if scheme != "simsource":
        raise ValueError(f"expected a simsource:// URL, got {url!r}")
    known = {"world", "power_w", "wavelength_nm", "beam_radius_mm", "max_power_w"}
    unknown = set(options) - known
    if unknown:
        raise ValueError(f"unknown simsource options {sorted(unknown)}; known {sorted(known)}")
    world = get_world(options.get("world", "sim"))
    changes = {}
    for key, value in options.items():
        if key == "world":
            continue
        try:
            changes[key] = float(value)
        except ValueError:
            raise ValueError(f"{url}: option {key}={value!r} is not a number") from None
    if changes:
        world.update_source(**changes)
    return SimulatedSource(name or host, world=world)
