"""The instrument function of a reading: what a BRDF gives through the real beam and receiver.

A reading of the goniometer is not f at the nominal angles. It integrates f over

* the **incident beam**: a Gaussian profile of 1/e² radius w whose footprint on the sample
  grows as 1/cos θi along the plane of incidence (clipped by the sample's edge when the
  beam overfills it at grazing incidence), and the beam's **divergence** (a Gaussian
  spread of incident directions);
* the **receiver's field**: every point of the footprint seen through every point of the
  receiver aperture — a camera's entrance pupil (its pixels are summed over the
  footprint's image, so the whole footprint counts) or a power meter's aperture — at its
  distance R, with the 1/r² and obliquity factors of each pair;
* the **set-point uncertainty** of the axes: the incidence and receiver angles scatter
  about their read-backs with standard deviations σθi, σθr. Its mean effect (½σ²f'')
  is part of the kernel here; its scatter is noise, carried by
  :mod:`analysis.brdf.reduction.forward` as an effective variance (Orear 1982).

Radiometry (Nicodemus et al. 1977, NBS Monograph 160, eq. for dΦ_r): the
power a receiver collects is

    P = ∫_spot ∫_aperture f(ωi, ω) E(x) cos θ cos α / r² dA_ap dA,

ω, r the direction and distance from spot point x to aperture point a, θ its polar angle,
α its angle to the aperture normal, and E(x) = 2Pᵢ cos θi /(πw²) exp(−2(u² cos²θi + v²)/w²)
the beam's irradiance on the sample (u along the plane of incidence, v across). The
absolute method divides P by Pᵢ Ω cos θr (:mod:`analysis.brdf.reduction.values`), so a
reading is Σ_m W_m f(node m) with

    W = (E dA/Pᵢ) · (cos θ cos α A_ap / r²) / (Ω cos θr)  × (angular-spread weight),

and the **receiver factor** G = Σ W (:func:`receiver_factor`) is the reading of f ≡ 1.
Dividing G out makes a reduced value the normalised average Σ W f / Σ W, which
:func:`receiver_model` computes for any model.

Quadrature (:data:`LEVELS`; the level is chosen per point by
:mod:`analysis.brdf.reduction.forward` until the next level changes the value by less
than a fraction of the noise):

* footprint: Gauss–Hermite in (s, t) = (√2 u cos θi / w, √2 v / w), whose weight is the
  Gaussian itself; where the sample's edge cuts the footprint, Gauss–Legendre over the
  chord of the sample disk at each t node, with the Gaussian in the weights;
* aperture: Radon's degree-5 disk rule (Stroud 1971, S2:5-1) at level 0, then product
  rules of Gauss–Chebyshev (second kind) across and Gauss–Legendre along the chords,
  aligned with the plane of ωi and ωr and with more nodes across it where a lobe seen at
  grazing is narrow there (:func:`_aspect`); a pinhole (``sample_aperture=False``) uses
  the aperture centre only;
* angular spread (divergence ⊕ set-point uncertainty, a Gaussian in up to three angles):
  the centre at level 0, Stroud's degree-3 rule (±√n along each axis) at level 1, the
  3-point Gauss–Hermite product (degree 5) above.

This model is written from the sample's side (footprint × aperture); the simulated camera
renders from the image side (pixels × pupil, ``hw_mocks.sim.camera``), so agreement of
the two is a check of both (tests/analysis/brdf/test_forward_model.py).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.geometry import Geometry, flat_angles, geometry_from_vectors, make_geometry
from analysis.brdf.model import BRDFModel

__all__ = [
    "LEVELS",
    "NodeSet",
    "QuadratureLevel",
    "ReceiverGeometry",
    "receiver_factor",
    "receiver_model",
    "receiver_nodes",
]


@dataclass(frozen=True)
class QuadratureLevel:
    """Orders of one quadrature level.

    Attributes
    ----------
    footprint : (int, int)
        Nodes along u (the plane of incidence) and v.
    pupil : (int, int)
        Nodes across and along the chords of the aperture rule (:func:`_disk`), the second
        multiplied by the point's aspect (1, 2, 4 or 8); (0, 0) is Radon's 7-point rule.
    angular : int
        Degree of the angular-spread rule (1, 3 or 5).
    """

    footprint: tuple[int, int]
    pupil: tuple[int, int]
    angular: int


#: The refinement ladder (module docstring). Nodes per point without angular spread or
#: clipping, for an aspect-1 point: 28, 54, 300, 1 536, 5 760.
LEVELS: tuple[QuadratureLevel, ...] = (
    QuadratureLevel((2, 2), (0, 0), 1),
    QuadratureLevel((3, 2), (3, 3), 3),
    QuadratureLevel((4, 3), (5, 5), 5),
    QuadratureLevel((6, 4), (8, 8), 5),
    QuadratureLevel((8, 5), (12, 12), 5),
)


@dataclass(frozen=True)
class ReceiverGeometry:
    """What one receiver reading integrates (module docstring).

    Attributes
    ----------
    beam_radius_mm : float
        1/e² intensity radius w of the beam at the sample (mm).
    distance_mm : float
        R, sample centre to the aperture (camera pupil) centre (mm).
    aperture_diameter_mm : float
        D of the receiver aperture or camera entrance pupil (mm).
    solid_angle_sr : float
        The Ω the reduction divides by (:func:`solid_angle_sr` or
        :func:`camera_solid_angle_sr`).
    sample_aperture : bool
        True: the aperture is integrated (a power-meter aperture, a lens pupil). False: the
        ray through the aperture centre with étendue A cos α / r² (a pinhole).
    beam_divergence_rad : float
        1/e² half-angle of the beam's Gaussian angular profile (a collimated TEM00 beam:
        λ/(π w₀)); 0 for a collimated beam.
    sample_radius_mm : float or None
        Radius of the sample disk (clips the footprint at grazing incidence); None: the
        sample is larger than any footprint.
    sigma_theta_i_rad, sigma_theta_r_rad : float
        Standard uncertainty of the incidence and receiver angles (axis set points).
    """

    beam_radius_mm: float
    distance_mm: float
    aperture_diameter_mm: float
    solid_angle_sr: float
    sample_aperture: bool = True
    beam_divergence_rad: float = 0.0
    sample_radius_mm: float | None = None
    sigma_theta_i_rad: float = 0.0
    sigma_theta_r_rad: float = 0.0

    def __post_init__(self) -> None:
        if not (self.beam_radius_mm > 0 and self.distance_mm > 0):
            raise ValueError("beam radius and distance must be > 0")
        if not (self.aperture_diameter_mm > 0 and self.solid_angle_sr > 0):
            raise ValueError("aperture diameter and solid angle must be > 0")
        if min(self.beam_divergence_rad, self.sigma_theta_i_rad, self.sigma_theta_r_rad) < 0:
            raise ValueError("beam divergence and angular uncertainties must be >= 0")
        if self.sample_radius_mm is not None and not self.sample_radius_mm > 0:
            raise ValueError("sample_radius_mm must be > 0 (or None)")

    @property
    def angular_sigmas(self) -> tuple[float, float, float]:
        """σ of the incident direction in and across the plane of incidence and of the
        receiver direction in its meridian plane (radians). A 1/e² half-angle θ of a
        Gaussian intensity profile exp(−2δ²/θ²) is σ = θ/2 per axis."""
        div = 0.5 * self.beam_divergence_rad
        return (float(np.hypot(div, self.sigma_theta_i_rad)), div, self.sigma_theta_r_rad)


# ------------------------------------------------------------------------------ rules
@lru_cache(maxsize=1)
def _radon7() -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    """Radon's 7-point disk rule (Stroud 1971, S2:5-1): (x, y, w) on the unit disk."""
    r = np.sqrt(2.0 / 3.0)
    chi = np.arange(6) * np.pi / 3.0
    x = np.concatenate([[0.0], r * np.cos(chi)])
    y = np.concatenate([[0.0], r * np.sin(chi)])
    return x, y, np.concatenate([[0.25], np.full(6, 0.125)])


@lru_cache(maxsize=64)
def _disk(n_x: int, n_y: int) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    """A product rule on the unit disk, exact for polynomials of degree
    < 2·min(n_x, n_y): Gauss–Chebyshev of the second kind in x (weight √(1 − x²), the
    chord's half-length; Abramowitz & Stegun 25.4.40) and Gauss–Legendre along each chord,
    y = √(1 − x²)·η. Returns (x, y, w), Σw = 1; (0, 0) gives Radon's rule. ``n_y`` > ``n_x``
    resolves integrands narrow along y (a lobe seen at grazing, :func:`_aspect`)."""
    if n_x == 0:
        return _radon7()
    k = np.arange(1, n_x + 1)
    angle = k * np.pi / (n_x + 1)
    xs = np.cos(angle)
    wx = np.sin(angle) ** 2  # × π/(n_x + 1), dropped by the normalisation
    eta, we = np.polynomial.legendre.leggauss(n_y)
    half = np.sqrt(1.0 - xs * xs)
    x = np.repeat(xs, n_y)
    y = (half[:, None] * eta[None, :]).reshape(-1)
    w = (wx[:, None] * we[None, :]).reshape(-1)
    return x, y, w / w.sum()


def _aspect(wi: NDArray[Any], wr: NDArray[Any]) -> NDArray[np.intp]:
    """How much narrower a lobe of the half vector h = (ωi + ωr)/|ωi + ωr| is across the
    plane of ωi and ωr than within it, as seen from the receiver: a receiver offset ε
    across the plane tilts h by ε/|v|, one within it by ε sin∠(t, h)/|v| (t the in-plane
    direction ⟂ ωr). At grazing specular incidence the ratio 1/sin∠(t, h) = 1/cos θ
    reaches 5.8 at 80°. Rounded to 1, 2, 4 or 8."""
    v = wi + wr
    h = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)
    across = np.cross(wi, wr)
    across /= np.maximum(np.linalg.norm(across, axis=-1, keepdims=True), 1e-12)
    t = np.cross(across, wr)
    sin_th = np.sqrt(np.maximum(1.0 - np.sum(t * h, axis=-1) ** 2, 0.0))
    ratio = 1.0 / np.maximum(sin_th, 1.0 / 8.0)
    return np.minimum(2 ** np.round(np.log2(ratio)), 8).astype(np.intp)


@lru_cache(maxsize=16)
def _hermite(n: int) -> tuple[NDArray[Any], NDArray[Any]]:
    """Gauss–Hermite nodes and weights of ∫ g(s) exp(−s²) ds / √π (Σw = 1)."""
    x, w = np.polynomial.hermite.hermgauss(n)
    return x, w / np.sqrt(np.pi)


@lru_cache(maxsize=16)
def _legendre(n: int) -> tuple[NDArray[Any], NDArray[Any]]:
    return np.polynomial.legendre.leggauss(n)


@lru_cache(maxsize=16)
def _angular_rule(degree: int, dims: tuple[bool, bool, bool]) -> tuple[NDArray[Any], NDArray[Any]]:
    """Nodes (K, 3) in units of σ and weights (K,) of a standard normal in the dimensions
    flagged in ``dims`` (the others stay 0): the centre (degree 1), Stroud's Gn 3-1
    (±√n on each axis, degree 3) or the 3-point Gauss–Hermite product (degree 5)."""
    active = [k for k in range(3) if dims[k]]
    n = len(active)
    if n == 0 or degree <= 1:
        return np.zeros((1, 3)), np.ones(1)
    if degree <= 3:
        nodes = np.zeros((2 * n, 3))
        for j, k in enumerate(active):
            nodes[2 * j, k] = np.sqrt(n)
            nodes[2 * j + 1, k] = -np.sqrt(n)
        return nodes, np.full(2 * n, 1.0 / (2 * n))
    x, w = np.polynomial.hermite_e.hermegauss(3)  # weight exp(−x²/2)
    w = w / w.sum()
    grids = np.meshgrid(*([x] * n), indexing="ij")
    wg = np.meshgrid(*([w] * n), indexing="ij")
    nodes = np.zeros((grids[0].size, 3))
    for j, k in enumerate(active):
        nodes[:, k] = grids[j].reshape(-1)
    weights = np.prod([g.reshape(-1) for g in wg], axis=0)
    return nodes, weights


# ------------------------------------------------------------------------------ nodes
@dataclass(frozen=True)
class NodeSet:
    """Quadrature nodes of N readings, stored point after point.

    Attributes
    ----------
    geometry : Geometry, shape (M,)
        Incident and receiver directions of every node.
    weights : ndarray, shape (M,)
        W of the module docstring (their sum per point is the receiver factor G).
    starts : ndarray of int, shape (N,)
        Index of each point's first node (``np.add.reduceat`` segments).
    """

    geometry: Geometry
    weights: NDArray[np.float64]
    starts: NDArray[np.intp]

    def sums(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """Σ over each point's nodes of ``values`` (shape (M,) or (M, k))."""
        return np.add.reduceat(values, self.starts, axis=0)


def _frame(w: NDArray[Any]) -> tuple[NDArray[Any], NDArray[Any]]:
    """Two unit vectors (N, 3) ⟂ to the unit vectors ``w`` (N, 3) and to each other."""
    helper = np.where((np.abs(w[:, 1]) < 0.9)[:, None], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    e1 = np.cross(w, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(w, e1)


def _meridian_axis(w: NDArray[Any]) -> NDArray[Any]:
    """Unit vector ⟂ to the meridian plane of ``w`` (the plane of w and the normal z):
    rotating about it changes w's polar angle only."""
    axis = np.stack([-w[:, 1], w[:, 0], np.zeros(len(w))], axis=-1)
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    return np.where(norm > 1e-12, axis / np.where(norm > 1e-12, norm, 1.0), [0.0, 1.0, 0.0])


def _rotate(v: NDArray[Any], axis: NDArray[Any], angle: NDArray[Any]) -> NDArray[Any]:
    """Rodrigues' rotation of v (..., 3) about unit ``axis`` (..., 3) by ``angle`` (...)."""
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    return v * c + np.cross(axis, v) * s + axis * np.sum(axis * v, axis=-1)[..., None] * (1 - c)


def _chord_nodes(wi: NDArray[Any], receiver: ReceiverGeometry, level: QuadratureLevel
                 ) -> NDArray[np.intp]:
    """Gauss–Legendre nodes along the footprint of each point (N,) where the sample's edge
    cuts it (0 where Gauss–Hermite serves): e^{−s²} on [−a, a] to 1e-9 takes about
    4.5a + 4 nodes (24 at a = 4.4, 13 at a = 2), a the edge at v = 0 in s units; the
    BRDF's variation asks for 2·nu + 2 at least. Per point, so that a point gets the same
    nodes whatever other points it is evaluated with (a cross-validation fold)."""
    n = wi.shape[0]
    if receiver.sample_radius_mm is None:
        return np.zeros(n, dtype=np.intp)
    a = (receiver.sample_radius_mm * np.maximum(wi[:, 2], 1e-9) * np.sqrt(2.0)
         / receiver.beam_radius_mm)
    need = np.maximum(np.ceil(4.5 * a + 4.0), 2 * level.footprint[0] + 2).astype(np.intp)
    return np.where(a > _GH_EDGE, 0, need)


#: Where the sample's edge lies beyond this many s units the footprint is integrated by
#: Gauss–Hermite as if unbounded (a tail of erfc(3.8)/2 < 1e-8, lost from G and the model
#: alike).
_GH_EDGE = 3.8


def _level_nodes(wi: NDArray[Any], wr: NDArray[Any], receiver: ReceiverGeometry,
                 level: QuadratureLevel, aspect: int = 1, n_gl: int = 0
                 ) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    """Nodes of the points (wi, wr) (N, 3) at one level and aspect (:func:`_aspect`), with
    ``n_gl`` Gauss–Legendre nodes along a footprint the sample's edge cuts
    (:func:`_chord_nodes`; 0: Gauss–Hermite): incident and receiver directions (N, K, 3)
    and weights (N, K)."""
    n = wi.shape[0]
    w_beam = receiver.beam_radius_mm
    cos_i = np.maximum(wi[:, 2], 1e-9)
    # footprint axes: u along the beam's projection on the sample, v across it
    proj = np.hypot(wi[:, 0], wi[:, 1])
    safe = proj > 1e-12
    eu = np.zeros((n, 3))
    eu[:, 0] = np.where(safe, wi[:, 0] / np.where(safe, proj, 1.0), 1.0)
    eu[:, 1] = np.where(safe, wi[:, 1] / np.where(safe, proj, 1.0), 0.0)
    ev = np.stack([-eu[:, 1], eu[:, 0], np.zeros(n)], axis=-1)
    nu, nv = level.footprint
    t, wt = _hermite(nv)
    v = t * w_beam / np.sqrt(2.0)  # (nv,) mm
    s_gh, w_gh = _hermite(nu)
    if n_gl == 0:
        s = np.broadcast_to(s_gh, (n, nv, nu))
        ws = np.broadcast_to(w_gh, (n, nv, nu))
    else:
        # Gauss–Legendre over the chord of the sample disk at each v (in s units), with
        # the Gaussian in the weights; a v node whose chord reaches past the Gaussian's
        # reach keeps Gauss–Hermite (padded with zero-weight nodes to one shape)
        assert receiver.sample_radius_mm is not None
        rs = receiver.sample_radius_mm
        chord = np.sqrt(np.maximum(rs * rs - v * v, 0.0))  # (nv,) mm
        s_edge = chord[None, :] * cos_i[:, None] * np.sqrt(2.0) / w_beam  # (n, nv)
        x, wl = _legendre(n_gl)
        s_gl = s_edge[..., None] * x
        w_gl = s_edge[..., None] * wl * np.exp(-s_gl * s_gl) / np.sqrt(np.pi)
        use_gh = (s_edge > _GH_EDGE)[..., None]
        pad = np.zeros(max(n_gl - nu, 0))
        s = np.where(use_gh, np.concatenate([s_gh, pad])[:n_gl], s_gl)
        ws = np.where(use_gh, np.concatenate([w_gh, pad])[:n_gl], w_gl)
    u = s * w_beam / (np.sqrt(2.0) * cos_i[:, None, None])  # (n, nv, nu') mm
    spot = (u[..., None] * eu[:, None, None, :]
            + np.broadcast_to(v[None, :, None, None], (*u.shape, 1)) * ev[:, None, None, :])
    spot = spot.reshape(n, -1, 3)
    w_spot = (ws * wt[None, :, None]).reshape(n, -1)
    # angular spread: incident (in plane, across) and receiver (meridian) offsets
    sig = receiver.angular_sigmas
    a_nodes, a_w = _angular_rule(level.angular, tuple(x > 0 for x in sig))
    e_in = np.cross(wi, ev)  # in the plane of incidence, ⟂ wi
    e_in /= np.linalg.norm(e_in, axis=-1, keepdims=True)
    # pupil
    rho = 0.5 * receiver.aperture_diameter_mm
    area = np.pi * rho * rho
    if receiver.sample_aperture:
        px, py, pw = _disk(level.pupil[0], level.pupil[1] * aspect)
    else:
        px, py, pw = np.zeros(1), np.zeros(1), np.ones(1)
    radial = _meridian_axis(wr)
    out_i, out_r, out_w = [], [], []
    for (da, db, dc), aw in zip(a_nodes, a_w, strict=True):
        wi_k = wi
        if da or db:
            wi_k = wi + (da * sig[0]) * e_in + (db * sig[1]) * ev
            wi_k = wi_k / np.linalg.norm(wi_k, axis=-1, keepdims=True)
        wr_k = wr if not dc else _rotate(wr, radial, np.full(n, dc * sig[2]))
        # the aperture's y axis across the plane of ωi and ωr (where lobes are narrow)
        e2 = np.cross(wi, wr_k)
        norm = np.linalg.norm(e2, axis=-1, keepdims=True)
        _f1, f2 = _frame(wr_k)
        e2 = np.where(norm > 1e-9, e2 / np.where(norm > 1e-9, norm, 1.0), f2)
        e1 = np.cross(e2, wr_k)
        ap = (receiver.distance_mm * wr_k[:, None, :]
              + rho * (px[None, :, None] * e1[:, None, :] + py[None, :, None] * e2[:, None, :]))
        d = ap[:, None, :, :] - spot[:, :, None, :]  # (n, Ks, Kp, 3): spot → aperture
        r2 = np.einsum("...k,...k->...", d, d)
        omega = d / np.sqrt(r2)[..., None]
        cos_t = np.clip(omega[..., 2], 0.0, None)
        cos_a = np.clip(np.einsum("...k,...k->...", omega, wr_k[:, None, None, :]), 0.0, None)
        wgt = (w_spot[:, :, None] * pw[None, None, :] * aw * area * cos_t * cos_a / r2
               / (receiver.solid_angle_sr * np.maximum(wr[:, 2], 1e-12)[:, None, None]))
        k = omega.shape[1] * omega.shape[2]
        out_i.append(np.broadcast_to(wi_k[:, None, :], (n, k, 3)))
        out_r.append(omega.reshape(n, k, 3))
        out_w.append(wgt.reshape(n, k))
    return (np.concatenate(out_i, axis=1), np.concatenate(out_r, axis=1),
            np.concatenate(out_w, axis=1))


def _unit_vectors(geometry: Geometry) -> tuple[NDArray[Any], NDArray[Any]]:
    wi = np.stack([geometry.xi, geometry.yi, geometry.mu_i], axis=-1).reshape(-1, 3)
    wr = np.stack([geometry.xr, geometry.yr, geometry.mu_r], axis=-1).reshape(-1, 3)
    return (wi / np.linalg.norm(wi, axis=-1, keepdims=True),
            wr / np.linalg.norm(wr, axis=-1, keepdims=True))


def receiver_nodes(geometry: Geometry, receiver: ReceiverGeometry,
                   levels: ArrayLike | int = 1) -> NodeSet:
    """Quadrature of a reading (module docstring) for every point of ``geometry``.

    Parameters
    ----------
    geometry : Geometry
        N nominal (ωi, ωr) pairs (flattened).
    receiver : ReceiverGeometry
    levels : int or array_like of int, shape (N,)
        Index into :data:`LEVELS` per point (or one for all).

    Returns
    -------
    NodeSet
        Nodes stored point after point; ``weights`` are W (their per-point sum is G).
    """
    n = int(np.prod(geometry.shape))
    lev = np.broadcast_to(np.asarray(levels, dtype=np.intp), (n,))
    if n and (lev.min() < 0 or lev.max() >= len(LEVELS)):
        raise ValueError(f"levels must lie in 0..{len(LEVELS) - 1}")
    counts = np.zeros(n, dtype=np.intp)
    blocks: list[tuple[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]]] = []
    for k in np.unique(lev):
        for idx_all, bi, br, bw in _level_blocks(geometry, receiver, int(k)):
            keep = lev[idx_all] == k
            if not keep.any():
                continue
            idx = idx_all[keep]
            counts[idx] = bw.shape[1]
            blocks.append((idx, bi[keep], br[keep], bw[keep]))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.intp)
    total = int(counts.sum())
    vi, vr, vw = np.empty((total, 3)), np.empty((total, 3)), np.empty(total)
    for idx, bi, br, bw in blocks:
        k = bw.shape[1]
        pos = (starts[idx][:, None] + np.arange(k)[None, :]).reshape(-1)
        vi[pos] = bi.reshape(-1, 3)
        vr[pos] = br.reshape(-1, 3)
        vw[pos] = bw.reshape(-1)
    return NodeSet(geometry_from_vectors(vi, vr), vw, starts)


def _level_blocks(geometry: Geometry, receiver: ReceiverGeometry, level: int
                  ) -> list[tuple[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]]]:
    """Every point's nodes at ``level``, in blocks of one shape (aspect, chord nodes):
    (point indices, incident (m, K, 3), receiver (m, K, 3), weights (m, K)); cached on the
    geometry, so that any mix of levels only gathers rows."""
    key = ("receiver-level", receiver, level)
    if key not in geometry.cache:
        wi, wr = _unit_vectors(geometry)
        n = wi.shape[0]
        aspect = _aspect(wi, wr) if receiver.sample_aperture else np.ones(n, dtype=np.intp)
        n_gl = _chord_nodes(wi, receiver, LEVELS[level])
        out = []
        for a, m in sorted(set(zip(aspect.tolist(), n_gl.tolist(), strict=True))):
            idx = np.flatnonzero((aspect == a) & (n_gl == m))
            out.append((idx, *_level_nodes(wi[idx], wr[idx], receiver, LEVELS[level],
                                            int(a), int(m))))
        geometry.cache[key] = out
    return geometry.cache[key]


def receiver_factor(
    theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike, phi_r: ArrayLike,
    *, receiver: ReceiverGeometry,
) -> NDArray[np.float64]:
    """G = Σ W: the reading of a constant BRDF f = 1 in units of Pᵢ Ω cos θr, shape (n,).

    For a point receiver and a point spot G = 1; the finite footprint (1/r² and the
    obliquities across it), the aperture's projected solid angle (π sin²a against Ω),
    and the sample's edge where the beam overfills it make it differ (a few 10⁻⁴ on the
    sim bench at θi ≤ 60°; less than 1 where the edge cuts the footprint). Computed at
    the finest level of :data:`LEVELS` (the integrand is smooth). Dividing a reduced value
    by G turns it into a normalised average of f over what was integrated
    (:func:`receiver_model`).
    """
    g = make_geometry(*flat_angles(theta_i, phi_i, theta_r, phi_r))
    wi, wr = _unit_vectors(g)
    n_gl = _chord_nodes(wi, receiver, _FACTOR_LEVEL)
    out = np.empty(wi.shape[0])
    for m in np.unique(n_gl):
        idx = np.flatnonzero(n_gl == m)
        _, _, w = _level_nodes(wi[idx], wr[idx], receiver, _FACTOR_LEVEL, 1, int(m))
        out[idx] = w.sum(axis=1)
    return out


#: The rule of :func:`receiver_factor`: f ≡ 1 leaves a smooth integrand, but where the
#: sample's edge cuts the footprint the Gaussian is integrated over a chord (more nodes).
_FACTOR_LEVEL = QuadratureLevel((12, 8), (4, 4), 3)


def _normalised(nodes: NodeSet) -> NodeSet:
    total = nodes.sums(nodes.weights)
    counts = np.diff(np.append(nodes.starts, nodes.weights.size))
    return NodeSet(nodes.geometry, nodes.weights / np.repeat(total, counts), nodes.starts)


def prepared_nodes(g: Geometry, receiver: ReceiverGeometry, levels: NDArray[np.intp]
                   ) -> NodeSet:
    """Normalised nodes (weights summing to 1 per point) of ``g`` at ``levels``, cached on
    the geometry."""
    key = ("receiver", receiver, levels.tobytes())
    if key not in g.cache:
        g.cache[key] = _normalised(receiver_nodes(g, receiver, levels))
    return g.cache[key]


def receiver_model(model: BRDFModel, receiver: ReceiverGeometry, *, level: int = 1
                   ) -> BRDFModel:
    """``model`` as the receiver sees it, f_meas = Σ W f(node) / Σ W, at one quadrature
    ``level`` for every point (module docstring).

    The normalisation matches values reduced with :func:`receiver_factor` divided out, so
    a Lambertian is exact at any level; for a lobe, the level sets the accuracy (a fit
    chooses it per point against the noise: :func:`analysis.brdf.reduction.forward_model`).
    Same name, parameters and bounds as ``model``; the Jacobian is the same average of the
    model's Jacobian (analytic where the model's is).
    """
    return _AtLevels(model, receiver, lambda n: np.full(n, level, dtype=np.intp),
                     f"level {level}").as_model()


_TOKENS = itertools.count()


class _AtLevels:
    """A model averaged over receiver nodes, with the level of each point from
    ``levels_for(g)`` (a callable of the number of points or of the geometry)."""

    def __init__(self, model: BRDFModel, receiver: ReceiverGeometry,
                 levels_for: Callable[[Any], Any],
                 label: str, *, by_geometry: bool = False) -> None:
        self.model, self.receiver, self.label = model, receiver, label
        self._levels_for, self._by_geometry = levels_for, by_geometry
        self._token = next(_TOKENS)  # this instance's level table, in geometry caches

    def _nodes(self, g: Geometry) -> NodeSet:
        key = ("levels", self._token)
        if key not in g.cache:
            n = int(np.prod(g.shape))
            lev = self._levels_for(g) if self._by_geometry else self._levels_for(n)
            g.cache[key] = prepared_nodes(g, self.receiver, np.asarray(lev, dtype=np.intp))
        return g.cache[key]

    def value(self, p: NDArray[np.float64], g: Geometry) -> NDArray[np.float64]:
        nodes = self._nodes(g)
        return nodes.sums(self.model.value_fn(p, nodes.geometry) * nodes.weights
                          ).reshape(g.shape)

    def jac(self, p: NDArray[np.float64], g: Geometry) -> NDArray[np.float64]:
        nodes = self._nodes(g)
        # jac_fn is not None: this class is only built for models that have one
        j = np.asarray(self.model.jac_fn(p, nodes.geometry), dtype=float)  # type: ignore[misc]
        return nodes.sums(j * nodes.weights[:, None]).reshape((*g.shape, p.size))

    def as_model(self) -> BRDFModel:
        m = self.model
        r = self.receiver
        # a plain BRDFModel under the same name (a composite's parts would stay unaveraged)
        return BRDFModel(
            name=m.name, params=m.params, value_fn=self.value,
            jac_fn=self.jac if m.jac_fn is not None else None,
            energy_bounded=m.energy_bounded, reciprocal=False, unit=m.unit,
            validity=m.validity, reference=m.reference,
            description=f"{m.description} Averaged over the beam footprint seen through a "
            f"{r.aperture_diameter_mm:g} mm receiver at {r.distance_mm:g} mm "
            f"({self.label}).")
