"""Direction sets for hemispherical scans.

Equal-solid-angle grid: the cap θ ≤ θmax (solid angle Ω = 2π(1 − cos θmax)) is cut into
rings of polar bands; ring k holds n_k cells, all of the same solid angle ω = Ω/N. Ring
counts follow the band areas (n_k ≈ A_k/ω, cells roughly square: M ≈ θmax/√ω rings),
then the band edges are recomputed so each band has exactly n_k·ω:
cos θ_{k+1} = cos θ_k − n_k ω / (2π). The cell centre sits at the band's solid-angle
midpoint, cos θ_c = (cos θ_k + cos θ_{k+1})/2, and at azimuths φ_j = (j + ½)·360°/n_k
(Nicodemus 1977 for dΩ = sinθ dθ dφ; the construction is the usual equal-area ring grid).
"""

from __future__ import annotations

import math

import numpy as np

from instrument.bench.kinematics import Angles, direction

__all__ = ["dedupe_reciprocal", "equal_solid_angle_count", "equal_solid_angle_grid",
           "specular_cone"]


def equal_solid_angle_grid(n: int, theta_max_deg: float = 85.0) -> tuple[np.ndarray, float]:
    """About ``n`` directions (θ, φ) in degrees, shape (N, 2), and the cell solid angle (sr).

    N equals ``n`` exactly unless rounding the rings forces a different count; every cell
    has the same solid angle, returned as the second value.
    """
    counts = _ring_counts(n, theta_max_deg)
    cmin = math.cos(math.radians(theta_max_deg))
    omega_total = 2.0 * math.pi * (1.0 - cmin)
    # First ring of a cap is one cell (the pole) when it is small enough.
    total = int(counts.sum())
    omega = omega_total / total
    out = []
    c_top = 1.0
    for k, nk in enumerate(counts):
        c_bot = c_top - nk * omega / (2.0 * math.pi) if k < len(counts) - 1 else cmin
        theta_c = math.degrees(math.acos((c_top + c_bot) / 2.0))
        if nk == 1 and k == 0:
            theta_c = 0.0 if c_top == 1.0 else theta_c
        for j in range(nk):
            out.append((theta_c, (j + 0.5) * 360.0 / nk if nk > 1 else 0.0))
        c_top = c_bot
    return np.array(out), omega


def equal_solid_angle_count(n: int, theta_max_deg: float = 85.0) -> int:
    """How many directions :func:`equal_solid_angle_grid` gives for ``n``, without making
    them (a plan's point count before generation)."""
    return int(_ring_counts(n, theta_max_deg).sum())


def _ring_counts(n: int, theta_max_deg: float) -> np.ndarray:
    """Cells per ring of the equal-solid-angle grid of about ``n`` cells (module docstring:
    n_k ≈ A_k/ω over M ≈ θmax/√ω bands of equal polar width)."""
    if n < 1:
        raise ValueError("n must be >= 1")
    cmin = math.cos(math.radians(theta_max_deg))
    omega = 2.0 * math.pi * (1.0 - cmin) / n
    rings = max(1, round(math.radians(theta_max_deg) / math.sqrt(omega)))
    edges = np.linspace(0.0, math.radians(theta_max_deg), rings + 1)
    areas = 2.0 * math.pi * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    return np.maximum(1, np.round(areas / omega)).astype(int)


def specular_cone(theta_i: float, phi_i: float, *, half_width_deg: float, rings: int,
                  per_ring: int) -> list[tuple[float, float]]:
    """Directions on ``rings`` cones around the specular direction of (θi, φi), degrees.

    The specular direction is θr = θi, φr = φi + 180° (analysis.brdf.geometry); ring k has
    opening half-angle k·half_width/rings. Directions below the horizon are dropped.
    """
    axis = direction(theta_i, phi_i + 180.0)
    ref = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    u = np.cross(axis, ref)
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    out = []
    for k in range(1, rings + 1):
        a = math.radians(half_width_deg * k / rings)
        for j in range(per_ring):
            b = 2.0 * math.pi * j / per_ring
            vec = math.cos(a) * axis + math.sin(a) * (math.cos(b) * u + math.sin(b) * w)
            if vec[2] <= 1e-6:
                continue
            th = math.degrees(math.acos(min(1.0, vec[2])))
            ph = math.degrees(math.atan2(vec[1], vec[0])) % 360.0
            out.append((th, ph))
    return out


def _key(a: Angles, isotropic: bool, ndigits: int = 6) -> tuple[float, ...]:
    if isotropic:
        dphi = (a.phi_r - a.phi_i) % 360.0
        if a.theta_i < 1e-9 or a.theta_r < 1e-9:
            dphi = 0.0
        dphi = round(dphi, ndigits) % 360.0
        return (round(a.theta_i, ndigits), round(a.theta_r, ndigits), dphi)
    wi, wr = a.omega_i, a.omega_r
    return tuple(round(float(x), ndigits) + 0.0 for x in (*wi, *wr))


def dedupe_reciprocal(angles: list[Angles], *, isotropic: bool = True) -> list[int]:
    """Indices of ``angles`` to keep: one of each set equal under reciprocity.

    Helmholtz reciprocity f(i→r) = f(r→i) (Nicodemus et al. 1977) makes a point and its
    source/detector exchange measure the same value; for an isotropic sample only
    θi, θr and φr − φi matter. The first occurrence is kept; exact duplicates go too.
    """
    seen: set[tuple[float, ...]] = set()
    keep = []
    for i, a in enumerate(angles):
        k1 = _key(a, isotropic)
        k2 = _key(a.reciprocal(), isotropic)
        if k1 in seen or k2 in seen:
            continue
        seen.add(k1)
        keep.append(i)
    return keep
