"""A polarimetric run's readings, grouped by geometry and wavelength (ADR 0103 layout).

A dual-rotating-retarder run stores, per point: the geometry (read-back angles), the
mounts' read-back angles as columns of ``entry/points/positions``, the step index k in
the planned point's meta (``drr_step``; ``filter`` on a wavelength axis), and the power
meter's reading with its own dark (``power_dark_w``). ``entry/instrument/optical_train``
holds the nominal optics and the plan's ``[polarimetry]`` table as JSON.

The points of one planned geometry (θi, φi, θr, φr) and one wavelength form a
:class:`StepGroup`: the K steps the reduction turns into one Mueller matrix. Grouping uses
the *planned* angles (read-back ones jitter within the stages' tolerance); each group's
geometry is the mean of its read-back angles.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from analysis.polarimetry.drr import generator_extinction
from instrument.bench.meter_noise import meter_noise
from instrument.pipelines.polarimetry.groups import (
    MOUNT_ROLES,
    PemGroup,
    StepGroup,
    element_axis,
    train_element,
)
from instrument.run.runfile import RunData, RunFileError, as_text, open_run, read_planned

__all__ = ["MOUNT_ROLES", "PemGroup", "PolarimetricRun", "StepGroup", "is_polarimetric",
           "read_polarimetric"]

@dataclass(frozen=True)
class PolarimetricRun:
    """A polarimetric run read for the reduction."""

    run: RunData
    train: dict[str, Any]
    polarimetry: dict[str, Any]
    groups: tuple[StepGroup, ...]
    noise_source: str

    def retardance_deg(self, arm: str, wavelength_nm: float) -> float:
        """Nominal retardance (degrees) of the arm's retarder at a wavelength."""
        el = train_element(self.train, arm, "retarder")
        return _interp(el, wavelength_nm)

    def extinction(self, arm: str) -> float:
        """Extinction of the arm's polariser that W takes: the datasheet value the run's
        optical train stores, for the generator lowered by the source's own polarisation
        (:func:`analysis.polarimetry.drr.generator_extinction`); 0 (ideal) for runs
        recorded before the field."""
        el = train_element(self.train, arm, "polariser")
        eps = float(el.get("extinction", 0.0))
        if arm == "psg":
            return generator_extinction(eps, float(el.get("source_dop", 0.0)))
        return eps


def is_polarimetric(path: str | Path) -> bool:
    """Whether the run file records an optical train (a polarimetric run, ADR 0103)."""
    with open_run(path) as f:
        return "entry" in f and "instrument" in f["entry"] and \
            "optical_train" in f["entry/instrument"]


def _interp(el: Mapping[str, Any], wavelength_nm: float) -> float:
    ys = [float(v) for v in el.get("retardance_deg", [])]
    xs = [float(v) for v in el.get("retardance_nm", [])]
    if not ys:
        raise RunFileError(f"the optical train's retarder on {el.get('mount')!r} has no "
                           "retardance_deg")
    if len(ys) == 1 or not math.isfinite(wavelength_nm):
        return ys[len(ys) // 2] if len(ys) > 1 else ys[0]
    return float(np.interp(wavelength_nm, xs, ys))


def _wavelength(run: RunData) -> np.ndarray:
    col = run.wavelength_nm
    if col is not None and np.any(np.isfinite(col)):
        return np.asarray(col, dtype=float)
    prof = run.profile()
    wl = prof.get("simulation", {}).get("source", {}).get("wavelength_nm")
    if wl is None:
        wl = prof.get("devices", {}).get("power_meter", {}).get("settings", {}).get(
            "wavelength_nm")
    return np.full(run.n_points, math.nan if wl is None else float(wl))


def read_polarimetric(path: str | Path, run: RunData | None = None) -> PolarimetricRun:
    """Read a polarimetric run and group its points (module docstring).

    Raises
    ------
    RunFileError
        Not a polarimetric run, an unknown mode, no readings of the mode's detector, or a
        mount's read-back column missing.
    """
    from instrument.run.runfile import read_run

    run = run or read_run(path)
    with open_run(path) as f:
        if "optical_train" not in f["entry/instrument"]:
            raise RunFileError(f"{path} is not a polarimetric run (no "
                               "entry/instrument/optical_train)")
        train = json.loads(as_text(f["entry/instrument/optical_train"][()]))
    pol = dict(train.get("polarimetry", {}))
    mode = pol.get("mode", "drr")
    if mode not in ("drr", "pem"):
        raise RunFileError(f"{path}: polarimetry mode {mode!r} is not reduced by this "
                           "version (only 'drr' and 'pem')")
    planned = read_planned(path)
    rows = np.flatnonzero((run.point_status == 0) & (run.label == "sample"))
    if rows.size == 0:
        raise ValueError(f"{path} holds no completed sample points")
    wl = _wavelength(run)
    keys, metas = _geometries(run, planned, rows, wl)
    if mode == "pem":
        from instrument.pipelines.polarimetry.pem_readings import pem_groups

        groups, source = pem_groups(path, run, train, keys, metas, wl)
    else:
        groups, source = _drr_groups(path, run, train, keys, metas, wl)
    groups.sort(key=lambda g: (g.wavelength_nm if math.isfinite(g.wavelength_nm) else 0.0,
                               g.theta_i, g.phi_r, g.theta_r))
    return PolarimetricRun(run=run, train=train, polarimetry=pol, groups=tuple(groups),
                           noise_source=source)


def _geometries(run: RunData, planned: Any, rows: np.ndarray, wl: np.ndarray
                ) -> tuple[dict[tuple[float, ...], list[int]], dict[int, dict[str, Any]]]:
    """The rows of each planned geometry and wavelength (module docstring), and each row's
    planned meta."""
    keys: dict[tuple[float, ...], list[int]] = {}
    metas: dict[int, dict[str, Any]] = {}
    for r in rows:
        k = int(run.index[r])
        # the point's meta is stored as a list of [key, value] pairs
        meta = dict(json.loads(planned.meta[k])) if k < len(planned.meta) and \
            planned.meta[k] else {}
        metas[int(r)] = meta
        ang = planned.angles[k] if k < len(planned.angles) else [
            run.theta_i[r], run.phi_i[r], run.theta_r[r], run.phi_r[r]]
        key = (*(round(float(a), 3) for a in ang), round(float(wl[r]), 1)
               if math.isfinite(wl[r]) else math.nan, float(meta.get("filter", -1)))
        keys.setdefault(key, []).append(int(r))
    return keys, metas


def _drr_groups(path: str | Path, run: RunData, train: dict[str, Any],
                keys: dict[tuple[float, ...], list[int]], metas: dict[int, dict[str, Any]],
                wl: np.ndarray) -> tuple[list[StepGroup], str]:
    missing = [r for r in ("psg_retarder", "psa_retarder") if r not in run.axes]
    if missing:
        raise RunFileError(f"{path} has no read-back angles of {missing}: the run did not "
                           "move the retarders")
    rows = np.array([r for members in keys.values() for r in members])
    power = np.asarray(run.power_w, dtype=float)
    dark = run.power_dark_w
    dark = np.zeros_like(power) if dark is None else np.nan_to_num(np.asarray(dark, float))
    if not np.all(np.isfinite(power[rows])):
        raise ValueError(f"{path} has no power-meter reading at every point: the "
                         "polarimetric reduction reads the power meter")
    noise = meter_noise(run.profile())
    floor = noise.floor_w or 0.0
    net = power - dark
    # a reading's noise and its own dark's floor (ADR 0103: a dark per point)
    sigma = np.hypot(noise.relative * np.abs(power), math.sqrt(2.0) * floor)
    if np.any(sigma[rows] <= 0):
        raise ValueError("the power meter's noise is unknown (no relative_noise or "
                         "noise_floor_w in the profile): the Mueller matrices need it")
    g_ret = element_axis(run, train, "psg_retarder", "psg", "retarder")
    a_ret = element_axis(run, train, "psa_retarder", "psa", "retarder")
    g_pol = element_axis(run, train, "psg_polariser", "psg", "polariser")
    a_pol = element_axis(run, train, "psa_polariser", "psa", "polariser")
    steps = np.full(run.n_points, -1)
    for r, meta in metas.items():
        steps[r] = int(meta.get("drr_step", -1))
    groups = []
    for members in keys.values():
        idx = np.array(sorted(members, key=lambda r: (steps[r], r)))
        groups.append(StepGroup(
            theta_i=float(np.mean(run.theta_i[idx])), phi_i=float(np.mean(run.phi_i[idx])),
            theta_r=float(np.mean(run.theta_r[idx])), phi_r=float(np.mean(run.phi_r[idx])),
            wavelength_nm=float(np.mean(wl[idx])), rows=idx, step=steps[idx],
            psg_retarder_deg=g_ret[idx], psa_retarder_deg=a_ret[idx],
            psg_polariser_deg=float(np.mean(g_pol[idx])),
            psa_polariser_deg=float(np.mean(a_pol[idx])),
            intensity=net[idx], sigma=sigma[idx]))
    return groups, noise.source
