"""Numbers as an operator reads them (Qt-free): SI prefixes, durations, positions."""

from __future__ import annotations

import math

__all__ = ["STALE_AFTER_S", "age", "duration", "position", "si"]

_PREFIXES = [(1e-15, "f"), (1e-12, "p"), (1e-9, "n"), (1e-6, "µ"), (1e-3, "m"), (1.0, ""),
             (1e3, "k"), (1e6, "M"), (1e9, "G")]


def si(value: float | None, unit: str, digits: int = 4) -> str:
    """``0.0012345, "W"`` → ``"1.234 mW"``; NaN or None → ``"—"``."""
    if value is None or not math.isfinite(value):
        return "—"
    if value == 0:
        return f"0 {unit}"
    mag = abs(value)
    scale, prefix = _PREFIXES[0]
    for s, p in _PREFIXES:
        if mag >= s * 0.9995:
            scale, prefix = s, p
    return f"{value / scale:.{digits}g} {prefix}{unit}"


def duration(seconds: float | None) -> str:
    """``75.0`` → ``"1 min 15 s"``; NaN or None → ``"—"``."""
    if seconds is None or not math.isfinite(seconds):
        return "—"
    s = max(0.0, float(seconds))
    if s < 10:
        return f"{s:.1f} s"
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        minutes, sec = divmod(round(s), 60)
        return f"{minutes} min {sec:02d} s"
    hours, minutes = divmod(round(s / 60), 60)
    return f"{hours} h {minutes:02d} min"


def position(value: float | None, units: str) -> str:
    """An axis position with the precision its units need (deg: 3 decimals, mm: 4)."""
    if value is None or not math.isfinite(value):
        return "—"
    decimals = 4 if units == "mm" else 3
    return f"{value:.{decimals}f} {units}"


#: A reading older than this (s) is shown with its age: the device worker polls every
#: device at least once a second, so an older one is not being refreshed (a run owns the
#: bench and does not read this device, or the worker is busy).
STALE_AFTER_S = 2.0


def age(seconds: float | None) -> str:
    """``""`` for a fresh reading, else ``"read 12 s ago"`` (NaN/None: ``"not read"``)."""
    if seconds is None or not math.isfinite(seconds):
        return "not read"
    if seconds < STALE_AFTER_S:
        return ""
    return f"read {duration(seconds)} ago"
