"""Quadrature rules on the camera's entrance pupil (a disk), for the simulated camera.

A real lens collects, at each pixel, the radiance of every ray from its conjugate object
point through the whole entrance pupil; the simulated camera integrates over the pupil
with the rules below and refines them pixel by pixel until two successive rules agree
(:meth:`hw_mocks.sim.camera.SimulatedCamera.photon_rate`).

Every rule is a set of points (x, y) on the unit disk with weights summing to 1 (a mean
over the disk area):

* :func:`radon7` — Radon's 7-point rule, exact for polynomials of degree ≤ 5 (Stroud 1971,
  *Approximate Calculation of Multiple Integrals*, formula S2:5-1: the centre with weight
  1/4, six points at radius √(2/3) with weight 1/8): the first rung.
* :func:`polar_gauss` — a product rule in (s = r², φ): Gauss–Legendre in s on [0, 1]
  (dA = ½ ds dφ, so equal-area in s) times the trapezoid rule in φ, every other ring
  shifted by half a step. Exact for polynomials of degree < min(2·n_s, n_φ) in (x, y),
  and spectrally convergent for analytic integrands, hence the refinement ladder
  :data:`LADDER` (each rung doubles both orders).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

__all__ = ["LADDER", "DiskRule", "polar_gauss", "radon7"]


class DiskRule:
    """Points on the unit disk and weights (sum 1) of a mean over the disk."""

    __slots__ = ("weights", "x", "y")

    def __init__(self, x: NDArray[np.float64], y: NDArray[np.float64],
                 weights: NDArray[np.float64]) -> None:
        self.x, self.y, self.weights = x, y, weights

    def __len__(self) -> int:
        return int(self.weights.size)


@lru_cache(maxsize=1)
def radon7() -> DiskRule:
    """Radon's degree-5 rule (module docstring)."""
    r = math.sqrt(2.0 / 3.0)
    phi = np.arange(6) * (math.pi / 3.0)
    x = np.concatenate([[0.0], r * np.cos(phi)])
    y = np.concatenate([[0.0], r * np.sin(phi)])
    w = np.concatenate([[0.25], np.full(6, 0.125)])
    return DiskRule(x, y, w)


@lru_cache(maxsize=16)
def polar_gauss(n_s: int, n_phi: int) -> DiskRule:
    """Gauss–Legendre in s = r² (``n_s`` rings) × ``n_phi`` azimuths (module docstring)."""
    if n_s < 1 or n_phi < 1:
        raise ValueError("n_s and n_phi must be >= 1")
    t, wt = np.polynomial.legendre.leggauss(n_s)
    s = 0.5 * (t + 1.0)
    ring_w = 0.5 * wt  # ∫₀¹ ds = 1
    k = np.arange(n_phi)
    xs, ys, ws = [], [], []
    for j in range(n_s):
        phi = 2.0 * math.pi * (k + 0.5 * (j % 2)) / n_phi
        r = math.sqrt(s[j])
        xs.append(r * np.cos(phi))
        ys.append(r * np.sin(phi))
        ws.append(np.full(n_phi, ring_w[j] / n_phi))
    return DiskRule(np.concatenate(xs), np.concatenate(ys), np.concatenate(ws))


#: The refinement ladder after Radon's rule: (rings, azimuths) per rung.
LADDER: tuple[tuple[int, int], ...] = ((3, 10), (6, 20), (12, 40), (24, 80))
