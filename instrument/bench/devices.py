"""Open the devices a bench profile names, and close them safely.

Drivers are found by name in the driver registry (:mod:`instrument.bench.driver_registry`:
every driver, scatterlab's and plugins', is registered under the ``scatterlab.drivers``
entry-point group). Devices that exist only in simulation (camera, source) and the emulated
USB backend live in ``hw_mocks``; they are reached *only* through the URL scheme in the
profile (``simcam://``, ``simsource://``, ``simusb://``), by a string import, so no code
path that real hardware takes imports the mocks. Likewise the pyserial handlers of the
emulated serial controllers (each driver's registered emulator scheme: ``simapt://``,
``simsmc://``... and a plugin's own) are registered by package name only when a profile
uses their scheme.
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from drivers.base import (
    Camera,
    Device,
    FilterWheel,
    LightSource,
    LockIn,
    MotionAxis,
    PowerMeter,
    Shutter,
)
from drivers.errors import ConnectionFailed, DeviceError
from drivers.transport import add_url_handler_package
from instrument.bench.driver_registry import PluginError, driver_registry, kind_abc
from instrument.bench.profile import (
    BenchProfile,
    DeviceSpec,
    FieldError,
    ProfileError,
)

__all__ = ["Bench", "open_bench", "open_device", "serial_emulator_schemes"]

#: Simulation entry points, by URL scheme, as "module:function" strings.
SIM_ENTRY_POINTS = {
    "simcam": "hw_mocks.sim.camera:open_from_url",
    "simsource": "hw_mocks.sim.source:open_from_url",
    "simusb": "hw_mocks.usb:backend_from_url",
    # the waiting function that paces an emulated SR830's clock (None: the wall clock)
    "simsr830": "hw_mocks.urlhandler.protocol_simsr830:host_sleep",
}
SIM_WORLD_ENTRY = "hw_mocks.sim.world:configure_world"


def _entry(spec: str) -> Callable[..., Any]:
    module, _, func = spec.partition(":")
    opener: Callable[..., Any] = getattr(importlib.import_module(module), func)
    return opener


def sim_entry_point(scheme: str) -> Callable[..., Any]:
    """The simulation's opener for a URL scheme of :data:`SIM_ENTRY_POINTS` (``simcam`` …).

    Production code reaches the simulation only by these strings, never by an import.
    """
    return _entry(SIM_ENTRY_POINTS[scheme])


def _scheme(url: str) -> str:
    return url.split("://", 1)[0] if "://" in url else ""


def serial_emulator_schemes() -> dict[str, str]:
    """URL scheme → package of its pyserial handler, of every registered driver's emulator
    (``simapt`` → ``hw_mocks.urlhandler``; a plugin's own)."""
    return driver_registry().emulator_schemes()


def open_device(spec: DeviceSpec) -> Device:
    """Open one device and apply the profile's motion settings."""
    registry = driver_registry()
    handlers = registry.emulator_schemes().get(_scheme(spec.url))
    if handlers is not None:
        add_url_handler_package(handlers)
    driver = registry.get(spec.driver)
    if driver is None:
        raise ConnectionFailed(registry.unknown_driver_message(spec.driver), device=spec.role,
                               command="open")
    try:
        device = driver.open(spec)
    except DeviceError:
        raise
    except PluginError as err:
        raise ConnectionFailed(str(err), device=spec.role, command="open") from err
    except ImportError as err:
        raise ConnectionFailed(f"driver {spec.driver!r} is not available: {err}",
                               device=spec.role, command="open") from err
    kind = registry.kind_of(spec.driver)
    assert kind is not None  # the device was opened through its registered entry
    if not isinstance(device, Device) or not isinstance(device, kind_abc(kind)):
        with contextlib.suppress(Exception):
            device.close()
        raise ConnectionFailed(
            f"driver {spec.driver!r} (from {driver.origin}) opened a "
            f"{type(device).__name__}, not a device of its kind {kind!r}; fix the driver's "
            "open function", device=spec.role, command="open")
    try:
        if isinstance(device, MotionAxis):
            if spec.velocity is not None:
                device.velocity = spec.velocity
            if spec.acceleration is not None:
                device.acceleration = spec.acceleration
        for key, value in spec.settings.items():
            setattr(device, key, value)  # public properties: validated by the device
    except BaseException:
        device.close()
        raise
    return device


@dataclass
class Bench:
    """The opened devices of a profile, by role."""

    profile: BenchProfile
    devices: dict[str, Device] = field(default_factory=dict)

    @property
    def axes(self) -> dict[str, MotionAxis]:
        return {r: d for r, d in self.devices.items() if isinstance(d, MotionAxis)}

    def _one(self, kind: type) -> Any:
        found = [d for d in self.devices.values() if isinstance(d, kind)]
        return found[0] if found else None

    @property
    def camera(self) -> Camera | None:
        found: Camera | None = self._one(Camera)
        return found

    @property
    def power_meter(self) -> PowerMeter | None:
        found: PowerMeter | None = self._one(PowerMeter)
        return found

    @property
    def source(self) -> LightSource | None:
        """The light source proper (a shutter is a light source too: it is the source only
        on a bench with no other)."""
        found = [d for d in self.devices.values()
                 if isinstance(d, LightSource) and not isinstance(d, Shutter)]
        return found[0] if found else self.shutter

    @property
    def shutter(self) -> Shutter | None:
        found: Shutter | None = self._one(Shutter)
        return found

    @property
    def light_switch(self) -> LightSource | None:
        """What the engine switches for light and dark frames: the shutter when the bench
        has one (the source stays on, as a laser would), else the source."""
        return self.shutter or self.source

    @property
    def lockin(self) -> LockIn | None:
        found: LockIn | None = self._one(LockIn)
        return found

    @property
    def filter_wheel(self) -> FilterWheel | None:
        found: FilterWheel | None = self._one(FilterWheel)
        return found

    def homed_pose(self) -> dict[str, float]:
        """Positions (axis units) of the homed axes now, read from each axis: the pose the
        guard judges a manual move from (an unhomed axis's counter is not a physical
        position, so it is left out)."""
        pose = {}
        for role, axis in self.axes.items():
            s = axis.status()
            if s.is_homed:
                pose[role] = s.position
        return pose

    def make_safe(self) -> list[str]:
        """Stop every axis and turn the light off; return what could not be done."""
        problems = []
        for device in self.devices.values():
            try:
                if isinstance(device, LightSource):
                    device.turn_off()
                elif isinstance(device, MotionAxis):
                    device.stop()
            except DeviceError as err:
                problems.append(str(err))
        return problems

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.make_safe()
        for device in reversed(list(self.devices.values())):
            with contextlib.suppress(Exception):
                device.close()

    def __enter__(self) -> Bench:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def simulation_config(profile: BenchProfile) -> tuple[str, dict[str, Any]]:
    """The world name and the virtual-bench configuration for an emulated profile.

    What the profile already says is not repeated in ``[simulation]``: each motion role is
    bound to its device URL (a type (i) arm's with its stage offset; a mount on a bus of
    addressed modules, an Elliptec ELL14's, with its ``options.address``, so each mount
    of the bus is its own axis of the world), the power-meter head
    to the ``simusb://`` power meter, and the arm length to the geometry's detector
    distance, unless the table overrides them.
    """
    config = dict(profile.simulation or {})
    world = str(config.pop("world", "sim"))
    roles: dict[str, Any] = {role: _role_binding(spec) for role, spec in profile.axes.items()
                             if spec.is_simulated}
    geo = profile.geometry
    for arm, spec in (("source", geo.source_arm), ("detector", geo.detector_arm)):
        # a type (i) arm's stage reads its angle plus the profile's offset (ADR 0099)
        for axis, offset in ((f"{arm}_arc", 0.0 if spec is None else spec.arc_offset_deg),
                             (f"{arm}_azimuth",
                              0.0 if spec is None else spec.azimuth_offset_deg)):
            if offset and isinstance(roles.get(axis), str):
                roles[axis] = {"url": roles[axis], "offset": -offset}
    roles.update(config.get("roles", {}))
    config["roles"] = roles
    config.setdefault("arm_length_mm", profile.geometry.detector_distance_mm)
    # the simulated source has the coherence of the profile's [source]
    config["source"] = {**dict(config.get("source", {})), "coherence": profile.coherence}
    meters = [s.url for s in profile.devices.values()
              if s.kind == "power_meter" and s.is_simulated]
    if meters:
        # The simulated head is the detector the geometry describes: same distance and
        # limiting aperture, so an absolute BRDF uses the profile's solid angle. An
        # emulated meter of any driver reads it; a PM100USB's is bound by its URL.
        head = dict(config.get("power_meter", {}))
        usb = [url for url in meters if _scheme(url) == "simusb"]
        if usb:
            head.setdefault("url", usb[0])
        head.setdefault("distance_mm", profile.geometry.detector_distance_mm)
        head.setdefault("aperture_diameter_mm", profile.geometry.detector_aperture_mm)
        config["power_meter"] = head
    return world, config


def _role_binding(spec: DeviceSpec) -> Any:
    """What the virtual bench reads for one simulated motion device: its URL, or, for a
    module on a shared bus (an ``address`` option), the URL and that address."""
    address = spec.options.get("address")
    if address is None:
        return spec.url
    return {"url": spec.url, "address": str(address)}


def configure_simulation(profile: BenchProfile) -> None:
    """Create the virtual bench a profile's ``[simulation]`` table describes."""
    if profile.simulation is None:
        return
    world, config = simulation_config(profile)
    try:
        _entry(SIM_WORLD_ENTRY)(world, config)
    except (ValueError, TypeError, KeyError) as err:
        # The virtual bench validates its own tables; report it as the profile field it is.
        raise ProfileError(f"bench profile {profile.name!r}",
                           [FieldError("simulation", str(err))]) from err


def open_bench(profile: BenchProfile, *, roles: Iterable[str] | None = None) -> Bench:
    """Open the profile's devices (all, or ``roles``). Nothing stays open on failure."""
    wanted = list(profile.devices) if roles is None else list(roles)
    configure_simulation(profile)
    bench = Bench(profile)
    try:
        for role in wanted:
            bench.devices[role] = open_device(profile.device(role))
    except BaseException:
        bench.close()
        raise
    return bench
