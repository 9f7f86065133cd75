"""The groups a polarimetric run's readings form, and the optical-train look-ups that both
the dual-rotating-retarder and the PEM readers use (ADR 0103, ADR 0106): one module that
:mod:`~instrument.pipelines.polarimetry.readings` and
:mod:`~instrument.pipelines.polarimetry.pem_readings` import, so neither imports the other's
helpers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from analysis.polarimetry.pem import PemSetting
from instrument.run.runfile import RunData, RunFileError

__all__ = ["MOUNT_ROLES", "PemGroup", "StepGroup", "element_axis", "train_element"]

#: The mount roles a dual-rotating-retarder run moves (instrument.bench.optics).
MOUNT_ROLES = ("psg_polariser", "psg_retarder", "psa_retarder", "psa_polariser")


@dataclass(frozen=True)
class PemGroup:
    """One geometry's PEM readings: per point the DC, 1f and 2f (V; the lock-in's signed
    RMS in-phase outputs) with their σ, the setting as the mounts reached it, and the
    modulator's amplitude at the group's wavelength (rad)."""

    readings: np.ndarray
    sigmas: np.ndarray
    settings: tuple[PemSetting, ...]
    amplitude_rad: float


@dataclass(frozen=True)
class StepGroup:
    """The K steps of one geometry and wavelength.

    Angles in degrees. ``psg_retarder_deg`` etc. are the element axes: the profile's
    nominal ``orientation_deg`` plus the mount's read-back position. ``intensity`` is the
    meter's reading less its dark (W) and ``sigma`` its standard deviation.
    """

    theta_i: float
    phi_i: float
    theta_r: float
    phi_r: float
    wavelength_nm: float
    rows: np.ndarray
    step: np.ndarray
    psg_retarder_deg: np.ndarray
    psa_retarder_deg: np.ndarray
    psg_polariser_deg: float
    psa_polariser_deg: float
    intensity: np.ndarray
    sigma: np.ndarray
    #: A PEM run's group: its DC, 1f and 2f readings and settings (ADR 0106); ``None`` for a
    #: dual rotating retarder's. ``intensity``/``sigma`` then hold the DC channel.
    pem: PemGroup | None = None

    @property
    def transmitted(self) -> bool:
        """Taken straight through (θr ≥ 90°: the detector arm in the beam, a reference)."""
        return not (abs(self.theta_r) < 90.0 and abs(self.theta_i) < 90.0)

    def label(self) -> str:
        """``θi 50.0° θr 50.0°`` (with φr off the plane and λ when known)."""
        if self.transmitted:
            return "straight through" + (f" λ {self.wavelength_nm:.0f} nm" if
                                         math.isfinite(self.wavelength_nm) else "")
        text = f"θi {self.theta_i:.1f}° θr {self.theta_r:.1f}°"
        if abs(math.remainder(self.phi_r - self.phi_i, 360.0)) < 179.0:
            text += f" φr {self.phi_r:.1f}°"
        if math.isfinite(self.wavelength_nm):
            text += f" λ {self.wavelength_nm:.0f} nm"
        return text


def train_element(train: Mapping[str, Any], arm: str, kind: str) -> dict[str, Any]:
    """The optical train's element of ``kind`` in the arm (``psg`` source, ``psa``
    detector), as stored in the run file."""
    key = "source" if arm == "psg" else "detector"
    for el in train.get("optics", {}).get(key, []):
        if el.get("kind") == kind:
            return dict(el)
    raise RunFileError(f"the run's optical train has no {kind} in the "
                       f"{'source' if arm == 'psg' else 'detector'} arm: a dual rotating "
                       "retarder needs a polariser and a retarder in each arm")


def element_axis(run: RunData, train: Mapping[str, Any], role: str, arm: str, kind: str
                 ) -> np.ndarray:
    """Each point's axis of an element (deg): its nominal orientation plus its mount's
    read-back position (0 where the run did not move the mount)."""
    base = float(train_element(train, arm, kind).get("orientation_deg", 0.0))
    pos = run.position(role)
    return base + np.where(np.isfinite(pos), pos, 0.0)
