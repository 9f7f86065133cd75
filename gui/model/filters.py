"""The bands of a filter wheel's slots, as the GUI shows them (Qt-free, no driver calls).

Two places may describe the filters of a wheel:

* the driver's own configuration (``[devices.<role>] options = { filters = { 2 = {
  center_nm = 550.0, bandwidth_nm = 10.0 } } }``), which the engine uses; the device worker
  reads it with the wheel's info (``info["filters"]``: slot → (centre, FWHM, label));
* a list of tables in the profile, ``[[filter_wheel.filters]]`` (or
  ``[[devices.<role>.filters]]``) with ``position``, ``centre_nm`` (or ``center_nm``),
  ``bandwidth_nm`` and an optional ``label``.

The GUI only *shows* bands, so the profile's list is read defensively from the profile's
TOML text: an entry that is not a table, has no integer position or no positive finite
centre is skipped and reported, never raised. Where both describe a slot, the driver's
configuration wins: it is what a run records.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["FilterBand", "bands_from_info", "bands_from_profile", "merge_bands", "slot_label"]


@dataclass(frozen=True)
class FilterBand:
    """One slot's filter: centre and full width at half maximum in nm (None: empty slot),
    or a neutral-density filter's optical density ``od`` (ADR 0018)."""

    slot: int
    centre_nm: float | None = None
    bandwidth_nm: float | None = None
    label: str = ""
    od: float | None = None


def bands_from_info(filters: Mapping[Any, Any] | None) -> dict[int, FilterBand]:
    """The wheel info's ``filters`` (slot → (centre, FWHM, label[, od])) as bands."""
    out: dict[int, FilterBand] = {}
    for slot, spec in (filters or {}).items():
        items = tuple(spec)
        centre, width, label, od = (*items, *(None, None, "", None)[len(items):])[:4]
        out[int(slot)] = FilterBand(int(slot), centre, width, str(label or ""), od)
    return out


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    value = float(value)
    return value if math.isfinite(value) and value > 0 else None


def _parse_entry(entry: Any) -> FilterBand | str:
    """A band from one ``[[...filters]]`` table, or the reason it was skipped."""
    if not isinstance(entry, Mapping):
        return f"not a table: {entry!r}"
    slot = entry.get("position", entry.get("slot"))
    if isinstance(slot, bool) or not isinstance(slot, int) or slot < 1:
        return f"no slot number (position = 1, 2, …): {dict(entry)!r}"
    centre = _number(entry.get("centre_nm", entry.get("center_nm")))
    if centre is None:
        return f"slot {slot}: no positive centre_nm"
    width = _number(entry.get("bandwidth_nm"))
    label = entry.get("label", "")
    return FilterBand(slot, centre, width, label if isinstance(label, str) else str(label))


def bands_from_profile(source_text: str | None, role: str
                       ) -> tuple[dict[int, FilterBand], list[str]]:
    """The bands a profile's ``[[filter_wheel.filters]]`` (or ``[[devices.<role>.filters]]``)
    lists, and what was skipped (one line each). Never raises."""
    if not source_text:
        return {}, []
    try:
        doc = tomllib.loads(source_text)
    except tomllib.TOMLDecodeError as err:
        return {}, [f"profile not readable: {err}"]
    entries: list[Any] = []
    for table in (doc.get("filter_wheel"), doc.get("devices", {}).get(role)):
        if isinstance(table, Mapping) and isinstance(table.get("filters"), list):
            entries.extend(table["filters"])
    bands: dict[int, FilterBand] = {}
    skipped: list[str] = []
    for entry in entries:
        parsed = _parse_entry(entry)
        if isinstance(parsed, str):
            skipped.append(parsed)
        elif parsed.slot in bands:
            skipped.append(f"slot {parsed.slot} listed twice: the first is kept")
        else:
            bands[parsed.slot] = parsed
    return bands, skipped


def merge_bands(driver: Mapping[int, FilterBand], profile: Mapping[int, FilterBand]
                ) -> dict[int, FilterBand]:
    """The driver's configured bands, the profile's list for the slots it does not know."""
    out = dict(profile)
    out.update({slot: band for slot, band in driver.items()
                if band.centre_nm is not None or band.od is not None})
    return out


def slot_label(bands: Mapping[int, FilterBand], slot: int | None) -> str:
    """``"slot 2: 550 nm, FWHM 10 nm (green)"``, ``"slot 3: ND, OD 1 (ND1)"``,
    ``"slot 4: empty"``; ``"—"`` unknown."""
    if slot is None:
        return "—"
    band = bands.get(slot)
    if band is not None and band.od is not None:
        what = f"ND, OD {band.od:g}"
    elif band is None or band.centre_nm is None:
        what = "empty"
    elif band.bandwidth_nm is None:
        what = f"{band.centre_nm:g} nm"
    else:
        what = f"{band.centre_nm:g} nm, FWHM {band.bandwidth_nm:g} nm"
    label = f" ({band.label})" if band is not None and band.label else ""
    return f"slot {slot}: {what}{label}"
