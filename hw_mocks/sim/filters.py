"""Band-pass filters on the virtual bench: what a filter-wheel slot does to the source's light.

A filter is modelled as a flat-top pass band: transmission ``peak_transmission`` from
``center_nm - bandwidth_nm/2`` to ``center_nm + bandwidth_nm/2`` (the FWHM taken as the
full width of the top hat) and ``blocking`` outside. Real interference filters have sloped
edges and a finite optical density; the flat top is enough to make the light at the sample
follow the selected filter.

A neutral-density filter (:class:`NeutralDensity`) passes every wavelength with the same
``transmission``: the slot's true value, hidden from the instrument, which knows only the
nominal optical density of the profile and what its calibration plan measures.

The source's spectrum is equally simple: a line at ``wavelength_nm`` when its
``bandwidth_nm`` is 0 (a laser), otherwise a flat band of that full width around
``wavelength_nm`` with uniform spectral power. :func:`transmit` returns the light after
the filter: its power, and the centre and width of the band that passes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Protocol, TypeVar

__all__ = ["FilterBand", "Light", "NeutralDensity", "parse_bands", "transmit"]


class Light(Protocol):
    """What :func:`transmit` needs of the light (a frozen dataclass such as
    :class:`hw_mocks.sim.state.SourceState`)."""

    power_w: float
    wavelength_nm: float
    bandwidth_nm: float


L = TypeVar("L", bound=Light)


@dataclass(frozen=True)
class FilterBand:
    """A flat-top band-pass filter (wavelengths in nm, transmissions in [0, 1])."""

    center_nm: float
    bandwidth_nm: float
    peak_transmission: float = 1.0
    blocking: float = 0.0

    def __post_init__(self) -> None:
        for what, value in (("center_nm", self.center_nm), ("bandwidth_nm", self.bandwidth_nm)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"filter {what} must be a finite number > 0, got {value}")
        if not 0.0 <= self.blocking <= self.peak_transmission <= 1.0:
            raise ValueError("need 0 <= blocking <= peak_transmission <= 1, got "
                             f"{self.blocking}, {self.peak_transmission}")

    @property
    def edges_nm(self) -> tuple[float, float]:
        half = 0.5 * self.bandwidth_nm
        return self.center_nm - half, self.center_nm + half


@dataclass(frozen=True)
class NeutralDensity:
    """A neutral-density filter: the same ``transmission`` (0, 1] at every wavelength."""

    transmission: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.transmission) and 0.0 < self.transmission <= 1.0):
            raise ValueError("a neutral-density filter's transmission must be in (0, 1], "
                             f"got {self.transmission}")


def transmit(source: L, band: FilterBand | NeutralDensity | None) -> L:
    """The light after ``band`` (``None``: an empty slot, everything passes)."""
    if band is None:
        return source
    if isinstance(band, NeutralDensity):
        return replace(source, power_w=source.power_w * band.transmission)
    low, high = band.edges_nm
    if source.bandwidth_nm <= 0.0:  # a line: in the band or blocked
        inside = low <= source.wavelength_nm <= high
        t = band.peak_transmission if inside else band.blocking
        return replace(source, power_w=source.power_w * t)
    half = 0.5 * source.bandwidth_nm
    lo = max(low, source.wavelength_nm - half)
    hi = min(high, source.wavelength_nm + half)
    passed = max(hi - lo, 0.0)
    fraction = passed / source.bandwidth_nm
    t = band.peak_transmission * fraction + band.blocking * (1.0 - fraction)
    if passed > 0.0:
        return replace(source, power_w=source.power_w * t, wavelength_nm=0.5 * (lo + hi),
                       bandwidth_nm=passed)
    return replace(source, power_w=source.power_w * t)


def parse_bands(filters: Mapping[Any, Any] | None
                ) -> dict[int, FilterBand | NeutralDensity]:
    """Slot (1-based; TOML gives string keys) → :class:`FilterBand` from plain tables
    ``{center_nm, bandwidth_nm[, peak_transmission, blocking]}``, :class:`NeutralDensity`
    from ``{transmission}``; empty tables are clear."""
    out: dict[int, FilterBand | NeutralDensity] = {}
    for key, spec in (filters or {}).items():
        try:
            slot = int(key)
        except (TypeError, ValueError):
            raise ValueError(f"filter slots are numbered from 1, got {key!r}") from None
        if slot < 1:
            raise ValueError(f"filter slots are numbered from 1, got {key!r}")
        if isinstance(spec, FilterBand | NeutralDensity):
            out[slot] = spec
            continue
        if not isinstance(spec, Mapping):
            raise TypeError(f"filter {slot}: expected a table, got {spec!r}")
        table = {k: v for k, v in spec.items() if k != "label"}
        if not table:
            continue  # an empty slot
        if set(table) == {"transmission"}:
            out[slot] = NeutralDensity(float(table["transmission"]))
            continue
        known = {"center_nm", "bandwidth_nm", "peak_transmission", "blocking"}
        # (a neutral-density filter is {transmission} alone)
        unknown = set(table) - known
        if unknown:
            raise ValueError(f"filter {slot}: unknown keys {sorted(unknown)}; known "
                             f"{sorted(known)}")
        out[slot] = FilterBand(**{k: float(v) for k, v in table.items()})
    return out
