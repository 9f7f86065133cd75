"""A PEM run's readings, grouped by geometry and wavelength (ADR 0106 layout).

Per point the run file holds the photodiode's DC on the lock-in's Aux In 1 (``pem_dc_v``),
the in-phase 1f and 2f outputs (``pem_1f_v``, ``pem_2f_v``, signed V rms) with their σ
(``pem_u_*``), the modulator's amplitude (rad at its wavelength setting
``pem_wavelength_nm``), the mounts' read-back angles in ``entry/points/positions`` and the
setting index ``pem_setting`` in the planned meta. A group's settings are the element axes
the mounts reached (each element's nominal ``orientation_deg`` plus its mount's read-back:
an ELL14 stops on whole pulses), the modulator's axis its nominal orientation, and its
amplitude at the group's wavelength ``A(λ) = A(λ_PEM) · λ_PEM / λ`` (the drive fixes a
retardation in nm).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from analysis.brdf.reduction.lockin import pooled_reading_sigma
from analysis.polarimetry.pem import PemSetting
from instrument.pipelines.polarimetry.groups import (
    PemGroup,
    StepGroup,
    element_axis,
    train_element,
)
from instrument.plans.polarimetry_pem import DEFAULT_READS
from instrument.run.pem_reading import OUTPUT_FLOOR
from instrument.run.runfile import RunData, RunFileError

__all__ = ["pem_groups"]

#: The per-point columns a PEM group needs.
_CHANNELS = (("pem_dc_v", "pem_u_dc_v"), ("pem_1f_v", "pem_u_1f_v"), ("pem_2f_v", "pem_u_2f_v"))


def _column(run: RunData, name: str) -> np.ndarray:
    col = run.detectors.get(name)
    return np.full(run.n_points, math.nan) if col is None else np.asarray(col, dtype=float)


def pem_groups(path: str | Path, run: RunData, train: Mapping[str, Any],
               keys: Mapping[tuple[float, ...], list[int]],
               metas: Mapping[int, Mapping[str, Any]], wl: np.ndarray
               ) -> tuple[list[StepGroup], str]:
    """The groups of a PEM run, and where their σ came from.

    Raises
    ------
    RunFileError
        The train has no PEM, no polariser before it or no analyser retarder, or a point
        lacks its readings, σ, amplitude or setting index.
    """
    pem = train_element(train, "psg", "pem")
    for role in ("psg_polariser", "psa_retarder"):
        if role not in run.axes:
            raise RunFileError(f"{path} has no read-back angles of {role!r}: the run did "
                               "not set the PEM polarimeter's mounts")
    y = np.stack([_column(run, v) for v, _ in _CHANNELS], axis=1)
    s = np.stack([_column(run, u) for _, u in _CHANNELS], axis=1)
    amp, amp_nm = _column(run, "pem_amplitude_rad"), _column(run, "pem_wavelength_nm")
    rows = np.array([r for members in keys.values() for r in members])
    bad = ~(np.all(np.isfinite(y[rows]), axis=1) & np.all(s[rows] > 0, axis=1)
            & np.isfinite(amp[rows]))
    if bad.any():
        raise RunFileError(f"{path}: {int(bad.sum())} PEM point(s) lack their DC/1f/2f "
                           "readings, σ or the modulator's amplitude (pem_* columns)")
    # 1f and 2f: σ from the run's lock-in noise model (var of a snapshot = a + b·level,
    # fitted to every point's spread, ADR 0053) rather than each point's own spread of a
    # few snapshots, itself uncertain by 1/√(2(n−1)); never below the outputs' floor. The
    # level is the DC, not |X|: the noise at 1f and 2f is the amplifier's (a) and the shot
    # noise of the whole photocurrent (∝ DC), which does not vanish where the harmonic
    # does (the 45° generator setting, whose 1f and 2f are ~0 under full light)
    reads = int(train.get("polarimetry", {}).get("reads", DEFAULT_READS))
    for col, harmonic in ((1, 1), (2, 2)):
        floor = OUTPUT_FLOOR * _column(run, f"pem_{harmonic}f_sensitivity_v")[rows]
        pooled, _, _ = pooled_reading_sigma(y[rows, 0], s[rows, col], reads)
        s[rows, col] = np.maximum(pooled, np.nan_to_num(floor))
    g_pol = element_axis(run, train, "psg_polariser", "psg", "polariser")
    a_ret = element_axis(run, train, "psa_retarder", "psa", "retarder")
    try:
        a_pol = element_axis(run, train, "psa_polariser", "psa", "polariser")
    except RunFileError:  # an analyser without its own polariser element (a fixed one)
        a_pol = np.zeros(run.n_points)
    pem_axis = float(pem.get("orientation_deg", 45.0))
    groups = []
    for members in keys.values():
        if any("pem_setting" not in metas[r] for r in members):
            raise RunFileError(f"{path}: a point lacks its pem_setting (planned meta)")
        idx = np.array(sorted(members, key=lambda r: (int(metas[r]["pem_setting"]), r)))
        lam = float(np.mean(wl[idx]))
        ratio = np.where(np.isfinite(amp_nm[idx]) & math.isfinite(lam), amp_nm[idx] / lam, 1.0)
        amplitude = float(np.mean(amp[idx] * ratio))
        settings = tuple(PemSetting(float(g_pol[r]), float(a_ret[r]), pem_axis, float(a_pol[r]))
                         for r in idx)
        groups.append(StepGroup(
            theta_i=float(np.mean(run.theta_i[idx])), phi_i=float(np.mean(run.phi_i[idx])),
            theta_r=float(np.mean(run.theta_r[idx])), phi_r=float(np.mean(run.phi_r[idx])),
            wavelength_nm=lam, rows=idx,
            step=np.array([int(metas[r]["pem_setting"]) for r in idx]),
            psg_retarder_deg=np.full(idx.size, math.nan), psa_retarder_deg=a_ret[idx],
            psg_polariser_deg=math.nan, psa_polariser_deg=float(np.mean(a_pol[idx])),
            intensity=y[idx, 0], sigma=s[idx, 0],
            pem=PemGroup(readings=y[idx], sigmas=s[idx], settings=settings,
                         amplitude_rad=amplitude)))
    return groups, ("the lock-in: each harmonic's noise model in the DC fitted to the run's "
                    "snapshot spreads (at least 1e-5 of its full scale); the DC's spread with "
                    "the Aux In's quantisation")
