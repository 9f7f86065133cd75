"""Device settings a client changes through the server: what may be set, how a request is
checked, and how it is carried out (docs/decisions/0080, "Device settings").

The lock-in, filter wheel and power meter panels of the in-process window set these
through the device worker; a client of the server sends the same changes to
``POST /api/v1/bench/devices/{role}/settings``. A request names one device (by role) and
one or more fields; :func:`check_changes` judges every field before anything is sent to
the device, against the device's own tables (its ranges and time constants, slot count,
wavelength range) as the server last read them, and raises :class:`SettingRefused`
naming the first bad field. The service then applies the fields in the order given, on a
worker thread of its own (:meth:`~instrument.server.service.BenchService.device_settings`).

Fields by device kind:

* ``lockin``: ``sensitivity_v`` and ``time_constant_s`` (a value of the instrument's
  table), ``reference_source`` (``internal`` or ``external``), ``auto_range`` (``true``:
  slow, at most :data:`~instrument.bench.device_state.AUTO_RANGE_TIMEOUT_S`);
* ``filter_wheel``: ``position`` (a slot, 1 … count: slow, seconds), ``speed``;
* ``power_meter``: ``wavelength_nm`` (within the head's range), ``averaging`` (samples
  per reading), ``auto_range`` (true or false), ``zero`` (``true``: a dark zero, slow;
  block the light first).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from drivers.base import FilterWheel, LockIn, PowerMeter, ReferenceSource, WheelSpeed
from instrument.bench.device_state import AUTO_RANGE_TIMEOUT_S

__all__ = ["FIELDS", "SETTABLE_KINDS", "Change", "SettingField", "SettingRefused",
           "check_changes", "describe"]

#: Relative tolerance when a value is matched to an instrument's table (JSON round trip).
TABLE_RTOL = 1e-6


class SettingRefused(ValueError):
    """A change refused before anything was sent; ``field`` names it (``role.name``)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = f"{field}: {message}"


@dataclass(frozen=True)
class SettingField:
    """One settable field of a device kind. ``check(value, info)`` returns the value to
    apply or raises ValueError with a sentence; ``apply(device, value)`` calls the driver
    (which checks again, in its own words); ``slow``: it holds the device for seconds."""

    name: str
    check: Callable[[Any, Mapping[str, Any]], Any]
    apply: Callable[[Any, Any], None]
    slow: bool = False


@dataclass(frozen=True)
class Change:
    """A checked field and the value it is set to."""

    field: SettingField
    value: Any


def _number(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or \
            not math.isfinite(value):
        raise ValueError(f"expected a finite number, got {value!r}")
    return float(value)


def _integer(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float) or value != int(value):
        raise ValueError(f"expected an integer, got {value!r}")
    return int(value)


def _true(value: Any) -> bool:
    if value is not True:
        raise ValueError(f"an action: send true to run it, got {value!r}")
    return True


def _boolean(value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"expected true or false, got {value!r}")
    return value


def _one_of_table(key: str, unit: str) -> Callable[[Any, Mapping[str, Any]], float]:
    """A value of the instrument's table ``info[key]`` (the device's own list)."""
    def check(value: Any, info: Mapping[str, Any]) -> float:
        v = _number(value)
        table = [float(t) for t in info.get(key) or ()]
        for t in table:
            if math.isclose(v, t, rel_tol=TABLE_RTOL):
                return t
        if not table:
            return v  # tables not read yet: the driver judges it
        raise ValueError(f"{v:g} {unit} is not one of the instrument's values "
                         f"({table[0]:g} … {table[-1]:g} {unit}, {len(table)} steps)")
    return check


def _choice(values: Sequence[str]) -> Callable[[Any, Mapping[str, Any]], str]:
    def check(value: Any, info: Mapping[str, Any]) -> str:
        if not isinstance(value, str) or value not in values:
            raise ValueError(f"expected one of {', '.join(values)}, got {value!r}")
        return value
    return check


def _slot(value: Any, info: Mapping[str, Any]) -> int:
    slot = _integer(value)
    count = info.get("count")
    if isinstance(count, int) and not 1 <= slot <= count:
        raise ValueError(f"slot {slot} does not exist: the wheel has slots 1 … {count}")
    if slot < 1:
        raise ValueError(f"slot {slot} does not exist: slots count from 1")
    return slot


def _wavelength(value: Any, info: Mapping[str, Any]) -> float:
    v = _number(value)
    rng = info.get("wavelength_range_nm")
    if isinstance(rng, list | tuple) and len(rng) == 2 and not rng[0] <= v <= rng[1]:
        raise ValueError(f"{v:g} nm is outside the head's range {rng[0]:g} … {rng[1]:g} nm")
    return v


def _averaging(value: Any, info: Mapping[str, Any]) -> int:
    n = _integer(value)
    if n < 1:
        raise ValueError(f"at least 1 sample per reading, got {n}")
    return n


def _set(name: str) -> Callable[[Any, Any], None]:
    def apply(device: Any, value: Any) -> None:
        setattr(device, name, value)
    return apply


def _auto_range(li: LockIn, _value: Any) -> None:
    li.auto_range(timeout=AUTO_RANGE_TIMEOUT_S)


def _move(wheel: FilterWheel, slot: Any) -> None:
    wheel.move_to(int(slot))


def _zero(pm: PowerMeter, _value: Any) -> None:
    pm.zero()


def _fields(*fields: SettingField) -> dict[str, SettingField]:
    return {f.name: f for f in fields}


#: Settable fields by device kind (``instrument.bench.device_state`` names).
FIELDS: dict[str, dict[str, SettingField]] = {
    "lockin": _fields(
        SettingField("sensitivity_v", _one_of_table("sensitivities_v", "V"),
                     _set("sensitivity_v")),
        SettingField("time_constant_s", _one_of_table("time_constants_s", "s"),
                     _set("time_constant_s")),
        SettingField("reference_source", _choice([s.value for s in ReferenceSource]),
                     _set("reference_source")),
        SettingField("auto_range", lambda v, _i: _true(v), _auto_range, slow=True)),
    "filter_wheel": _fields(
        SettingField("position", _slot, _move, slow=True),
        SettingField("speed", _choice([s.value for s in WheelSpeed]), _set("speed"))),
    "power_meter": _fields(
        SettingField("wavelength_nm", _wavelength, _set("wavelength_nm")),
        SettingField("averaging", _averaging, _set("averaging")),
        SettingField("auto_range", lambda v, _i: _boolean(v), _set("auto_range")),
        SettingField("zero", lambda v, _i: _true(v), _zero, slow=True)),
}
#: The device kinds a client may set.
SETTABLE_KINDS = tuple(FIELDS)


def check_changes(role: str, kind: str, changes: Mapping[str, Any],
                  info: Mapping[str, Any]) -> list[Change]:
    """Every field of ``changes`` for device ``role`` of kind ``kind``, checked against its
    tables ``info`` (as the server read them; empty: the driver judges the values).

    Raises
    ------
    SettingRefused
        The first field that is unknown or whose value is refused, named ``role.field``.
    """
    fields = FIELDS.get(kind)
    if fields is None:
        raise SettingRefused(role, f"a {kind} has no settings a client may change (devices "
                             f"with settings: {', '.join(SETTABLE_KINDS)})")
    if not changes:
        raise SettingRefused(role, f"nothing to set: give one or more of "
                             f"{', '.join(fields)}")
    out = []
    for name, value in changes.items():
        f = fields.get(name)
        if f is None:
            raise SettingRefused(f"{role}.{name}", f"not a setting of a {kind} (settings: "
                                 f"{', '.join(fields)})")
        try:
            out.append(Change(f, f.check(value, info)))
        except ValueError as err:
            raise SettingRefused(f"{role}.{name}", str(err)) from err
    return out


def describe(changes: Sequence[Change]) -> str:
    """``sensitivity_v=0.001, auto_range`` for messages and the audit log (an action by
    its name alone)."""
    def one(c: Change) -> str:
        if c.value is True and c.field.slow:
            return c.field.name
        value = f"{c.value:g}" if isinstance(c.value, float) else str(c.value)
        return f"{c.field.name}={value}"
    return ", ".join(one(c) for c in changes)
