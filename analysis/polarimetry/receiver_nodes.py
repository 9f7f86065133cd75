"""What a finite receiver integrates of a Mueller-matrix BRDF: quadrature nodes over the
beam's footprint and the receiver's aperture, with the polarimeter's frames at each node.

A polarimetric reading is not F at the nominal angles. Like a scalar one it integrates F
over the lit footprint seen through every point of the receiver aperture (Nicodemus et al.
1977, NBS Monograph 160, the equation for dΦ_r), and after the reduction's division by
P Ω cos θr (:mod:`instrument.pipelines.polarimetry.reduce`) it is

    F_meas = Σ_m W_m · R_out(m) F(ωi_m, ωr_m) R_in(m)

with the nodes and weights W of the scalar instrument function
(:func:`analysis.brdf.reduction.receiver.receiver_nodes`: Gauss–Hermite over the
Gaussian footprint, a product rule of Gauss–Chebyshev and Gauss–Legendre on the aperture
disk, Radon's degree-5 rule at level 0 — Stroud 1971, *Approximate Calculation of
Multiple Integrals*, S2:5-1 — and the read-back spread of the axes). Σ W is the receiver
factor G of that module (not 1: 1/r² and the obliquities across the footprint, and the
aperture's projected solid angle against Ω), so a constant matrix comes back as G times
itself; with ``normalise`` the weights sum to one and it comes back unchanged.

**The frames.** A polariser in front of the receiver has one axis for every ray through
the aperture: its azimuth reference is fixed to the receiver arm, not to each ray's own
plane of incidence. The reference of a node's beam is the central ray's global s axis
(``s_g = (−sin φ, cos φ, 0)`` of :mod:`analysis.polarimetry.pbrdf`, ⟂ the plane of the
normal and the central beam) made perpendicular to the node's direction and normalised;
the same on the incident side (the beam's rays are parallel unless it diverges). For an
in-plane bench that axis is the goniometer's rotation axis, the reference of the
simulated world's Stokes bases too (``hw_mocks.sim.polarisation.transverse_basis``).
A node's own s_g differs from it by an angle ψ ≈ Δ cot θ about the beam for an offset Δ
across the plane (about 0.014 rad at the aperture's rim, 5 mm at 300 mm, θr = 30°); the
m₀₁/m₀₂ mixing that follows, 2ψ, averages out in first order but not in second (2ψ² of
m₀₁, 10⁻⁴ of it at θr = 30°), more than a PEM's 10⁻⁵ σ of columns 1 and 3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.geometry import make_geometry
from analysis.brdf.reduction.receiver import LEVELS, ReceiverGeometry, receiver_nodes

__all__ = ["LEVELS", "MuellerNodes", "mueller_nodes"]


@dataclass(frozen=True)
class MuellerNodes:
    """Quadrature nodes of N readings, stored point after point (:func:`mueller_nodes`).

    Attributes
    ----------
    wi, wr : ndarray of shape (M, 3)
        Unit vectors towards the source and towards the receiver point, sample frame.
    s_in, s_out : ndarray of shape (M, 3)
        Each beam's frame reference (module docstring): unit, ⟂ the beam.
    weights : ndarray of shape (M,)
        W; their sum per reading is the receiver factor G (1 with ``normalise``).
    starts : ndarray of int, shape (N,)
        Index of each reading's first node.
    level : int
        The quadrature level (index into :data:`LEVELS`).
    """

    wi: NDArray[np.float64]
    wr: NDArray[np.float64]
    s_in: NDArray[np.float64]
    s_out: NDArray[np.float64]
    weights: NDArray[np.float64]
    starts: NDArray[np.intp]
    level: int

    def average(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """Σ W · values over each reading's nodes: (M, ...) → (N, ...)."""
        w = self.weights.reshape((-1,) + (1,) * (values.ndim - 1))
        return np.asarray(np.add.reduceat(values * w, self.starts, axis=0))


def _project(ref: NDArray[np.float64], k: NDArray[np.float64]) -> NDArray[np.float64]:
    """``ref`` (M, 3) made perpendicular to the unit vectors ``k`` (M, 3), normalised."""
    v = ref - np.sum(ref * k, axis=-1, keepdims=True) * k
    return np.asarray(v / np.linalg.norm(v, axis=-1, keepdims=True))


def mueller_nodes(theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike,
                  phi_r: ArrayLike, receiver: ReceiverGeometry, *, level: int = 1,
                  normalise: bool = False) -> MuellerNodes:
    """The nodes of N readings at their nominal angles (radians, broadcast together).

    ``level`` indexes :data:`LEVELS` (nodes per reading: 28 at level 0 to 5 760 at 4
    without angular spread). ``normalise`` scales each reading's weights to sum to one
    (an average instead of the reading in units of P Ω cos θr).

    Raises
    ------
    ValueError
        A level outside :data:`LEVELS`, or polar angles outside [0, π/2].
    """
    geo = make_geometry(*np.broadcast_arrays(*(np.asarray(a, dtype=float).ravel()
                                               for a in (theta_i, phi_i, theta_r, phi_r))))
    n = int(np.prod(geo.shape))
    nodes = receiver_nodes(geo, receiver, level)
    g = nodes.geometry
    wi = np.stack([g.xi, g.yi, g.mu_i], axis=-1).reshape(-1, 3)
    wr = np.stack([g.xr, g.yr, g.mu_r], axis=-1).reshape(-1, 3)
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wr /= np.linalg.norm(wr, axis=-1, keepdims=True)
    counts = np.diff(np.append(nodes.starts, nodes.weights.size))
    # the central rays' global s axes, one per reading, repeated over its nodes
    phi_in = np.repeat(np.broadcast_to(np.asarray(phi_i, dtype=float).ravel(), (n,)), counts)
    phi_out = np.repeat(np.broadcast_to(np.asarray(phi_r, dtype=float).ravel(), (n,)), counts)
    zeros = np.zeros_like(phi_in)
    s_in = np.stack([-np.sin(phi_in), np.cos(phi_in), zeros], axis=-1)
    s_out = np.stack([-np.sin(phi_out), np.cos(phi_out), zeros], axis=-1)
    weights = np.asarray(nodes.weights, dtype=float)
    if normalise:
        weights = weights / np.repeat(nodes.sums(weights), counts)
    return MuellerNodes(wi=wi, wr=wr, s_in=_project(s_in, -wi), s_out=_project(s_out, wr),
                        weights=weights, starts=nodes.starts, level=level)
