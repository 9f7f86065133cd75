"""Real spherical-harmonic transforms: Gauss–Legendre grids with FFT in φ, and scattered fits.

Convention: :data:`analysis.sh.convention.PROJECT_CONVENTION` (real, orthonormal, no
Condon–Shortley phase, θ colatitude); coefficients in the flat layout ``l*l + l + m``.

Grid: L+1 Gauss–Legendre rings in θ (:func:`analysis.sh.legendre.gauss_legendre`) by
2L+1 equispaced longitudes φ_k = 2πk/(2L+1). For a function band-limited to degree L the
analysis on this grid is exact (the product of two degree-L harmonics has degree ≤ 2L, which
L+1 Gauss nodes integrate exactly in cos θ, and 2L+1 points exactly in φ) — the exact
quadrature numerics.md §4.3 asks for.

Algorithm (the standard "semi-naive" SHT, e.g. Reinecke 2011 arXiv:1010.2084 §2):
synthesis G_m(θ_j) = Σ_l Z_lm λ_l^m(cos θ_j) followed by an inverse real FFT per ring;
analysis by a real FFT per ring followed by the weighted Legendre sums. Rings come in
mirror pairs (θ, π−θ), and λ_l^m(−x) = (−1)^{l+m} λ_l^m(x), so the Legendre work is done on
the northern half only, split into even and odd l+m. The l-recurrence runs vectorised
over a block of orders m and all northern rings (:func:`analysis.sh.legendre.iterate_degrees`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from analysis.sh.convention import (
    PROJECT_CONVENTION,
    SHConvention,
    convert,
    degrees_orders,
    lm_index,
    lmax_from_size,
    n_coeffs,
)
from analysis.sh.legendre import gauss_legendre, iterate_degrees, sectoral_seeds

__all__ = [
    "GLGrid",
    "SHFit",
    "ScatteredFitOperator",
    "analysis",
    "directions_to_angles",
    "evaluate",
    "fit_scattered",
    "gl_grid",
    "real_sh_matrix",
    "scattered_fit_operator",
    "synthesis",
]

#: Target size in bytes of one (orders × northern rings) block of the recurrence.
_BLOCK_BYTES = 1 << 18
#: Degrees grouped per batched matrix product.
_K_BUFFER = 16
#: Largest Legendre table :func:`gl_grid` stores by default (L ≈ 400).
PLAN_MAX_BYTES = 1 << 27


@dataclass(frozen=True)
class GLGrid:
    """A Gauss–Legendre grid for band limit ``lmax``.

    Attributes
    ----------
    lmax : int
    theta : ndarray of shape (lmax+1,)
        Ring colatitudes, ascending (north to south).
    weights : ndarray of shape (lmax+1,)
        Gauss–Legendre weights in cos θ (sum 2).
    phi : ndarray of shape (2*lmax+1,)
        Longitudes 2πk/(2L+1).
    legendre : tuple of (m0, m1, ndarray of shape (m1−m0, L−m0+1, n_north)), or None
        Precomputed λ_{m+k}^m on the northern rings by blocks of orders (zero where
        m + k > L): a plan that turns both transforms into batched matrix products, like
        SHTOOLS' optional ``plx``. None: recomputed by the recurrence on every call.
    """

    lmax: int
    theta: np.ndarray = field(repr=False)
    weights: np.ndarray = field(repr=False)
    phi: np.ndarray = field(repr=False)
    legendre: tuple | None = field(default=None, repr=False, compare=False)

    @property
    def shape(self) -> tuple[int, int]:
        """(n_theta, n_phi) of maps on this grid."""
        return self.theta.size, self.phi.size


def gl_grid(lmax: int, *, precompute: bool | None = None) -> GLGrid:
    """The Gauss–Legendre grid that is exact for band limit ``lmax``.

    Parameters
    ----------
    lmax : int
    precompute : bool, optional
        Store the Legendre table with the grid (memory ≈ L³/4 · 8 bytes). Default: when it
        needs at most :data:`PLAN_MAX_BYTES`.
    """
    if lmax < 0:
        raise ValueError("lmax must be ≥ 0")
    theta, w = gauss_legendre(lmax + 1)
    nphi = 2 * lmax + 1
    phi = 2.0 * np.pi * np.arange(nphi) / nphi
    nh = (lmax + 2) // 2
    table_bytes = 8 * nh * (lmax + 1) * (lmax + 2) // 2
    if precompute is None:
        precompute = table_bytes <= PLAN_MAX_BYTES
    plan = None
    if precompute:
        th = theta[:nh]
        x, s = np.cos(th), np.sin(th)
        mant, expo = sectoral_seeds(s, lmax)
        blocks = []
        for m0, m1 in _blocks(lmax, nh):
            table = np.zeros((m1 - m0, lmax - m0 + 1, nh))
            for k, n, lam in iterate_degrees(m0, m1, lmax, x, mant[m0:m1], expo[m0:m1]):
                table[:n, k] = lam[:n]
            blocks.append((m0, m1, table))
        plan = tuple(blocks)
    return GLGrid(lmax=lmax, theta=theta, weights=w, phi=phi, legendre=plan)


def _legendre_chunks(grid: GLGrid, x: np.ndarray, s: np.ndarray):
    """(m0, m1, k0, buffer) over all orders, from the grid's plan or by the recurrence."""
    if grid.legendre is not None:
        for m0, m1, table in grid.legendre:
            yield m0, m1, 0, table
        return
    lmax = grid.lmax
    mant, expo = sectoral_seeds(s, lmax)
    for m0, m1 in _blocks(lmax, x.size):
        for k0, buf in _buffered_degrees(m0, m1, lmax, x, mant[m0:m1], expo[m0:m1]):
            yield m0, m1, k0, buf


@functools.lru_cache(maxsize=16)
def _z_layout(lmax: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Index maps between the flat layout and Z[m, k]: (m, k, flat +m, flat −m) over m ≤ l."""
    ar = np.arange(lmax + 1)
    m, k = np.nonzero(np.add.outer(ar, ar) <= lmax)
    l = m + k
    return m, k, lm_index(l, m), lm_index(l, -m)


def _coeffs_to_z(coeffs: np.ndarray, lmax: int) -> np.ndarray:
    """Flat real coefficients → Z[m, k] = c_{m+k,m} − i c_{m+k,−m} (k = l − m; c_{l,−0} ≡ 0)."""
    m, k, pos, neg = _z_layout(lmax)
    z = np.zeros((lmax + 1, lmax + 1), dtype=complex)
    z[m, k] = coeffs[pos] - 1j * np.where(m > 0, coeffs[neg], 0.0)
    return z


def _z_to_coeffs(z: np.ndarray, lmax: int) -> np.ndarray:
    """Inverse of :func:`_coeffs_to_z`."""
    m, k, pos, neg = _z_layout(lmax)
    out = np.zeros(n_coeffs(lmax))
    vals = z[m, k]
    out[pos] = vals.real
    has_sin = m > 0
    out[neg[has_sin]] = -vals.imag[has_sin]
    return out


def _blocks(lmax: int, n_rings: int) -> list[tuple[int, int]]:
    rows = max(4, _BLOCK_BYTES // (8 * max(n_rings, 1)))
    return [(m0, min(m0 + rows, lmax + 1)) for m0 in range(0, lmax + 1, rows)]


def _buffered_degrees(
    m0: int,
    m1: int,
    lmax: int,
    x: np.ndarray,
    seed_mant: np.ndarray,
    seed_exp: np.ndarray,
):
    """Group the recurrence steps of one block in buffers of shape (rows, kb, rings).

    Yields (k0, buffer) with buffer[:, i] = λ_{m+k0+i}^m; rows whose degree would exceed lmax
    hold finite stale values, to be multiplied by zero coefficients (synthesis) or discarded
    (analysis). Grouping lets one batched matrix product do the sums over l, which is far
    cheaper in numpy than one rank-1 update per degree.
    """
    rows = m1 - m0
    nk = lmax - m0 + 1
    kb_max = min(_K_BUFFER, nk)
    buf = np.zeros((rows, kb_max, x.size))
    k0 = 0
    for k, n, lam in iterate_degrees(m0, m1, lmax, x, seed_mant, seed_exp):
        buf[:n, k - k0] = lam[:n]
        if k - k0 + 1 == kb_max or k == nk - 1:
            yield k0, buf[:, : k - k0 + 1]
            k0 = k + 1
            kb_max = min(_K_BUFFER, nk - k0)
            if kb_max <= 0:
                return


def synthesis(
    coeffs: np.ndarray, *, grid: GLGrid, convention: SHConvention = PROJECT_CONVENTION
) -> np.ndarray:
    """Evaluate a real SH expansion on a Gauss–Legendre grid (inverse transform).

    Parameters
    ----------
    coeffs : ndarray of shape ((L+1)²,)
        Coefficients of a real function, ``L == grid.lmax``, in ``convention``.
    grid : GLGrid
    convention : SHConvention
        Convention of ``coeffs`` (converted at the boundary; the project's by default).

    Returns
    -------
    ndarray of shape (L+1, 2L+1)
        f(θ_j, φ_k).
    """
    c = np.asarray(coeffs)
    if convention != PROJECT_CONVENTION:
        c = convert(c, source=convention, target=PROJECT_CONVENTION)
    c = np.asarray(c, dtype=float)
    lmax = grid.lmax
    if c.shape != (n_coeffs(lmax),):
        raise ValueError(f"expected {(n_coeffs(lmax),)} coefficients, got {c.shape}")
    nlat, nphi = grid.shape
    nh = (nlat + 1) // 2
    th = grid.theta[:nh]
    x, s = np.cos(th), np.sin(th)
    z = _coeffs_to_z(c, lmax)
    # coefficient rows [Re even, Im even, Re odd, Im odd] for each order m and step k
    coef = np.zeros((lmax + 1, 4, lmax + 1))
    coef[:, 0, 0::2] = z.real[:, 0::2]
    coef[:, 1, 0::2] = z.imag[:, 0::2]
    coef[:, 2, 1::2] = z.real[:, 1::2]
    coef[:, 3, 1::2] = z.imag[:, 1::2]
    acc = np.zeros((lmax + 1, 4, nh))
    for m0, m1, k0, buf in _legendre_chunks(grid, x, s):
        kb = buf.shape[1]
        # a contiguous operand keeps numpy's matmul on the BLAS path
        acc[m0:m1] += np.matmul(np.ascontiguousarray(coef[m0:m1, :, k0 : k0 + kb]), buf)
    even = acc[:, 0] + 1j * acc[:, 1]
    odd = acc[:, 2] + 1j * acc[:, 3]
    g_n = even + odd
    g_s = even - odd
    # Real harmonics of order m > 0 carry √2; irfft divides by nphi and doubles m > 0.
    scale = np.full(lmax + 1, np.sqrt(2.0) * nphi / 2.0)
    scale[0] = nphi
    spec = np.zeros((nlat, nphi // 2 + 1), dtype=complex)
    spec[:nh, : lmax + 1] = (g_n * scale[:, None]).T
    south = (g_s * scale[:, None]).T
    # Southern ring j' = nlat−1−j mirrors northern ring j; the equator (odd nlat) is once.
    n_mirror = nlat - nh
    spec[nh:, : lmax + 1] = south[:n_mirror][::-1]
    return np.fft.irfft(spec, n=nphi, axis=1)


def analysis(
    values: np.ndarray, *, grid: GLGrid, convention: SHConvention = PROJECT_CONVENTION
) -> np.ndarray:
    """SH coefficients of a real map on a Gauss–Legendre grid (forward transform).

    Parameters
    ----------
    values : ndarray of shape (L+1, 2L+1)
    grid : GLGrid
    convention : SHConvention
        Convention of the returned coefficients (the project's by default).

    Returns
    -------
    ndarray of shape ((L+1)²,)
        Exact for maps band-limited to ``grid.lmax``; complex for a complex convention.
    """
    f = np.asarray(values, dtype=float)
    lmax = grid.lmax
    nlat, nphi = grid.shape
    if f.shape != (nlat, nphi):
        raise ValueError(f"expected a map of shape {(nlat, nphi)}, got {f.shape}")
    nh = (nlat + 1) // 2
    th = grid.theta[:nh]
    x, s = np.cos(th), np.sin(th)
    spec = np.fft.rfft(f, axis=1)[:, : lmax + 1]
    spec = spec * (grid.weights * 2.0 * np.pi / nphi)[:, None]
    north = spec[:nh]
    south = np.zeros_like(north)
    n_mirror = nlat - nh
    south[:n_mirror] = spec[nh:][::-1]
    f_even = (north + south).T  # (m, ring)
    f_odd = (north - south).T
    if nlat % 2 == 1:
        # The equator ring is its own mirror: count it once.
        f_even[:, nh - 1] = north[nh - 1]
        f_odd[:, nh - 1] = north[nh - 1]
    scale = np.full(lmax + 1, np.sqrt(2.0))
    scale[0] = 1.0
    f_even = f_even * scale[:, None]
    f_odd = f_odd * scale[:, None]
    # columns [Re even, Im even, Re odd, Im odd] per order and ring
    rhs = np.stack([f_even.real, f_even.imag, f_odd.real, f_odd.imag], axis=-1)
    z = np.zeros((lmax + 1, lmax + 1, 2))
    for m0, m1, k0, buf in _legendre_chunks(grid, x, s):
        kb = buf.shape[1]
        prod = np.matmul(buf, rhs[m0:m1])  # (rows, kb, 4)
        even = ((np.arange(k0, k0 + kb) & 1) == 0)[None, :]
        z[m0:m1, k0 : k0 + kb, 0] = np.where(even, prod[..., 0], prod[..., 2])
        z[m0:m1, k0 : k0 + kb, 1] = np.where(even, prod[..., 1], prod[..., 3])
    # Entries with m + k > L were computed from stale buffer rows: they are not coefficients.
    m_idx, k_idx = np.indices((lmax + 1, lmax + 1))
    z[m_idx + k_idx > lmax] = 0.0
    out = _z_to_coeffs(z[..., 0] + 1j * z[..., 1], lmax)
    if convention != PROJECT_CONVENTION:
        return convert(out, source=PROJECT_CONVENTION, target=convention)
    return out


def directions_to_angles(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (..., 3) → (θ colatitude from +z, φ azimuth from +x in [0, 2π))."""
    d = np.asarray(directions, dtype=float)
    norm = np.linalg.norm(d, axis=-1)
    # arctan2 keeps θ accurate near the poles, unlike arccos(z).
    theta = np.arctan2(np.hypot(d[..., 0], d[..., 1]), d[..., 2])
    phi = np.mod(np.arctan2(d[..., 1], d[..., 0]), 2.0 * np.pi)
    if np.any(norm == 0):
        raise ValueError("zero-length direction")
    return theta, phi


def _legendre_all_orders(lmax: int, theta: np.ndarray) -> np.ndarray:
    """λ_l^m at scattered points, table[l, m] of shape (L+1, L+1, N), all orders at once.

    The vectorised recurrence of the transforms; values below 2^−300 come back as 0, which
    is harmless in a design matrix (:func:`analysis.sh.legendre.legendre_table` keeps them).
    """
    x, s = np.cos(theta), np.sin(theta)
    mant, expo = sectoral_seeds(s, lmax)
    table = np.zeros((lmax + 1, lmax + 1, theta.size))
    m_all = np.arange(lmax + 1)
    for k, n, lam in iterate_degrees(0, lmax + 1, lmax, x, mant, expo):
        table[m_all[:n] + k, m_all[:n]] = lam[:n]
    return table


def real_sh_matrix(lmax: int, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Real orthonormal harmonics at scattered points (the design matrix of a fit).

    Parameters
    ----------
    lmax : int
    theta, phi : ndarray of shape (N,)
        Colatitude and azimuth in radians.

    Returns
    -------
    ndarray of shape (N, (lmax+1)²)
        Column ``l*l + l + m`` holds Y_lm (:mod:`analysis.sh.convention`).
    """
    th = np.atleast_1d(np.asarray(theta, dtype=float)).ravel()
    ph = np.atleast_1d(np.asarray(phi, dtype=float)).ravel()
    if th.shape != ph.shape:
        raise ValueError("theta and phi must have the same shape")
    table = _legendre_all_orders(lmax, th)
    y = np.empty((th.size, n_coeffs(lmax)))
    l_all, m_all = degrees_orders(lmax)
    for m in range(lmax + 1):
        l = np.arange(m, lmax + 1)
        lam = table[l, m].T  # (N, n_l)
        if m == 0:
            y[:, lm_index(l, 0)] = lam
        else:
            y[:, lm_index(l, m)] = np.sqrt(2.0) * lam * np.cos(m * ph)[:, None]
            y[:, lm_index(l, -m)] = np.sqrt(2.0) * lam * np.sin(m * ph)[:, None]
    del l_all, m_all
    return y


def evaluate(coeffs: np.ndarray, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Evaluate a real SH expansion at scattered points.

    Parameters
    ----------
    coeffs : ndarray of shape ((L+1)²,) or ((L+1)², K)
    theta, phi : ndarray of the same shape S

    Returns
    -------
    ndarray of shape S (or S + (K,))
    """
    c = np.asarray(coeffs, dtype=float)
    lmax = lmax_from_size(c.shape[0])
    th = np.asarray(theta, dtype=float)
    t_flat = th.ravel()
    p_flat = np.broadcast_to(np.asarray(phi, dtype=float), th.shape).ravel()
    out = np.empty((t_flat.size, *c.shape[1:]))
    # Points in chunks: the design matrix of a large image would not fit in memory.
    step = max(1, (1 << 21) // (lmax + 1) ** 2)
    for p0 in range(0, t_flat.size, step):
        sl = slice(p0, p0 + step)
        out[sl] = real_sh_matrix(lmax, t_flat[sl], p_flat[sl]) @ c
    return out.reshape(th.shape + c.shape[1:])


@dataclass(frozen=True)
class SHFit:
    """Result of a least-squares SH fit to scattered samples.

    Attributes
    ----------
    coeffs : ndarray of shape ((L+1)²,)
    coeff_std : ndarray of shape ((L+1)²,)
        Standard errors from the residual noise estimate and (AᵀWA + ridge·I)⁻¹.
    residual_rms : float
        Weighted rms of the residuals.
    noise_sigma : float
        Noise estimate σ̂ = √(Σ w r² / (N − dof)) in the units of the samples.
    rank : int
        Numerical rank of the weighted design matrix.
    condition : float
        Its 2-norm condition number (inf when rank-deficient).
    dof : float
        Effective number of fitted parameters, trace of the hat matrix.
    ridge : float
        The Tikhonov parameter actually used.
    n_samples : int
    """

    coeffs: np.ndarray
    coeff_std: np.ndarray
    residual_rms: float
    noise_sigma: float
    rank: int
    condition: float
    dof: float
    ridge: float
    n_samples: int


def fit_scattered(
    values: np.ndarray,
    theta: np.ndarray,
    phi: np.ndarray,
    *,
    lmax: int,
    mask: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    ridge: float = 0.0,
) -> SHFit:
    """Least-squares fit of real SH coefficients to masked scattered samples.

    Minimises Σ_i w_i (f_i − Σ c_lm Y_lm(θ_i, φ_i))² + ridge · Σ c_lm² over the samples with
    ``mask`` true (a camera sees only part of the sphere; numerics.md §2.2 warns that such
    coverage makes the design matrix rank-deficient, which the ridge term regularises).

    Parameters
    ----------
    values, theta, phi : ndarray of the same shape
    lmax : int
    mask : bool ndarray of the same shape, optional
        Samples to use (default: all finite values).
    weights : ndarray of the same shape, optional
        Sample weights w_i (e.g. solid angle per sample); default 1.
    ridge : float
        Tikhonov parameter ≥ 0 in the units of w·f²/c².

    Returns
    -------
    SHFit
    """
    f = np.asarray(values, dtype=float).ravel()
    th = np.asarray(theta, dtype=float).ravel()
    ph = np.asarray(phi, dtype=float).ravel()
    use = np.isfinite(f)
    if mask is not None:
        use &= np.asarray(mask, dtype=bool).ravel()
    w = np.ones_like(f) if weights is None else np.asarray(weights, dtype=float).ravel()
    use &= w > 0
    if ridge < 0:
        raise ValueError("ridge must be ≥ 0")

    if use.sum() == 0:
        raise ValueError("no usable samples")
    y = real_sh_matrix(lmax, th[use], ph[use])
    sw = np.sqrt(w[use])
    a = y * sw[:, None]
    b = f[use] * sw
    u, sv, vt = np.linalg.svd(a, full_matrices=False)
    tol = sv.max() * max(a.shape) * np.finfo(float).eps
    rank = int(np.sum(sv > tol))
    condition = float(sv.max() / sv.min()) if sv.min() > tol else float("inf")
    # Filter factors s/(s² + ridge) of the Tikhonov solution (exactly the pseudo-inverse when 0).
    with np.errstate(divide="ignore"):
        filt = np.where(sv > tol, sv / (sv**2 + ridge), 0.0)
    coeffs = vt.T @ (filt * (u.T @ b))
    hat = np.where(sv > tol, sv**2 / (sv**2 + ridge), 0.0)
    dof = float(hat.sum())
    resid = b - a @ coeffs
    n = int(use.sum())
    rms = float(np.sqrt(np.mean(resid**2)))
    sigma = float(np.sqrt(np.sum(resid**2) / max(n - dof, 1.0)))
    cov_diag = np.sum((vt.T * filt) ** 2, axis=1)
    return SHFit(
        coeffs=coeffs,
        coeff_std=sigma * np.sqrt(cov_diag),
        residual_rms=rms,
        noise_sigma=sigma,
        rank=rank,
        condition=condition,
        dof=dof,
        ridge=float(ridge),
        n_samples=n,
    )


@dataclass(frozen=True)
class ScatteredFitOperator:
    """The linear map samples → coefficients of a fixed scattered-sample geometry.

    Many images of one sphere geometry share the design matrix; this holds its regularised
    pseudo-inverse so each fit is one matrix product (:func:`scattered_fit_operator`).

    Attributes
    ----------
    lmax : int
    pinv : ndarray of shape ((L+1)², N)
        Coefficients = pinv @ (√w · values).
    sqrt_weights : ndarray of shape (N,)
    rank : int
    condition : float
    dof : float
    ridge : float
    """

    lmax: int
    pinv: np.ndarray = field(repr=False)
    sqrt_weights: np.ndarray = field(repr=False)
    rank: int
    condition: float
    dof: float
    ridge: float

    def apply(self, values: np.ndarray) -> np.ndarray:
        """Coefficients for samples of shape (N,) or (N, K) → ((L+1)²,) or ((L+1)², K)."""
        v = np.asarray(values, dtype=float)
        sw = self.sqrt_weights if v.ndim == 1 else self.sqrt_weights[:, None]
        return self.pinv @ (v * sw)


def scattered_fit_operator(
    theta: np.ndarray,
    phi: np.ndarray,
    *,
    lmax: int,
    weights: np.ndarray | None = None,
    ridge: float = 0.0,
) -> ScatteredFitOperator:
    """Precompute the (Tikhonov-regularised) least-squares fit of :func:`fit_scattered`.

    Parameters
    ----------
    theta, phi : ndarray of shape (N,)
        Sample directions (only the usable samples: no mask here).
    lmax : int
    weights : ndarray of shape (N,), optional
    ridge : float
    """
    th = np.asarray(theta, dtype=float).ravel()
    ph = np.asarray(phi, dtype=float).ravel()
    w = np.ones_like(th) if weights is None else np.asarray(weights, dtype=float).ravel()
    if ridge < 0:
        raise ValueError("ridge must be ≥ 0")
    sw = np.sqrt(w)
    a = real_sh_matrix(lmax, th, ph) * sw[:, None]
    u, sv, vt = np.linalg.svd(a, full_matrices=False)
    tol = sv.max() * max(a.shape) * np.finfo(float).eps
    rank = int(np.sum(sv > tol))
    condition = float(sv.max() / sv.min()) if sv.min() > tol else float("inf")
    with np.errstate(divide="ignore"):
        filt = np.where(sv > tol, sv / (sv**2 + ridge), 0.0)
    pinv = (vt.T * filt) @ u.T
    dof = float(np.sum(np.where(sv > tol, sv**2 / (sv**2 + ridge), 0.0)))
    return ScatteredFitOperator(lmax, pinv, sw, rank, condition, dof, float(ridge))
