"""The per-scan false-alarm rate of the localiser's search, from the statistic's smoothness.

The localiser reports a candidate when its significance ``s`` clears a threshold ``s*``
set so that noise alone exceeds it *somewhere in the searched region* with probability
α per scan (ADR 0032).  Noise alone makes the single-point statistic

    ``Z(x) = ⟨K_x, n⟩ / σ(x)``,   ``σ(x)² = K_xᵀ C K_x``,

a smooth Gaussian field of unit variance over the searched positions ``x = (y, z)``
(``K_x`` the point response on the rays, ``C`` the reconstruction's noise covariance,
:mod:`.significance`).  For such a field the probability that its maximum over a region
``S`` exceeds ``u`` is, for the high ``u`` a threshold needs, the expected Euler
characteristic of the excursion set (Adler & Taylor 2007, *Random Fields and Geometry*,
ch. 12; Worsley, Marrett, Neelin, Vandal, Friston & Evans 1996, "A unified statistical
approach for determining significant signals in images of cerebral activation", Hum.
Brain Mapp. 4, 58–73, the EC densities of a Gaussian field):

    ``P(max_S Z > u) ≈ E χ(A_u) = L₀ Q(u) + L₁ e^{−u²/2}/(2π) + L₂ u e^{−u²/2}/(2π)^{3/2}``

with ``Q`` the Gaussian upper tail and the Lipschitz–Killing curvatures of ``S`` in the
field's own metric ``Λ(x) = Var(∇Z(x))``: ``L₀`` its Euler characteristic (1, one
region), ``L₁`` half its boundary length, ``L₂ = ∫_S √det Λ dx`` its area.  ``Λ`` follows
from the same noise model and the responses' derivatives (the ``∂K/∂y``, ``∂K/∂z`` of
:func:`.ray_fit.ray_model`): with ``σ_i = K_iᵀ C K / σ``,

    ``Λ_ij = K_iᵀ C K_j / σ² − (K_iᵀ C K)(K_jᵀ C K) / σ⁴``.

This replaces the count of resolution cells (Bonferroni, ``N_cells Q(u)``), which assumed
one independent trial per theoretical cell ``δy × δz``: the statistic's correlation is not
that cell (across it falls within ≈ 0.6 δy, in depth it spans ≈ 2.4 δz/D², ADR 0032), and
the number of trials it implies differed from the field's by a factor that depends on the
wall (``benchmarks/bench_lightfield_null.py``, BENCHMARKS.md).  Nothing is fitted to seeds:
``L₁`` and ``L₂`` are computed per scan from the scan's own filter and noise power.

``Λ`` is evaluated on a coarse sub-grid of the search (``COARSE_Z`` depths and
``COARSE_Y`` positions across, evenly spread, the ends included) and interpolated
linearly in its logarithm against ``ln|z|`` (it varies as a power of the depth:
``√Λ_yy ∝ 1/δy ∝ 1/|z|``); the integrals are sums over the search grid's samples that the
caller marks as searched.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq
from scipy.special import ndtr

from .field import LightField2D
from .spectral import coefficients

__all__ = ["COARSE_Y", "COARSE_Z", "EulerTail", "StatisticMetric", "expected_euler",
           "lipschitz_killing", "statistic_metric"]

#: samples of the search grid where the field's metric is evaluated (depths, across)
COARSE_Z = 8
COARSE_Y = 10
#: complex values per chunk of positions in :func:`statistic_metric` (memory bound)
_CHUNK = 2_000_000


@dataclass(frozen=True)
class StatisticMetric:
    """Noise of the single-point statistic and of its gradient at K positions.

    Attributes
    ----------
    sigma : (K,) — ``√(K_xᵀ C K_x)``, the noise of the response's inner product
    metric : (K, 2, 2) — ``Λ = Var(∇Z)`` of the unit-variance statistic, (y, z) in mm⁻²
    """

    sigma: NDArray[np.float64]
    metric: NDArray[np.float64]


@dataclass(frozen=True)
class EulerTail:
    """The Lipschitz–Killing curvatures of a searched region in the statistic's metric.

    ``probability(u)`` is the expected Euler characteristic of the excursion above ``u``
    (the per-scan false-alarm probability of a threshold ``u``, capped at 1);
    ``threshold(α)`` the ``u`` where it equals α.
    """

    l0: float
    l1: float
    l2: float

    def expected(self, u: ArrayLike) -> NDArray[np.float64]:
        """``E χ(A_u)`` itself (not capped)."""
        # beyond 40σ every term is 0 in double precision (and ∞ · 0 would give NaN)
        s = np.minimum(np.asarray(u, dtype=float), 40.0)
        g = np.exp(-0.5 * s * s)
        return np.asarray(self.l0 * ndtr(-s) + self.l1 * g / (2.0 * np.pi)
                          + self.l2 * s * g / (2.0 * np.pi) ** 1.5, dtype=float)

    def probability(self, u: ArrayLike) -> NDArray[np.float64]:
        return np.clip(self.expected(u), 0.0, 1.0)

    def threshold(self, alpha: float) -> float:
        if not 0.0 < alpha < 1.0:
            raise ValueError(f"false_alarm {alpha:g} must be in (0, 1): a probability per "
                             f"scan")

        def excess(u: float) -> float:
            return float(self.expected(u)) - alpha

        # E χ falls monotonically for u ≥ 1 when L₁, L₂ ≥ 0; below 1 the formula is no
        # tail estimate, and a threshold there would claim nothing
        hi = 2.0
        while excess(hi) > 0.0 and hi < 40.0:
            hi *= 2.0
        return float(brentq(excess, 1.0, hi)) if excess(1.0) > 0.0 else 1.0


def _quadratic_forms(vectors: NDArray[Any], use: NDArray[np.bool_], v: NDArray[Any]
                     ) -> NDArray[np.float64]:
    """``V_aᵀ C V_b`` for the ray vectors ``vectors`` (A, K, R, n_use) at each of K
    positions: (K, A, A).  ``C`` is stationary in θ with order variances ``v`` (N,) and
    rows independent (:func:`.significance.amplitude_fit`'s model)."""
    n = use.size
    full = np.zeros((*vectors.shape[:3], n))
    full[..., use] = vectors
    m = coefficients(full, axis=-1)  # (A, K, R, N)
    return (n * n) * np.einsum("akrp,bkrp->kab", m * v, m.conj()).real


def statistic_metric(
    lf_wall: LightField2D, use: NDArray[np.bool_], phi: ArrayLike, noise_power: ArrayLike,
    pos: NDArray[Any],
) -> StatisticMetric:
    """``σ`` and ``Λ`` (module doc) of the point statistic at ``pos`` (K, 2) in (y, z) mm.

    ``phi`` and ``noise_power`` (N,) are the reconstruction's filter factors and
    ``σ_p²/|S_pp|²`` (fftfreq order; infinite noise where the filter passes nothing counts
    0), as for :func:`.significance.amplitude_fit`.  Where a position sees no ray
    (σ = 0) its metric is 0.
    """
    from .ray_fit import ray_model

    phi_ = np.asarray(phi, dtype=float)
    npw = np.broadcast_to(np.asarray(noise_power, dtype=float), phi_.shape)
    v = np.where((phi_ > 0) & np.isfinite(npw),
                 phi_**2 * np.where(np.isfinite(npw), npw, 0.0), 0.0)
    pos_ = np.asarray(pos, dtype=float).reshape(-1, 2)
    per = 3 * lf_wall.y_mm.size * use.size
    step = max(_CHUNK // max(per, 1), 1)
    parts = []
    for i in range(0, pos_.shape[0], step):
        r, d_y, d_z = ray_model(lf_wall, use, phi_, pos_[i:i + step])
        parts.append(_quadratic_forms(np.stack([r, d_y, d_z]), use, v))
    q = np.concatenate(parts) if parts else np.zeros((0, 3, 3))  # (K, 3, 3)
    s2 = q[:, 0, 0]
    ok = s2 > 0
    inv = np.where(ok, 1.0 / np.where(ok, s2, 1.0), 0.0)
    cross = q[:, 1:, 0]  # K_iᵀ C K
    lam = q[:, 1:, 1:] * inv[:, None, None] - cross[:, :, None] * cross[:, None, :] * (
        inv * inv)[:, None, None]
    return StatisticMetric(np.sqrt(np.clip(s2, 0.0, None)), lam)


def _coarse(n: int, count: int) -> NDArray[np.intp]:
    return np.unique(np.round(np.linspace(0, n - 1, max(min(n, count), 1))).astype(np.intp))


def expected_euler(
    lf_wall: LightField2D, use: NDArray[np.bool_], phi: ArrayLike, noise_power: ArrayLike,
    y_mm: ArrayLike, z_mm: ArrayLike, searched: NDArray[np.bool_],
) -> EulerTail:
    """The Lipschitz–Killing curvatures of the searched region (module doc).

    ``y_mm`` (N_y,) and ``z_mm`` (N_z,) are the search grid (uniform), ``searched``
    (N_z, N_y) the samples it searches.  Each sample stands for a cell ``Δy × Δz`` around
    it: ``L₂ = Σ √det Λ Δy Δz`` over the searched samples, ``L₁ = ½ Σ`` over their sides
    that border an unsearched sample or the grid's edge (``Δy √Λ_yy`` for a side along y,
    ``Δz √Λ_zz`` along z), ``L₀ = 1``.
    """
    from scipy.interpolate import RegularGridInterpolator

    y = np.asarray(y_mm, dtype=float)
    zs = np.asarray(z_mm, dtype=float)
    mask = np.asarray(searched, dtype=bool)
    if not mask.any():
        return EulerTail(0.0, 0.0, 0.0)
    iz, iy = _coarse(zs.size, COARSE_Z), _coarse(y.size, COARSE_Y)
    cz, cy = np.meshgrid(zs[iz], y[iy], indexing="ij")
    lam = statistic_metric(lf_wall, use, phi, noise_power,
                           np.column_stack([cy.ravel(), cz.ravel()])).metric
    lam = lam.reshape(iz.size, iy.size, 2, 2)
    det = np.clip(lam[..., 0, 0] * lam[..., 1, 1] - lam[..., 0, 1] ** 2, 0.0, None)
    tiny = 1e-300
    logs = 0.5 * np.log(np.stack([det, np.clip(lam[..., 0, 0], 0.0, None),
                                  np.clip(lam[..., 1, 1], 0.0, None)]) + tiny)
    # against ln|z| (the metric is a power of the depth), ascending for the interpolator
    lz = np.log(np.abs(zs))
    order = np.argsort(lz[iz])
    zz, yy = np.meshgrid(lz, y, indexing="ij")
    pts = np.column_stack([zz.ravel(), yy.ravel()])
    if iz.size > 1 and iy.size > 1:
        fields = [np.exp(RegularGridInterpolator((lz[iz][order], y[iy]), lg[order])(pts)
                         ).reshape(zz.shape) for lg in logs]
    else:  # a single depth or position: nearest coarse value
        jz = np.abs(zs[:, None] - zs[iz][None, :]).argmin(axis=1)
        jy = np.abs(y[:, None] - y[iy][None, :]).argmin(axis=1)
        fields = [np.exp(lg[np.ix_(jz, jy)]) for lg in logs]
    dy = float(abs(y[1] - y[0])) if y.size > 1 else 1.0
    dz = float(abs(zs[1] - zs[0])) if zs.size > 1 else 1.0
    root_det, root_yy, root_zz = fields
    return lipschitz_killing(root_det, root_zz, root_yy, mask, (dz, dy))


def lipschitz_killing(
    root_det: NDArray[Any], root_11: NDArray[Any], root_22: NDArray[Any],
    mask: NDArray[np.bool_], steps: tuple[float, float],
) -> EulerTail:
    """The curvatures of the region ``mask`` (N₁, N₂) on a grid of ``steps`` (Δ₁, Δ₂) in a
    metric given at each sample by ``√det Λ``, ``√Λ₁₁`` and ``√Λ₂₂`` (arrays like
    ``mask``): ``L₂ = Σ √det Λ Δ₁ Δ₂`` over the region's samples, ``L₁ = ½ Σ`` over their
    sides that border a sample outside it or the grid's edge (``Δ₂ √Λ₂₂`` for a side along
    axis 2, ``Δ₁ √Λ₁₁`` along axis 1), ``L₀ = 1`` (one region).  Each sample stands for the
    cell ``Δ₁ × Δ₂`` around it."""
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        return EulerTail(0.0, 0.0, 0.0)
    d1, d2 = steps
    l2 = float(np.sum(np.asarray(root_det)[m])) * d1 * d2
    padded = np.pad(m, 1, constant_values=False)
    inner = padded[1:-1, 1:-1]
    # a side along axis 2 borders the neighbour one step along axis 1, and conversely
    along_2 = (inner & ~padded[:-2, 1:-1]).astype(float) + (inner & ~padded[2:, 1:-1])
    along_1 = (inner & ~padded[1:-1, :-2]).astype(float) + (inner & ~padded[1:-1, 2:])
    l1 = 0.5 * float(np.sum(along_2 * np.asarray(root_22)) * d2
                     + np.sum(along_1 * np.asarray(root_11)) * d1)
    return EulerTail(1.0, l1, l2)
