"""The drivers a bench profile may name: every one registered under one entry-point group.

A driver — built into scatterlab or shipped by another package — is registered in its
distribution's metadata under the entry-point group :data:`ENTRY_POINT_GROUP`
(``scatterlab.drivers``); the entry point's name is the name profiles use
(``driver = "thorlabs_apt"``) and its value a :class:`DriverEntry`::

    # the plugin's pyproject.toml
    [project.entry-points."scatterlab.drivers"]
    lumen_lpm = "lumen_lpm.plugin:DRIVER"

A :class:`DriverEntry` says which device kind the driver implements (an ABC of
:mod:`drivers.base`, by its name in :data:`KINDS`), the class (``"module:Class"``, imported
only when a device is opened or the drivers are listed), the profile keys it takes (its
``options`` and ``settings``, validated like every other profile field) and, optionally,
the pyserial URL scheme of its emulator and the package holding the handler.
scatterlab's own drivers are registered the same way (``pyproject.toml``,
:mod:`instrument.bench.builtin_drivers`): nothing here knows a driver by name.

A plugin that cannot be used — its entry point does not import, is not a
:class:`DriverEntry`, names an unknown kind, a class that is not a subclass of its kind's
ABC, or a name another distribution registered too — is a :class:`PluginProblem` naming
the plugin, its distribution and what to do; the other drivers load regardless (ADR 0092).
"""

from __future__ import annotations

import functools
import importlib
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # importlib.metadata is imported when the registry is first read
    from importlib import metadata

#: A profile's device table as validated (:class:`instrument.bench.profile.DeviceSpec`;
#: not imported here: the profile's validator imports this module).
DeviceSpec = Any
#: A device (:class:`drivers.base.Device`): the ABCs are imported only when a class is
#: checked, so that validating a profile does not import NumPy.
Device = Any

__all__ = [
    "BUILTIN_DISTRIBUTION",
    "ENTRY_POINT_GROUP",
    "KINDS",
    "DriverEntry",
    "DriverRegistry",
    "Emulator",
    "Option",
    "PluginError",
    "PluginProblem",
    "RegisteredDriver",
    "driver_registry",
    "kind_abc",
    "load_registry",
]

#: The entry-point group every driver is registered under.
ENTRY_POINT_GROUP = "scatterlab.drivers"
#: The distribution whose drivers are the built-in ones (they win a name clash).
BUILTIN_DISTRIBUTION = "scatterlab"
#: Device kinds by name → the name of the ABC of :mod:`drivers.base` a driver of that kind
#: subclasses. The names are the GUI's device kinds (:mod:`instrument.bench.device_state`), so a
#: plugin's device is shown through its kind. The GUI may add kinds that refine one of
#: these for a driver class with more to set (``genicam_camera``: a ``camera`` whose class
#: is a ``drivers.genicam_camera.GenICamCamera``); it shows a device through the most
#: derived kind its class implements.
KINDS: dict[str, str] = {
    "motion_axis": "MotionAxis",
    "camera": "Camera",
    "light_source": "LightSource",
    "shutter": "Shutter",
    "power_meter": "PowerMeter",
    "lockin": "LockIn",
    "filter_wheel": "FilterWheel",
    "modulator": "Modulator",
}


def kind_abc(kind: str) -> type:
    """The ABC of ``kind`` (a key of :data:`KINDS`), from :mod:`drivers.base`."""
    abc: type = getattr(importlib.import_module("drivers.base"), KINDS[kind])
    return abc


_TYPE_WORDS = {float: "a number", int: "an integer", bool: "true or false", str: "a string",
               dict: "a table", list: "an array"}


@dataclass(frozen=True)
class Option:
    """One key a driver takes in a profile's ``options`` or ``settings`` table.

    ``type`` is ``float`` (an integer is accepted too), ``int``, ``bool``, ``str``,
    ``dict`` (a TOML table, checked by the driver) or ``list``; ``low``/``high`` bound a
    number (inclusive), ``choices`` a string. ``doc`` says what it is, with its unit.
    """

    type: type
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    doc: str = ""

    def __post_init__(self) -> None:
        if self.type not in _TYPE_WORDS:
            raise TypeError(f"Option type must be one of "
                            f"{', '.join(t.__name__ for t in _TYPE_WORDS)}, got {self.type!r}")

    def problem(self, value: Any) -> str | None:
        """What is wrong with ``value`` for this key (None: nothing), in the profile's words."""
        if self.type is bool:
            return None if isinstance(value, bool) else "must be true or false"
        if self.type is str:
            if not isinstance(value, str):
                if self.choices:
                    return (f"must be one of {', '.join(repr(c) for c in self.choices)}, "
                            f"got {type(value).__name__}")
                return f"must be a string, got {type(value).__name__}"
            if self.choices and value not in self.choices:
                return f"must be one of {', '.join(repr(c) for c in self.choices)}"
            return None
        if self.type in (dict, list):
            return None if isinstance(value, self.type) else f"must be {_TYPE_WORDS[self.type]}"
        number = (isinstance(value, int | float) and not isinstance(value, bool)
                  and math.isfinite(value))
        if not number or (self.type is int and not isinstance(value, int)):
            return self._range_words()
        if (self.low is not None and value < self.low) or (
                self.high is not None and value > self.high):
            return self._range_words()
        return None

    def _range_words(self) -> str:
        what = _TYPE_WORDS[self.type]
        if self.low is not None and self.high is not None:
            return f"must be {what} from {self.low:g} to {self.high:g}"
        if self.low is not None:
            return f"must be {what} ≥ {self.low:g}"
        if self.high is not None:
            return f"must be {what} ≤ {self.high:g}"
        return f"must be {what}"

    def convert(self, value: Any) -> Any:
        """The validated value as the driver receives it (an integer given for a float
        becomes a float)."""
        return float(value) if self.type is float else value


@dataclass(frozen=True)
class Emulator:
    """The emulator of a driver behind a pyserial URL: ``scheme`` (``simapt``) is served by
    the module ``protocol_<scheme>`` of the package ``handlers``, which is added to
    pyserial's handler packages when a profile's URL uses the scheme."""

    scheme: str
    handlers: str

    def __post_init__(self) -> None:
        if not self.scheme.isidentifier() or not self.scheme.islower():
            raise ValueError(f"an emulator's URL scheme is a lower-case identifier (pyserial "
                             f"imports protocol_<scheme>), got {self.scheme!r}")


@dataclass(frozen=True)
class DriverEntry:
    """What a driver registers under :data:`ENTRY_POINT_GROUP`.

    ``kind``
        The device kind, a key of :data:`KINDS` (``"power_meter"``).
    ``driver``
        The :class:`drivers.base.Device` subclass, or ``"module:Class"`` (imported when a
        device is opened or the drivers are listed, not when a profile is validated).
    ``options``
        The keys the profile's ``options`` table may hold: keyword arguments of the
        constructor (:class:`Option` each). A key not listed is a profile error.
    ``settings``
        The device's public properties a profile's ``settings`` table may set after
        opening (``wavelength_nm``): validated here, then set through the property.
    ``emulator``
        Optional :class:`Emulator`: the pyserial URL scheme of the driver's emulator.
    ``open``
        How to construct the device from the profile's :class:`DeviceSpec`:
        ``open(cls, spec) -> Device``. By default ``cls(spec.url, name=spec.role,
        **options)``, and for a motion axis also ``soft_limits`` and
        ``position_tolerance`` from the profile's ``limits`` and ``position_tolerance``.
    ``summary``
        One line for ``scatterlab devices --list-drivers``.
    ``by_serial``
        True for a driver that finds its device by serial number (a GenICam camera that
        pylon enumerates): the profile names the device by ``serial = "..."`` instead of
        ``url``, and the serial reaches ``open`` as ``spec.url``.
    """

    kind: str
    driver: type | str
    options: Mapping[str, Option] = field(default_factory=dict)
    settings: Mapping[str, Option] = field(default_factory=dict)
    emulator: Emulator | None = None
    open: Callable[[type, DeviceSpec], Device] | None = None
    summary: str = ""
    by_serial: bool = False


class PluginError(RuntimeError):
    """A registered driver cannot be used; the message names it, its distribution and
    what to do."""


@dataclass(frozen=True)
class _Registration:
    """One entry point: the driver name, the distribution and version that registered it,
    and its ``module:attr``."""

    name: str
    distribution: str
    version: str
    target: str

    @property
    def origin(self) -> str:
        return f"{self.distribution} {self.version}".strip()


@dataclass(frozen=True)
class PluginProblem(_Registration):
    """A driver registration that was refused (the others load regardless)."""

    message: str

    def __str__(self) -> str:
        return f"driver {self.name!r} ({self.target}, from {self.origin}): {self.message}"


@dataclass(frozen=True)
class RegisteredDriver(_Registration):
    """A usable driver: its registration and its entry."""

    entry: DriverEntry

    @property
    def kind(self) -> str:
        return self.entry.kind

    @property
    def builtin(self) -> bool:
        return self.distribution == BUILTIN_DISTRIBUTION

    def driver_class(self) -> type[Device]:
        """The driver's class, imported now; :class:`PluginError` naming the driver, its
        distribution and what to do if it does not import or is not a subclass of its
        kind's ABC."""
        try:
            return _resolve_class(self.entry)
        except PluginError as err:
            raise PluginError(f"driver {self.name!r} (from {self.origin}): {err}") from err

    def open(self, spec: DeviceSpec) -> Device:
        """Construct the device a profile's ``spec`` describes (not yet checked)."""
        cls = self.driver_class()
        if self.entry.open is not None:
            return self.entry.open(cls, spec)
        kwargs: dict[str, Any] = {"name": spec.role}
        if self.entry.kind == "motion_axis":
            if spec.limits is not None:
                kwargs["soft_limits"] = spec.limits
            if spec.position_tolerance is not None:
                kwargs["position_tolerance"] = spec.position_tolerance
        kwargs.update(spec.options)
        return cls(spec.url, **kwargs)


def _resolve_class(entry: DriverEntry) -> type[Device]:
    """``entry.driver`` as a class of its kind, or :class:`PluginError` saying why not."""
    target = entry.driver
    if isinstance(target, str):
        module, _, attr = target.partition(":")
        try:
            target = getattr(importlib.import_module(module), attr)
        except Exception as err:  # any failure of a third party's import is reported
            raise PluginError(
                f"its class {entry.driver!r} does not import ({type(err).__name__}: {err}); "
                "install what it needs, fix the plugin, or uninstall it") from err
    abc = kind_abc(entry.kind)
    if not (isinstance(target, type) and issubclass(target, abc)):
        raise PluginError(
            f"{getattr(target, '__qualname__', target)!r} is not a subclass of "
            f"drivers.base.{abc.__name__}, the ABC of kind {entry.kind!r}: a driver of that "
            f"kind subclasses {abc.__name__} and implements its _do_* hooks; fix the plugin")
    return target


@dataclass
class DriverRegistry:
    """The usable drivers by name, and the registrations that were refused."""

    drivers: dict[str, RegisteredDriver] = field(default_factory=dict)
    problems: list[PluginProblem] = field(default_factory=list)

    def get(self, name: str) -> RegisteredDriver | None:
        return self.drivers.get(name)

    def kind_of(self, name: str) -> str | None:
        found = self.drivers.get(name)
        return None if found is None else found.kind

    def names(self) -> list[str]:
        return sorted(self.drivers)

    def problem_of(self, name: str) -> PluginProblem | None:
        """Why a driver of this name is not usable (a refused registration), if it was."""
        return next((p for p in self.problems if p.name == name), None)

    def verify(self) -> list[PluginProblem]:
        """Import every driver's class now (those named ``"module:Class"`` are otherwise
        imported when a device is opened): the drivers whose class does not import or is
        not of its kind move from :attr:`drivers` to :attr:`problems`, which are returned."""
        found = []
        for name, d in list(self.drivers.items()):
            try:
                _resolve_class(d.entry)
            except PluginError as err:
                del self.drivers[name]
                found.append(PluginProblem(name, d.distribution, d.version, d.target, str(err)))
        self.problems.extend(found)
        return found

    def serial_drivers(self) -> list[str]:
        """The drivers that find their device by serial number (``by_serial``)."""
        return [n for n in self.names() if self.drivers[n].entry.by_serial]

    def emulator_schemes(self) -> dict[str, str]:
        """URL scheme → the package holding its pyserial handler, of every driver."""
        return {d.entry.emulator.scheme: d.entry.emulator.handlers
                for d in self.drivers.values() if d.entry.emulator is not None}

    def unknown_driver_message(self, name: str) -> str:
        """What a profile naming an unregistered driver is told."""
        problem = self.problem_of(name)
        if problem is not None:
            return f"driver {name!r} is not usable: {problem.message}"
        if not any(d.builtin for d in self.drivers.values()):
            return (f"unknown driver {name!r}: no built-in driver is registered, so "
                    f"scatterlab's entry points are missing; reinstall it "
                    f"(pip install -e . in the source tree)")
        return (f"unknown driver {name!r}; use one of {', '.join(self.names())} (or install "
                f"the package that registers it: scatterlab devices --list-drivers)")


def _entry_points() -> Iterable[metadata.EntryPoint]:
    from importlib import metadata

    return metadata.entry_points(group=ENTRY_POINT_GROUP)


def _dist_of(ep: metadata.EntryPoint) -> tuple[str, str]:
    dist = ep.dist
    if dist is None:
        return "(unknown distribution)", ""
    return dist.metadata["Name"] or dist.name, dist.version or ""


def _problem(ep: metadata.EntryPoint, message: str) -> PluginProblem:
    name, version = _dist_of(ep)
    return PluginProblem(ep.name, name, version, ep.value, message)


def _load_one(ep: metadata.EntryPoint) -> RegisteredDriver | PluginProblem:
    dist, version = _dist_of(ep)
    try:
        entry = ep.load()
    except Exception as err:  # a plugin's import may fail in any way; report, go on
        return _problem(ep, f"the entry point {ep.value!r} does not import "
                            f"({type(err).__name__}: {err}); install what it needs, fix the "
                            f"plugin, or uninstall {dist}")
    if not isinstance(entry, DriverEntry):
        return _problem(ep, f"the entry point {ep.value!r} is a {type(entry).__name__}, not "
                            f"an instrument.bench.driver_registry.DriverEntry; fix the plugin")
    if entry.kind not in KINDS:
        return _problem(ep, f"unknown device kind {entry.kind!r}; kinds are "
                            f"{', '.join(KINDS)}; fix the plugin")
    if not isinstance(entry.driver, str):
        try:  # a class given as such is checked now; a "module:Class" string when used
            _resolve_class(entry)
        except PluginError as err:
            return _problem(ep, str(err))
    return RegisteredDriver(ep.name, dist, version, ep.value, entry)


def load_registry(entry_points: Iterable[metadata.EntryPoint] | None = None) -> DriverRegistry:
    """Read every driver registered under :data:`ENTRY_POINT_GROUP` (or ``entry_points``).

    A name registered by scatterlab and by a plugin stays scatterlab's (the plugin's
    registration is refused); a name two plugins register is refused for both, since
    neither can be chosen for the other.
    """
    registry = DriverRegistry()
    loaded: dict[str, list[RegisteredDriver]] = {}
    for ep in _entry_points() if entry_points is None else entry_points:
        result = _load_one(ep)
        if isinstance(result, PluginProblem):
            registry.problems.append(result)
        else:
            loaded.setdefault(result.name, []).append(result)
    for name, found in loaded.items():
        builtin = [d for d in found if d.builtin]
        if len(found) == 1:
            registry.drivers[name] = found[0]
            continue
        keep = builtin[0] if len(builtin) == 1 else None
        if keep is not None:
            registry.drivers[name] = keep
        for d in found:
            if d is keep:
                continue
            others = ", ".join(o.origin for o in found if o is not d)
            what = ("a built-in driver has that name" if keep is not None
                    else f"{others} registers the same name")
            registry.problems.append(PluginProblem(
                name, d.distribution, d.version, d.target,
                f"duplicate driver name: {what}; rename the plugin's entry point or "
                f"uninstall one of them"))
    return registry


@functools.cache
def driver_registry() -> DriverRegistry:
    """The drivers of the installed distributions, read once per process."""
    return load_registry()
