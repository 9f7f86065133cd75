"""Device kinds, and how to read a device's state (Qt-free): the GUI's device worker and
the bench server's sampler both read devices through here.

A kind is one abstract class of :mod:`drivers.base` (motion axis, camera, light source,
shutter, power meter, lock-in amplifier, filter wheel, modulator); a device takes the most derived
kind it implements (a shutter is also a light source). For each, a :class:`DeviceKind`
says how to read the device's static information (once, after connecting or after a
setting changed) and its live values (on every poll), and how often to poll it. Every
function here calls the driver, so it runs on the thread that owns the bench (the device
worker), never on the GUI thread.

**Adding a kind**: write its ABC in ``drivers/base.py``, then register it here with
:func:`register_kind` — a name, the ABC, ``read_info`` and ``read_values`` functions and a
poll interval — and give it a panel in ``gui.qt.panels``
(``gui.qt.panels.register_panel`` with the same name). A driver of an existing kind
(a Zaber axis, another shutter) needs nothing: it is shown and commanded through its
kind. A device whose kind is not registered still appears, with its identity and an
"unknown kind" state.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from drivers.base import (
    AxisStatus,
    Camera,
    Device,
    FilterWheel,
    LightSource,
    LockIn,
    Modulator,
    MotionAxis,
    PixelFormat,
    PowerMeter,
    ReferenceSource,
    Shutter,
    ShutterState,
    WheelSpeed,
)
from drivers.errors import ConnectionFailed, DeviceError
from drivers.genicam_camera import GenICamCamera, TriggerMode

__all__ = [
    "AUTO_RANGE_TIMEOUT_S",
    "UNKNOWN_KIND",
    "DeviceKind",
    "DeviceState",
    "axis_status_values",
    "is_camera_kind",
    "kind_of",
    "kinds",
    "read_state",
    "register_kind",
    "state_from_message",
    "state_message",
]


@dataclass(frozen=True)
class DeviceKind:
    """How the GUI reads one kind of device.

    ``read_info(device)`` returns what changes only when a setting changes (units, limits,
    ranges, velocity); ``read_values(device)`` what a poll reads (position, reading, on/off).
    Both return plain values (numbers, strings, booleans, tuples) that other threads may
    read.
    """

    name: str
    title: str
    base: type
    read_info: Callable[[Any], dict[str, Any]]
    read_values: Callable[[Any], dict[str, Any]]
    poll_s: float = 0.1
    #: Public properties the operator may set (validated by the driver's setter).
    settings: tuple[str, ...] = ()
    #: Named operations without arguments beyond ``args`` (``name → fn(device, *args)``).
    actions: Mapping[str, Callable[..., Any]] = field(default_factory=dict)
    #: Actions that hold the device worker for seconds (a wheel's move, an auto-range):
    #: the session refuses them while an axis moves, so a stop never waits behind them.
    slow_actions: tuple[str, ...] = ()


@dataclass(frozen=True)
class DeviceState:
    """What the GUI shows of one device at one moment."""

    role: str
    kind: str
    connected: bool
    values: Mapping[str, Any] = field(default_factory=dict)
    info: Mapping[str, Any] = field(default_factory=dict)
    error: str | None = None
    t: float = field(default_factory=time.monotonic)

    def value(self, key: str, default: Any = None) -> Any:
        return self.values.get(key, default)


UNKNOWN_KIND = "unknown"
_KINDS: list[DeviceKind] = []


def register_kind(kind: DeviceKind) -> None:
    """Add a device kind (or replace the one of the same name)."""
    for k, old in enumerate(_KINDS):
        if old.name == kind.name:
            _KINDS[k] = kind
            return
    _KINDS.append(kind)


def kinds() -> list[DeviceKind]:
    return list(_KINDS)


def kind_of(device: Device) -> DeviceKind | None:
    """The registered kind whose ABC ``device`` implements; of several (a shutter is a light
    source), the most derived one."""
    matches = [kind for kind in _KINDS if isinstance(device, kind.base)]
    if not matches:
        return None
    mro = type(device).__mro__
    return min(matches, key=lambda kind: mro.index(kind.base))


def is_camera_kind(name: str) -> bool:
    """Whether the registered kind ``name`` is a camera (the camera view shows it)."""
    return any(k.name == name and issubclass(k.base, Camera) for k in _KINDS)


def identity_info(device: Device) -> dict[str, Any]:
    ident = device.identity
    out = {"vendor": ident.vendor, "model": ident.model, "serial": ident.serial,
           "firmware": ident.firmware}
    out.update({f"extra.{k}": v for k, v in ident.extra.items()})
    return out


def read_state(role: str, device: Device, *, with_info: bool,
               info: Mapping[str, Any] | None = None) -> DeviceState:
    """Read one device (on the thread that owns it). A :class:`DeviceError` becomes the
    state's ``error``; a lost connection also clears ``connected``."""
    kind = kind_of(device)
    name = kind.name if kind is not None else UNKNOWN_KIND
    base_info = dict(info or {})
    try:
        if with_info:
            base_info = {"identity": identity_info(device)}
            if kind is not None:
                base_info.update(kind.read_info(device))
        values = kind.read_values(device) if kind is not None else {}
    except ConnectionFailed as err:
        return DeviceState(role, name, False, {}, base_info, str(err))
    except (DeviceError, ValueError) as err:
        return DeviceState(role, name, not device.closed, {}, base_info, str(err))
    error = values.get("error") if isinstance(values.get("error"), str) else None
    return DeviceState(role, name, not device.closed, values, base_info, error)


def _plain(value: Any) -> Any:
    """``value`` as JSON can carry it: tuples as lists, keys as strings, NaN and ±inf as
    None (the event stream's JSON has no NaN), enums as their values."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, bool | int | float | str) or value is None:
        return value
    return _plain(getattr(value, "value", str(value)))


def state_message(state: DeviceState, read_at: float) -> dict[str, Any]:
    """One device's state as the bench server's ``devices`` message carries it (plain JSON
    values); ``read_at``: when it was read (unix seconds), so a client can say how old a
    state it shows is (a run reads only what it uses)."""
    return {"kind": state.kind, "connected": state.connected,
            "values": _plain(state.values), "info": _plain(state.info),
            "error": state.error, "read_at": read_at}


def state_from_message(role: str, data: Mapping[str, Any], now: float | None = None
                       ) -> DeviceState:
    """A :func:`state_message` back as a :class:`DeviceState` whose ``t`` is on this
    process's monotonic clock (its age as the server saw it, at least 0; ``now``: the
    wall clock)."""
    now = time.time() if now is None else now
    read_at = data.get("read_at")
    age = 0.0 if not isinstance(read_at, int | float) else max(0.0, now - read_at)
    return DeviceState(role, str(data.get("kind") or UNKNOWN_KIND),
                       bool(data.get("connected")), dict(data.get("values") or {}),
                       dict(data.get("info") or {}),
                       data.get("error") if isinstance(data.get("error"), str) else None,
                       time.monotonic() - age)


# --------------------------------------------------------------------------- the kinds


def _axis_info(axis: MotionAxis) -> dict[str, Any]:
    low, high = axis.soft_limits
    return {"units": axis.units, "limits": (low, high), "velocity": axis.velocity,
            "acceleration": axis.acceleration, "tolerance": axis.position_tolerance}


def axis_status_values(s: AxisStatus) -> dict[str, Any]:
    """An axis's live values from one status read (the device worker's poll, or the run
    engine's read-back while a run owns the bench)."""
    return {"position": s.position, "moving": s.is_moving or s.is_homing,
            "homed": s.is_homed, "homing": s.is_homing, "enabled": s.is_enabled,
            "at_limit": s.at_forward_limit or s.at_reverse_limit, "error": s.error}


def _axis_values(axis: MotionAxis) -> dict[str, Any]:
    return {**axis_status_values(axis.status()), "target": axis.target}


def _camera_info(cam: Camera) -> dict[str, Any]:
    h, w = cam.sensor_shape
    return {"sensor": (h, w), "bit_depth": cam.bit_depth,
            "exposure_range_us": tuple(cam.exposure_range_us),
            "gain_range": tuple(cam.gain_range)}


def _camera_values(cam: Camera) -> dict[str, Any]:
    return {"exposure_us": cam.exposure_us, "gain": cam.gain,
            "streaming": cam.is_streaming, "dropped": cam.dropped_frames}


def _source_info(src: LightSource) -> dict[str, Any]:
    rng = src.power_range_w
    return {"power_range_w": None if rng is None else tuple(rng)}


def _source_values(src: LightSource) -> dict[str, Any]:
    out: dict[str, Any] = {"on": src.is_on}
    if src.power_range_w is not None:
        try:
            out["power_w"] = src.power_w
        except DeviceError:
            out["power_w"] = math.nan
    return out


def _meter_info(pm: PowerMeter) -> dict[str, Any]:
    return {"wavelength_range_nm": tuple(pm.wavelength_range_nm)}


def _meter_values(pm: PowerMeter) -> dict[str, Any]:
    return {"power_w": pm.read_power_w(), "wavelength_nm": pm.wavelength_nm}


def _zero(pm: PowerMeter) -> None:
    pm.zero()


register_kind(DeviceKind("motion_axis", "Motion axis", MotionAxis, _axis_info, _axis_values,
                         poll_s=0.1, settings=("velocity", "acceleration")))
register_kind(DeviceKind("camera", "Camera", Camera, _camera_info, _camera_values,
                         poll_s=1.0, settings=("exposure_us", "gain")))
register_kind(DeviceKind("light_source", "Light source", LightSource, _source_info,
                         _source_values, poll_s=0.5, settings=("power_w",)))


# A GenICam camera (the Basler driver, ADR 0096) is a camera with more to set: its bit
# depth (pixel format), trigger mode and black level, within what its node map offers.


def _genicam_info(cam: GenICamCamera) -> dict[str, Any]:
    return {**_camera_info(cam),
            "bit_depths": tuple(f.bit_depth for f in cam.pixel_formats),
            "trigger_modes": tuple(m.value for m in TriggerMode),
            "hardware_line": cam.hardware_line,
            "black_level_range": tuple(cam.black_level_range)}


def _genicam_values(cam: GenICamCamera) -> dict[str, Any]:
    return {**_camera_values(cam), "bit_depth": cam.bit_depth,
            "trigger_mode": cam.trigger_mode.value, "black_level": cam.black_level}


def _set_bit_depth(cam: GenICamCamera, bits: Any) -> None:
    """Choose the mono pixel format of ``bits`` significant bits (8, 10, 12, 16)."""
    if isinstance(bits, bool) or not isinstance(bits, int | float) or bits != int(bits):
        raise TypeError(f"{cam.name}: a bit depth is an integer, got {bits!r}")
    try:
        fmt = PixelFormat(int(bits))
    except ValueError:
        raise ValueError(f"{cam.name}: no mono format of {bits} bits (8, 10, 12 or 16)"
                         ) from None
    cam.pixel_format = fmt  # the driver refuses a format the camera lacks, in its words


register_kind(DeviceKind("genicam_camera", "GenICam camera", GenICamCamera, _genicam_info,
                         _genicam_values, poll_s=1.0,
                         settings=("exposure_us", "gain", "trigger_mode", "black_level"),
                         actions={"set_bit_depth": _set_bit_depth}))


# The lock-in, the shutter and the filter wheel (issue 15). What their values mean and how
# they are written for the operator is gui.model.readouts; the profile's filter bands are
# gui.model.filters.

#: Longest auto-range the device worker runs (s): it holds the worker, so it is bounded,
#: and refused while an axis moves (``slow_actions``) so that it never delays a stop.
AUTO_RANGE_TIMEOUT_S = 20.0


def _lockin_info(li: LockIn) -> dict[str, Any]:
    return {"sensitivities_v": tuple(li.sensitivities_v),
            "time_constants_s": tuple(li.time_constants_s),
            "reference_sources": tuple(s.value for s in ReferenceSource),
            "filter_slope_db_per_oct": li.filter_slope_db_per_oct}


def _lockin_values(li: LockIn) -> dict[str, Any]:
    r = li.snapshot()
    flags = li.overload_status()  # latched since the last poll, cleared by reading
    return {"r_v": r.r_v, "theta_deg": r.theta_deg, "x_v": r.x_v, "y_v": r.y_v,
            "sensitivity_v": li.sensitivity_v, "time_constant_s": li.time_constant_s,
            "reference": li.reference_source.value,
            "frequency_hz": li.reference_frequency_hz, "overload": flags.overloaded,
            "input_overload": flags.input_overload, "filter_overload": flags.filter_overload,
            "output_overload": flags.output_overload,
            "reference_unlocked": flags.reference_unlocked}


def _auto_range(li: LockIn) -> None:
    li.auto_range(timeout=AUTO_RANGE_TIMEOUT_S)


def _shutter_values(shutter: Shutter) -> dict[str, Any]:
    state = shutter.shutter_state
    return {"state": state.value, "on": state is ShutterState.OPEN}


def _wheel_info(wheel: FilterWheel) -> dict[str, Any]:
    return {"count": wheel.position_count,
            "speeds": tuple(s.value for s in WheelSpeed),
            "filters": {slot: (spec.center_nm, spec.bandwidth_nm, spec.label,
                               getattr(spec, "od", None))
                        for slot, spec in wheel.filters.items()}}


def _wheel_values(wheel: FilterWheel) -> dict[str, Any]:
    return {"position": wheel.position, "speed": wheel.speed.value}


def _wheel_move(wheel: FilterWheel, slot: Any) -> None:
    if isinstance(slot, bool) or not isinstance(slot, int | float) or slot != int(slot):
        raise TypeError(f"{wheel.name}: a slot number is an integer, got {slot!r}")
    wheel.move_to(int(slot))  # the driver checks the slot against its count


register_kind(DeviceKind("lockin", "Lock-in amplifier", LockIn, _lockin_info,
                         _lockin_values, poll_s=0.5,
                         settings=("sensitivity_v", "time_constant_s", "reference_source"),
                         actions={"auto_range": _auto_range}, slow_actions=("auto_range",)))
# A shutter is a light source: the GUI opens and closes it as one (SetLight with its role),
# so that opening it passes the same beam check as turning a source on.
register_kind(DeviceKind("shutter", "Shutter", Shutter, lambda s: {}, _shutter_values,
                         poll_s=0.5))
register_kind(DeviceKind("filter_wheel", "Filter wheel", FilterWheel, _wheel_info,
                         _wheel_values, poll_s=0.5, settings=("speed",),
                         actions={"move_to": _wheel_move}, slow_actions=("move_to",)))
register_kind(DeviceKind("power_meter", "Power meter", PowerMeter, _meter_info,
                         _meter_values, poll_s=0.5,
                         settings=("wavelength_nm", "averaging", "auto_range"),
                         actions={"zero": _zero}))


def _modulator_info(pem: Modulator) -> dict[str, Any]:
    return {"wavelength_nm": pem.wavelength_nm}


def _modulator_values(pem: Modulator) -> dict[str, Any]:
    return {"retardation_waves": pem.retardation_waves, "frequency_hz": pem.frequency_hz}


# A photoelastic modulator: its amplitude (waves at the wavelength) and the frequency the
# lock-in takes as its reference.
register_kind(DeviceKind("modulator", "Photoelastic modulator", Modulator, _modulator_info,
                         _modulator_values, poll_s=1.0,
                         settings=("wavelength_nm", "retardation_waves")))
