"""Synthetic polarimeter data for the polarimetry tests (seeded, noise stated)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from analysis.polarimetry import drr_angles, instrument_matrix

QWP = math.pi / 2


def drr_w(steps: int = 36, retardance: float = QWP, *, psg_offset_deg: float = 0.0,
          psa_offset_deg: float = 0.0, psg_retardance: float | None = None,
          psa_retardance: float | None = None, psa_polariser_deg: float = 0.0,
          ) -> NDArray[np.float64]:
    """The instrument matrix of a DRR with optional hidden misalignments."""
    g, a = drr_angles(steps)
    return instrument_matrix(
        g + psg_offset_deg, a + psa_offset_deg,
        psg_retardance=retardance if psg_retardance is None else psg_retardance,
        psa_retardance=retardance if psa_retardance is None else psa_retardance,
        psa_polariser_deg=psa_polariser_deg)


def measure(w: NDArray[np.float64], m: NDArray[np.float64], sigma: float,
            rng: np.random.Generator) -> NDArray[np.float64]:
    """Intensities ``W vec(M)`` with Gaussian noise of standard deviation ``sigma``."""
    clean = w @ m.ravel()
    return clean + sigma * rng.standard_normal(clean.shape)
