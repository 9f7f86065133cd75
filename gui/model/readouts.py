"""What the lock-in and shutter panels say, from a polled :class:`DeviceState` (Qt-free).

The values come from :mod:`instrument.bench.device_state` (read on the device worker, or
by the bench server); this module only turns them into the operator's words: the reading,
the instrument's range and time-constant tables as choices, and what an overload or a lost
reference means and what to do about it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from gui.model import format as fmt

__all__ = [
    "LockInFault",
    "choices",
    "lockin_detail",
    "lockin_faults",
    "lockin_reading",
    "nearest",
    "shutter_open",
]


@dataclass(frozen=True)
class LockInFault:
    """One latched flag of the lock-in: its badge and what the operator should do."""

    badge: str
    advice: str


#: Flag → (badge, advice). The SR830 manual (Rev. 2.5, pp. 5-20 to 5-23, the LIA status byte)
#: names the flags; the advice follows from what each one saturates.
_FLAGS: tuple[tuple[str, str, str], ...] = (
    ("input_overload", "INPUT OVERLOAD",
     "the input amplifier saturated: lower the detector's gain or the light"),
    ("output_overload", "OVERLOAD",
     "R exceeds the full scale: choose a larger range or press Auto-range"),
    ("filter_overload", "FILTER OVERLOAD",
     "the output filter saturated: choose a larger range"),
    ("reference_unlocked", "UNLOCKED",
     "no reference at REF IN: check that the chopper runs and its reference cable is in"),
)


def lockin_faults(values: Mapping[str, Any]) -> list[LockInFault]:
    """The flags latched since the previous poll, most serious first (empty: trustworthy)."""
    return [LockInFault(badge, advice) for key, badge, advice in _FLAGS if values.get(key)]


def lockin_reading(values: Mapping[str, Any]) -> str:
    """``"R 1.234 mV rms, θ 12.3°"`` (``—`` for what is not known)."""
    theta = values.get("theta_deg")
    angle = "—" if theta is None or not math.isfinite(theta) else f"{theta:.1f}°"
    return f"R {fmt.si(values.get('r_v'), 'V')} rms, θ {angle}"


def lockin_detail(values: Mapping[str, Any]) -> str:
    """``"X 1.2 mV, Y 0.1 mV; reference external, 137 Hz"``."""
    freq = values.get("frequency_hz")
    return (f"X {fmt.si(values.get('x_v'), 'V')}, Y {fmt.si(values.get('y_v'), 'V')}; "
            f"reference {values.get('reference', '?')}, {fmt.si(freq, 'Hz')}")


def choices(table: Sequence[float], unit: str) -> list[tuple[str, float]]:
    """A setting's table (the instrument's ranges or time constants) as (label, value)."""
    return [(fmt.si(v, unit, 3), float(v)) for v in table]


def nearest(table: Sequence[float], value: float | None, rtol: float = 1e-6) -> int | None:
    """Index of the table entry equal to ``value`` within ``rtol`` (None: not in the table)."""
    if value is None or not math.isfinite(value):
        return None
    for k, entry in enumerate(table):
        if math.isclose(entry, value, rel_tol=rtol):
            return k
    return None


def shutter_open(values: Mapping[str, Any]) -> bool | None:
    """Whether the blade is open (light reaches the sample); None while not known."""
    state = values.get("state")
    return None if state is None else state == "open"
