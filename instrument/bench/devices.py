"""Open the devices a bench profile names, and close them safely.

Real drivers are imported from ``drivers`` by driver name. Devices that exist only in
simulation (camera, source) and the emulated USB backend live in ``hw_mocks``; they are
reached *only* through the URL scheme in the profile (``simcam://``, ``simsource://``,
``simusb://``), by a string import, so no code path that real hardware takes imports the
mocks. Likewise the pyserial handlers of the emulated serial controllers
(:data:`~instrument.bench.profile.SIM_SERIAL_SCHEMES`: ``simapt://``, ``simsmc://``,
``simzaber://``, ``simsr830://``, ``simsc10://``, ``simfw102c://``) are registered by
package name only when a profile uses those schemes.
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from drivers.base import (
    AxisKind,
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
from instrument.bench.profile import (
    SIM_SERIAL_SCHEMES,
    BenchProfile,
    DeviceSpec,
    FieldError,
    ProfileError,
)

__all__ = ["DRIVERS", "Bench", "open_bench", "open_device"]

#: Package holding the pyserial URL handlers of the firmware emulators.
SIM_URL_HANDLERS = "hw_mocks.urlhandler"
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
    return getattr(importlib.import_module(module), func)


def sim_entry_point(scheme: str) -> Callable[..., Any]:
    """The simulation's opener for a URL scheme of :data:`SIM_ENTRY_POINTS` (``simcam`` …).

    Production code reaches the simulation only by these strings, never by an import.
    """
    return _entry(SIM_ENTRY_POINTS[scheme])


def _scheme(url: str) -> str:
    return url.split("://", 1)[0] if "://" in url else ""


def _axis_kwargs(spec: DeviceSpec) -> dict[str, Any]:
    kw: dict[str, Any] = {"name": spec.role}
    if spec.limits is not None:
        kw["soft_limits"] = spec.limits
    if spec.position_tolerance is not None:
        kw["position_tolerance"] = spec.position_tolerance
    kw.update(spec.options)
    return kw


def _open_apt(spec: DeviceSpec) -> Device:
    from drivers.thorlabs_apt import AptMotor

    return AptMotor(spec.url, stage=spec.stage or "K10CR1", **_axis_kwargs(spec))


def _kind_kwargs(spec: DeviceSpec) -> dict[str, Any]:
    """The axis options with ``kind`` defaulted from the role (``camera_z`` is linear)."""
    kw = _axis_kwargs(spec)
    kw.setdefault("kind", AxisKind.LINEAR if spec.role == "camera_z" else AxisKind.ROTARY)
    if isinstance(kw["kind"], str):
        kw["kind"] = AxisKind.LINEAR if kw["kind"] == "linear" else AxisKind.ROTARY
    return kw


def _open_smc100(spec: DeviceSpec) -> Device:
    from drivers.newport_smc100 import Smc100Axis

    return Smc100Axis(spec.url, **_kind_kwargs(spec))


def _open_zaber(spec: DeviceSpec) -> Device:
    from drivers.zaber_ascii import ZaberAxis

    kw = _kind_kwargs(spec)
    if "microstep_size" not in kw:
        raise ConnectionFailed("a Zaber axis needs options.microstep_size (degrees or mm per "
                               "microstep, from the product's specification)",
                               device=spec.role, command="open")
    return ZaberAxis(spec.url, **kw)


def _open_sr830(spec: DeviceSpec) -> Device:
    from drivers.stanford_sr830 import Sr830LockIn

    kw: dict[str, Any] = {"name": spec.role, **spec.options}
    if _scheme(spec.url) == "simsr830":
        # An emulator on a host-paced clock (``clock=host``) lets time pass when the driver
        # waits, so its readings do not depend on how fast the machine runs the host.
        sleep = _entry(SIM_ENTRY_POINTS["simsr830"])(spec.url)
        if sleep is not None:
            kw.setdefault("sleep", sleep)
    return Sr830LockIn(spec.url, **kw)


def _open_sc10(spec: DeviceSpec) -> Device:
    from drivers.thorlabs_sc10 import Sc10Shutter

    return Sc10Shutter(spec.url, name=spec.role, **spec.options)


def _open_fw102c(spec: DeviceSpec) -> Device:
    from drivers.thorlabs_fw102c import Fw102cWheel

    return Fw102cWheel(spec.url, name=spec.role, **spec.options)


def _open_pm100(spec: DeviceSpec) -> Device:
    from drivers.thorlabs_pm100 import PM100USB

    kw: dict[str, Any] = {"name": spec.role, **spec.options}
    if _scheme(spec.url) == "simusb":
        kw["backend"] = _entry(SIM_ENTRY_POINTS["simusb"])(spec.url)
    elif spec.url.startswith("usb://"):
        serial = spec.url[len("usb://"):].strip("/")
        if serial:
            kw.setdefault("serial_number", serial)
    return PM100USB(**kw)


def _open_opencv(spec: DeviceSpec) -> Device:
    from drivers.opencv_camera import OpenCVCamera

    return OpenCVCamera(spec.url, name=spec.role, **spec.options)


def _open_basler(spec: DeviceSpec) -> Device:
    from drivers.pylon_transport import open_basler_camera

    return open_basler_camera(spec.url, name=spec.role, **spec.options)  # url: the serial


def _open_simulated(spec: DeviceSpec) -> Device:
    scheme = _scheme(spec.url)
    if scheme not in ("simcam", "simsource"):
        raise ConnectionFailed(f"driver {spec.driver!r} needs a simcam:// or simsource:// URL",
                               device=spec.role, command="open")
    device = _entry(SIM_ENTRY_POINTS[scheme])(spec.url)
    device.name = spec.role
    return device


#: Driver name → opener.
DRIVERS: dict[str, Callable[[DeviceSpec], Device]] = {
    "thorlabs_apt": _open_apt,
    "newport_smc100": _open_smc100,
    "pm100usb": _open_pm100,
    "opencv_camera": _open_opencv,
    "sim_camera": _open_simulated,
    "sim_source": _open_simulated,
    "zaber": _open_zaber,
    "sr830": _open_sr830,
    "sc10": _open_sc10,
    "fw102c": _open_fw102c,
    "basler": _open_basler,
}


def open_device(spec: DeviceSpec) -> Device:
    """Open one device and apply the profile's motion settings."""
    if _scheme(spec.url) in SIM_SERIAL_SCHEMES:
        add_url_handler_package(SIM_URL_HANDLERS)
    try:
        device = DRIVERS[spec.driver](spec)
    except DeviceError:
        raise
    except ImportError as err:
        raise ConnectionFailed(f"driver {spec.driver!r} is not available: {err}",
                               device=spec.role, command="open") from err
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
        return self._one(Camera)

    @property
    def power_meter(self) -> PowerMeter | None:
        return self._one(PowerMeter)

    @property
    def source(self) -> LightSource | None:
        """The light source proper (a shutter is a light source too: it is the source only
        on a bench with no other)."""
        found = [d for d in self.devices.values()
                 if isinstance(d, LightSource) and not isinstance(d, Shutter)]
        return found[0] if found else self.shutter

    @property
    def shutter(self) -> Shutter | None:
        return self._one(Shutter)

    @property
    def light_switch(self) -> LightSource | None:
        """What the engine switches for light and dark frames: the shutter when the bench
        has one (the source stays on, as a laser would), else the source."""
        return self.shutter or self.source

    @property
    def lockin(self) -> LockIn | None:
        return self._one(LockIn)

    @property
    def filter_wheel(self) -> FilterWheel | None:
        return self._one(FilterWheel)

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

    def __exit__(self, *exc) -> None:
        self.close()


def simulation_config(profile: BenchProfile) -> tuple[str, dict[str, Any]]:
    """The world name and the virtual-bench configuration for an emulated profile.

    What the profile already says is not repeated in ``[simulation]``: each motion role is
    bound to its device URL, the power-meter head to the ``simusb://`` power meter, and the
    arm length to the geometry's detector distance, unless the table overrides them.
    """
    config = dict(profile.simulation or {})
    world = str(config.pop("world", "sim"))
    roles = {role: spec.url for role, spec in profile.axes.items() if spec.is_simulated}
    roles.update(config.get("roles", {}))
    config["roles"] = roles
    config.setdefault("arm_length_mm", profile.geometry.detector_distance_mm)
    meters = [s.url for s in profile.devices.values() if _scheme(s.url) == "simusb"]
    if meters:
        # The simulated head is the detector the geometry describes: same distance and
        # limiting aperture, so an absolute BRDF uses the profile's solid angle.
        head = dict(config.get("power_meter", {}))
        head.setdefault("url", meters[0])
        head.setdefault("distance_mm", profile.geometry.detector_distance_mm)
        head.setdefault("aperture_diameter_mm", profile.geometry.detector_aperture_mm)
        config["power_meter"] = head
    return world, config


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
