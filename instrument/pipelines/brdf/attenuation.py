"""Neutral-density filters in the beam: their transmissions, and dividing them out.

When the camera clips at its shortest exposure the engine reads the point again through the
next denser neutral-density filter of the wheel and records its slot per point
(``nd_position``; ADR 0018). A reading taken through a filter of transmission T is the
open-beam reading times T, so the reduction divides it by T. T comes, in order of
preference, from

1. an ND calibration run (``--nd-calibration RUN`` or the plan's ``[calibration] nd``):
   the same geometry read through the open slot and through each filter, T the ratio of
   the dark-subtracted signals (:func:`calibrate_nd`);
2. the bench profile's ``transmission`` and ``u_transmission`` of the filter (a maker's
   certificate);
3. the nominal 10^−od, with :data:`NOMINAL_U_REL` relative uncertainty and a warning.

The error of a calibrated T is the same for every point read through that filter: it is
carried as a covariance between those points (relative (u_T/T)² between any two of them),
as a dark read once for several points is (GUM, JCGM 100:2008, §5.2: correlated input
quantities), and propagated into the parameters after the fit. The fit itself weighs
points by their independent σ, which is right only while u_T is small beside the step a
wrong T would put between open and filtered points. A nominal T (several per cent off) is
not: its error enters each filtered point's independent σ instead, so that an
uncalibrated filter weakens the peak's points rather than biasing the fit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from analysis.brdf.reduction import camera_signal
from instrument.run.runfile import RunData, read_run

__all__ = ["NOMINAL_U_REL", "Transmission", "apply_nd", "calibrate_nd",
           "calibration_run_path", "nd_filters", "nd_slots", "nd_transmissions"]

#: Relative standard uncertainty assumed for an uncalibrated filter's nominal 10^−od
#: (absorptive ND glass is sold within several per cent of nominal at one wavelength).
NOMINAL_U_REL = 0.10
#: Relative uncertainty a ratio of two camera readings at different exposures and signal
#: levels carries beyond their noise: the camera's linearity error (EMVA 1288 R3.1 §6.5).
#: The simulated camera's readings agree to 3.5·10⁻⁴ between 31 µs and 16 ms
#: (BENCHMARKS.md, nd_filters); a real camera's datasheet value replaces it.
LINEARITY_REL = 5e-4


@dataclass(frozen=True)
class Transmission:
    """A filter's transmission ``value`` ± ``u`` (standard uncertainty), and whence."""

    slot: int
    value: float
    u: float
    source: str
    label: str = ""
    #: measured (calibration run or certificate): its error is shared between the points
    calibrated: bool = True

    def describe(self) -> str:
        name = f"slot {self.slot}" + (f" ({self.label})" if self.label else "")
        return f"{name}: T = {self.value:.5g} ± {self.u:.2g} ({self.source})"


def nd_filters(run: RunData) -> dict[int, dict[str, Any]]:
    """Slot → the profile's table of each neutral-density filter (``od`` given) of the
    run's filter wheel (empty without one)."""
    for dev in dict(run.profile().get("devices", {})).values():
        if isinstance(dev, Mapping) and dev.get("driver") == "fw102c":
            filters = dict(dict(dev.get("options", {})).get("filters", {}))
            return {int(k): dict(v) for k, v in filters.items()
                    if isinstance(v, Mapping) and "od" in v}
    return {}


def nd_slots(run: RunData, rows: np.ndarray) -> np.ndarray:
    """The ND filter's slot of each row (-1: open beam; a file without the column: all
    open)."""
    col = run.nd_position
    if col is None:
        return np.full(rows.size, -1, dtype=np.int64)
    return cast(np.ndarray, np.asarray(col)[rows].astype(np.int64))  # numpy's stubs: Any


def calibration_run_path(run: RunData, src: str) -> Path:
    """A calibration run named by path, or by run id (or name) next to ``run``'s file."""
    path = Path(src)
    if not path.is_absolute() and not path.exists():
        path = run.path.parent / src
        if not path.suffix:
            path = path.with_suffix(".h5")
    return path


def _resolve(run: RunData, src: str) -> Path:
    path = calibration_run_path(run, src)
    if not path.exists():
        raise ValueError(f"ND calibration run {src!r} not found (looked for {path})")
    return path


def nd_transmissions(run: RunData, calibration: str | Path | None = None,
                     camera_calibration: str | None = None
                     ) -> tuple[dict[int, Transmission], list[str]]:
    """Each ND filter's transmission for ``run`` (module docstring) and the warnings for
    filters the run used without a calibration."""
    specs = nd_filters(run)
    src = calibration or run.calibration.get("nd")
    measured = (calibrate_nd(_resolve(run, str(src)), camera_calibration=camera_calibration)
                if src else {})
    used = set(nd_slots(run, run.brdf_rows()).tolist()) - {-1}
    out: dict[int, Transmission] = {}
    warnings = []
    for slot, spec in specs.items():
        label = str(spec.get("label", ""))
        if slot in measured:
            out[slot] = measured[slot]
        elif "transmission" in spec and "u_transmission" in spec:
            out[slot] = Transmission(slot, float(spec["transmission"]),
                                     float(spec["u_transmission"]), "bench profile", label)
        else:
            t = 10.0 ** -float(spec["od"])
            out[slot] = Transmission(slot, t, NOMINAL_U_REL * t,
                                     f"nominal od {float(spec['od']):g}", label,
                                     calibrated=False)
            if slot in used:
                warnings.append(
                    f"ND filter in slot {slot}{' (' + label + ')' if label else ''} not "
                    f"calibrated: its nominal transmission {t:.4g} is taken with "
                    f"{NOMINAL_U_REL:.0%} uncertainty in each of its points' σ (the peak "
                    "weighs little in the fit); run examples/calibration_nd.toml and give it "
                    "with --nd-calibration RUN")
    missing = sorted(used - set(out))
    if missing:
        raise ValueError(f"{run.path}: points were read through filter slot(s) {missing}, "
                         "which the run's bench profile does not describe as neutral-density "
                         "filters (give od in the filter wheel's options.filters)")
    return out, warnings


def apply_nd(power: np.ndarray, u_power: np.ndarray, slots: np.ndarray,
             table: Mapping[int, Transmission]
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Readings through filters divided by their transmission: the readings, their σ
    (independent part; with an uncalibrated filter's error) and the relative covariance
    the shared error of each calibrated filter's T adds (None when no row was read through
    a calibrated filter)."""
    power = np.asarray(power, dtype=float).copy()
    u_power = np.asarray(u_power, dtype=float).copy()
    behind = slots >= 0
    if not behind.any():
        return power, u_power, None
    rel = np.zeros(slots.size)
    for slot in np.unique(slots[behind]):
        t = table[int(slot)]
        rows = slots == slot
        power[rows] /= t.value
        u_power[rows] /= t.value
        if t.calibrated:
            rel[rows] = t.u / t.value
        else:
            u_power[rows] = np.hypot(u_power[rows], power[rows] * t.u / t.value)
    shared = rel > 0
    if not shared.any():
        return power, u_power, None
    same = (slots[:, None] == slots[None, :]) & shared[:, None]
    return power, u_power, np.where(same, np.outer(rel, rel), 0.0)


def calibrate_nd(path: str | Path, *, camera_calibration: str | None = None
                 ) -> dict[int, Transmission]:
    """The ND filters' transmissions from a calibration run (``examples/calibration_nd.toml``):
    at each geometry, T = S_filter / S_open, the camera's dark-subtracted signal rates
    (:func:`analysis.brdf.reduction.camera_signal`) through the filter and through the open
    slot, with u from both signals' σ and the camera's linearity (:data:`LINEARITY_REL`,
    shared by every ratio of a filter); several geometries or repeats are combined by
    their inverse-variance weighted mean, its σ scaled up by the Birge ratio √(χ²/dof)
    when they scatter more than their σ say (Birge 1932, Phys. Rev. 40, 207).

    Raises
    ------
    ValueError
        A run without open-slot readings, a filter never read at a geometry that has an
        open reading, or a reading clipped at its shortest exposure.
    """
    run = read_run(path)
    cal = run.camera_calibration(camera_calibration)
    specs = nd_filters(run)
    rows = run.brdf_rows()
    pos = run.filter_position
    if pos is None or not specs:
        raise ValueError(f"{path}: not an ND calibration run (no filter wheel with "
                         "neutral-density filters, or no filter slot per point)")
    n_avg = int(run.acquisition.get("frames", 1))
    open_by_geo: dict[tuple[float, float], list[tuple[float, float]]] = {}
    nd_by_geo: dict[tuple[int, tuple[float, float]], list[tuple[float, float]]] = {}
    for r in rows:
        light, exp, dark = run.frames_of(int(r))
        if dark is None:
            raise ValueError(f"{path}: point {run.index[r]} has no dark frames")
        s = camera_signal(light, exp, dark, noise=cal.noise, n_averaged=n_avg)
        if s.clipped_pixels:
            raise ValueError(f"{path}: point {run.index[r]} clipped at its shortest exposure; "
                             "choose a geometry where the open beam does not saturate")
        geo = (round(float(run.theta_i[r]), 2), round(float(run.theta_r[r]), 2))
        slot = int(pos[r])
        reading = (s.rate_dn_per_us, s.sigma)
        if slot in specs:
            nd_by_geo.setdefault((slot, geo), []).append(reading)
        else:
            open_by_geo.setdefault(geo, []).append(reading)
    if not open_by_geo:
        raise ValueError(f"{path}: no reading through the open slot to compare with")
    out = {}
    for slot, spec in sorted(specs.items()):
        ratios, sig = [], []
        for (s_slot, geo), readings in nd_by_geo.items():
            if s_slot != slot or geo not in open_by_geo:
                continue
            o, uo = _mean(open_by_geo[geo])
            f, uf = _mean(readings)
            ratios.append(f / o)
            sig.append(f / o * math.hypot(uf / f, uo / o))
        if not ratios:
            continue
        w = 1.0 / np.square(sig)
        t = float(np.sum(w * ratios) / np.sum(w))
        u = float(1.0 / math.sqrt(np.sum(w)))
        if len(ratios) > 1:
            birge = math.sqrt(float(np.sum(w * np.square(np.array(ratios) - t)))
                              / (len(ratios) - 1))
            u *= max(1.0, birge)
        u = math.hypot(u, LINEARITY_REL * t)
        out[slot] = Transmission(slot, t, u, f"calibration run {run.run_id}",
                                 str(spec.get("label", "")))
    return out


def _mean(readings: list[tuple[float, float]]) -> tuple[float, float]:
    """Inverse-variance mean of (value, σ) readings and its σ."""
    v = np.array([x for x, _ in readings])
    s = np.array([u for _, u in readings])
    w = 1.0 / np.square(s)
    return float(np.sum(w * v) / np.sum(w)), float(1.0 / math.sqrt(np.sum(w)))
