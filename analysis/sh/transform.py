"""Real spherical-harmonic transforms: Gauss–Legendre grids with FFT in φ, and scattered fits.

Convention: :data:`analysis.sh.convention.PROJECT_CONVENTION` (real, orthonormal, no
Condon–Shortley phase, θ colatitude); coefficients in the flat layout ``l*l + l + m``.

Grid: L+1 Gauss–Legendre rings in θ (ducc0's nodes and weights,
:func:`analysis.sh.ducc.gl_nodes`, shared by both backends) by 2L+1 equispaced longitudes
φ_k = 2πk/(2L+1). For a function band-limited to degree L the
analysis on this grid is exact (the product of two degree-L harmonics has degree ≤ 2L, which
L+1 Gauss nodes integrate exactly in cos θ, and 2L+1 points exactly in φ) — an exact
quadrature, as high orders need (approximate ones leave a bias that iterations do not
remove).

Backends: :func:`synthesis` and :func:`analysis` run on ducc0 by default
(:mod:`analysis.sh.ducc`: conventions matched at the boundary, ``nthreads`` explicit);
``backend="reference"`` runs the project's own transform described below, kept as the
reference the ducc0 path is tested against. The scattered-point functions (``evaluate``,
``real_sh_matrix``, the fits) always use the own recurrences.

Algorithm of the reference (the standard "semi-naive" SHT, e.g. Reinecke 2011 arXiv:1010.2084 §2):
synthesis G_m(θ_j) = Σ_l Z_lm λ_l^m(cos θ_j) followed by an inverse real FFT per ring;
analysis by a real FFT per ring followed by the weighted Legendre sums. Rings come in
mirror pairs (θ, π−θ), and λ_l^m(−x) = (−1)^{l+m} λ_l^m(x), so the Legendre work is done on
the northern half only, split into even and odd l+m. The l-recurrence runs vectorised
over a block of orders m and all northern rings, 32 degrees at a time
(:func:`analysis.sh.legendre.degree_chunks`), and each chunk's sums over l are two batched
BLAS products (even and odd l+m), so numpy does ~3 contiguous passes plus one matrix
product per Legendre value. Polar rings whose values are all below 2^−300 in a chunk
are left out, as libsharp skips them (Reinecke 2011 §3.1.1).

Cached per grid: the sectoral seeds and recurrence coefficients (:func:`_recurrence_setup`,
≈ 16·L²·(1/2 + 1) bytes, 67 MB at L = 2048, two grids kept). Stored with the grid on
request (``gl_grid(precompute=...)``, by default up to L ≈ 400 when the reference is the
module's backend): for L ≲ 64 one dense
λ table on all rings, so that each transform is one batched product and two FFT calls
(numpy call overhead dominates there), else the recurrence's chunks on the northern rings.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.fft
from numpy.typing import ArrayLike

from analysis.sh.convention import (
    PROJECT_CONVENTION,
    SHConvention,
    convert,
    degrees_orders,
    lm_index,
    n_coeffs,
)
from analysis.sh.ducc import (
    ducc_analysis,
    ducc_synthesis,
    gl_nodes,
    resolve,
    transform_defaults,
)
from analysis.sh.legendre import (
    chunk_scales,
    degree_chunks,
    iterate_degrees,
    sectoral_seeds,
)
from analysis.sh.validation import (
    SHInputError,
    check_coefficients,
    check_degree,
    check_finite,
    check_scalar,
)

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

#: Target size in bytes of one (orders × northern rings) slab of the recurrence buffer
#: (at most 64 orders); tuned on the 2-core dev box with ``benchmarks/bench_sht.py``.
_BLOCK_BYTES = 1 << 17
#: Degrees per chunk of the recurrence: the sums over l are matrix products over a chunk.
_CHUNK = 32
#: Largest Legendre table :func:`gl_grid` stores by default (L ≈ 400).
PLAN_MAX_BYTES = 1 << 27
#: Up to this size the stored table is one dense (orders × rings × degrees) array, so each
#: transform is a single batched matrix product (L ≲ 64).
_DENSE_MAX_BYTES = 1 << 22
#: Up to this L the dense table covers all rings (fewest numpy calls), above it the northern
#: half split by parity (half the memory traffic); the crossover measured near L = 48.
_DENSE_ALL_RINGS = 40


@dataclass(frozen=True)
class _DensePlan:
    """λ on the rings, zero-padded.

    Up to L = :data:`_DENSE_ALL_RINGS`, on all rings: syn[0][m, j, k] = s_m λ_{m+k}^m(θ_j)
    with s_m = n_φ (m = 0) or n_φ/√2 (m > 0), which folds the real-harmonic √2 and the
    1/n_φ of the inverse FFT into the table, and ana[0][m, k, j] = λ_{m+k}^m(θ_j) ·
    2π w_j/n_φ · (1 or √2): one matrix product per transform. Above, on the northern rings
    only, by parity p of k = l − m (k = 2i + p): syn[p][m, j, i], ana[p][m, i, j] — half
    the memory traffic for a few more (small) numpy calls. The equator ring of odd n_θ has
    no mirror and is counted once.
    """

    syn: tuple[np.ndarray, ...]
    ana: tuple[np.ndarray, ...]


@dataclass(frozen=True)
class _ChunkPlan:
    """Stored output of :func:`analysis.sh.legendre.degree_chunks` on the northern rings.

    chunks: tuple of (m0, k0, nc, n, mu of shape (nc, n, n_north), scale of shape (n, nc)).
    """

    chunks: tuple[Any, ...]


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
    legendre : object or None
        Precomputed Legendre functions on the rings (a plan that turns both transforms into
        batched matrix products, like SHTOOLS' optional ``plx``): a dense table for small L,
        else the recurrence's chunks on the northern rings. None: recomputed by the
        recurrence on every call. Private layout; test only for None.
    """

    lmax: int
    theta: np.ndarray = field(repr=False)
    weights: np.ndarray = field(repr=False)
    phi: np.ndarray = field(repr=False)
    legendre: object | None = field(default=None, repr=False, compare=False)

    @property
    def shape(self) -> tuple[int, int]:
        """(n_theta, n_phi) of maps on this grid."""
        return self.theta.size, self.phi.size


def gl_grid(lmax: int, *, precompute: bool | None = None) -> GLGrid:
    """The Gauss–Legendre grid that is exact for band limit ``lmax``.

    Parameters
    ----------
    lmax : int
        Band limit L ≥ 0.
    precompute : bool, optional
        Store the reference transform's Legendre table with the grid (memory ≈ L³/4 · 8
        bytes, twice that for L ≲ 64). Default: when the module's default backend is the
        reference (ducc0 needs no table) and the table needs at most
        :data:`PLAN_MAX_BYTES`.
    """
    lmax = check_degree("lmax", lmax)
    theta, w = gl_nodes(lmax + 1)
    nphi = 2 * lmax + 1
    phi = 2.0 * np.pi * np.arange(nphi) / nphi
    nh = (lmax + 2) // 2
    table_bytes = 8 * nh * (lmax + 1) * (lmax + 2) // 2
    if precompute is None:
        precompute = (transform_defaults().backend == "reference"
                      and table_bytes <= PLAN_MAX_BYTES)
    plan = None
    if precompute:
        grid = GLGrid(lmax=lmax, theta=theta, weights=w, phi=phi)
        if 8 * (lmax + 1) ** 2 * (lmax + 1) <= _DENSE_MAX_BYTES:
            plan = _dense_plan(grid)
        else:
            plan = _ChunkPlan(
                tuple(
                    (m0, k0, nc, n, skip, buf[2 : nc + 2, :n, skip:].copy(), sc[:n].copy())
                    for m0, k0, nc, n, skip, buf, sc in _recurrence_chunks(grid)
                )
            )
    return GLGrid(lmax=lmax, theta=theta, weights=w, phi=phi, legendre=plan)


def _dense_plan(grid: GLGrid) -> _DensePlan:
    lmax = grid.lmax
    nlat, nphi = grid.shape
    nh = (nlat + 1) // 2
    north = np.zeros((lmax + 1, nh, lmax + 1))
    for m0, k0, nc, n, skip, buf, sc in _recurrence_chunks(grid):
        lam = buf[2 : nc + 2, :n, skip:] * sc[:n].T[:, :, None]  # (nc, n, nh − skip)
        north[m0 : m0 + n, skip:, k0 : k0 + nc] = lam.transpose(1, 2, 0)
    m_idx, k_idx = np.indices((lmax + 1, lmax + 1))
    north[(m_idx + k_idx > lmax)[:, None, :].repeat(nh, axis=1)] = 0.0
    s_syn = np.full(lmax + 1, nphi / np.sqrt(2.0))
    s_syn[0] = nphi
    s_ana = np.full(lmax + 1, np.sqrt(2.0))
    s_ana[0] = 1.0
    if lmax <= _DENSE_ALL_RINGS:
        # λ_l^m(−x) = (−1)^{l+m} λ_l^m(x): the southern rings mirror the northern ones.
        sign = np.where(np.arange(lmax + 1) % 2 == 0, 1.0, -1.0)
        full = np.concatenate([north, (north * sign)[:, : nlat - nh][:, ::-1]], axis=1)
        wq = grid.weights * 2.0 * np.pi / nphi
        ana = (full * wq[None, :, None] * s_ana[:, None, None]).transpose(0, 2, 1)
        return _DensePlan(
            syn=(full * s_syn[:, None, None],), ana=(np.ascontiguousarray(ana),)
        )
    wq = grid.weights[:nh] * 2.0 * np.pi / nphi
    syn = north * s_syn[:, None, None]
    ana = (north * wq[None, :, None] * s_ana[:, None, None]).transpose(0, 2, 1)
    return _DensePlan(
        syn=(np.ascontiguousarray(syn[..., 0::2]), np.ascontiguousarray(syn[..., 1::2])),
        ana=(np.ascontiguousarray(ana[:, 0::2]), np.ascontiguousarray(ana[:, 1::2])),
    )


@functools.lru_cache(maxsize=2)
def _recurrence_setup(lmax: int, theta_key: bytes) -> tuple[Any, ...]:
    """Per-grid constants of the recurrence: northern x, seeds and per-block coefficients."""
    th = np.frombuffer(theta_key, dtype=float)
    x, s = np.cos(th), np.sin(th)
    mant, expo = sectoral_seeds(s, lmax)
    rows = min(64, max(4, _BLOCK_BYTES // (8 * max(th.size, 1))))
    blocks = []
    for m0 in range(0, lmax + 1, rows):
        m1 = min(m0 + rows, lmax + 1)
        blocks.append((m0, m1, chunk_scales(m0, m1, lmax, _CHUNK)))
    return x, mant, expo, tuple(blocks)


def _recurrence_chunks(grid: GLGrid) -> Iterator[tuple[Any, ...]]:
    """(m0, k0, nc, n, skip, buf, scale) from :func:`degree_chunks` over all blocks."""
    lmax = grid.lmax
    nh = (lmax + 2) // 2
    x, mant, expo, blocks = _recurrence_setup(lmax, grid.theta[:nh].tobytes())
    for m0, m1, coef in blocks:
        for k0, nc, n, skip, buf, sc in degree_chunks(
            m0, m1, lmax, x, mant[m0:m1], expo[m0:m1], chunk=_CHUNK, coefficients=coef
        ):
            yield m0, k0, nc, n, skip, buf, sc


def _chunks(grid: GLGrid) -> Iterator[tuple[Any, ...]]:
    """(m0, k0, nc, n, skip, mu (nc, n, n_north − skip), scale (n, nc)): stored or recomputed.

    Rings before ``skip`` (polar) hold only values below 2^−300 in this chunk.
    """
    if isinstance(grid.legendre, _ChunkPlan):
        yield from grid.legendre.chunks
        return
    for m0, k0, nc, n, skip, buf, sc in _recurrence_chunks(grid):
        yield m0, k0, nc, n, skip, buf[2 : nc + 2, :n, skip:], sc[:n]


@functools.lru_cache(maxsize=16)
def _layout(lmax: int, dense: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat coefficient l² + l + m ↔ entry of the working array Z.

    Z is (m, k, 2) for the dense plan and (m, parity of k, k // 2, 2) otherwise (k = l − m,
    last axis [Re, Im] of c_{l,m} − i c_{l,−m}). Returns (position of every flat coefficient
    in Z.ravel(), factor synthesis applies, factor analysis applies); the factors hold the
    sign of the sine part and, off the dense plan, the real-harmonic √2 and the 1/n_φ of
    the inverse FFT.
    """
    l_all, m_all = degrees_orders(lmax)
    m = np.abs(m_all)
    k = l_all - m
    part = (m_all < 0).astype(np.int64)
    nphi = 2 * lmax + 1
    if dense:
        pos = ((m * (lmax + 1) + k) * 2 + part).astype(np.int64)
        fac = np.where(m_all < 0, -1.0, 1.0)
        return pos, fac, fac.copy()
    nk2 = (lmax + 2) // 2
    pos = (((m * 2 + (k & 1)) * nk2 + (k >> 1)) * 2 + part).astype(np.int64)
    sign = np.where(m_all < 0, -1.0, 1.0)
    root = np.where(m > 0, np.sqrt(2.0), 1.0)
    return pos, sign * root * nphi / np.where(m > 0, 2.0, 1.0), sign * root


def synthesis(
    coeffs: np.ndarray,
    *,
    grid: GLGrid,
    convention: SHConvention = PROJECT_CONVENTION,
    backend: str | None = None,
    nthreads: int | None = None,
) -> np.ndarray:
    """Evaluate a real SH expansion on a Gauss–Legendre grid (inverse transform).

    Parameters
    ----------
    coeffs : ndarray of shape ((L+1)²,)
        Coefficients of a real function, ``L == grid.lmax``, in ``convention``; finite.
    grid : GLGrid
    convention : SHConvention
        Convention of ``coeffs`` (converted at the boundary; the project's by default).
    backend : {"ducc0", "reference"}, optional
        ducc0's compiled transform or the project's own (the reference it is tested
        against); default the module setting (:func:`analysis.sh.ducc.set_transform_defaults`,
        "ducc0" unless changed).
    nthreads : int, optional
        ducc0's threads (default the module setting, 1); the reference is single-threaded.

    Returns
    -------
    ndarray of shape (L+1, 2L+1)
        f(θ_j, φ_k).
    """
    if not isinstance(grid, GLGrid):
        raise SHInputError("grid", f"must be a GLGrid (gl_grid(L)), got {type(grid).__name__}")
    how, threads = resolve(backend, nthreads)
    dtype = complex if np.iscomplexobj(coeffs) else float
    c = check_finite("coeffs", coeffs, dtype=dtype)
    if convention is not PROJECT_CONVENTION and convention != PROJECT_CONVENTION:
        c = convert(c, source=convention, target=PROJECT_CONVENTION)
    c = np.asarray(c, dtype=float)
    lmax = grid.lmax
    if c.shape != ((lmax + 1) ** 2,):
        raise SHInputError("coeffs", f"must have shape {(n_coeffs(lmax),)} for the grid's "
                           f"L = {lmax}, got {c.shape}")
    if how == "ducc0":
        return ducc_synthesis(c, lmax, threads)
    return _reference_synthesis(c, grid)


def _reference_synthesis(c: np.ndarray, grid: GLGrid) -> np.ndarray:
    """The project's own synthesis (semi-naive, module docstring) of checked coefficients."""
    lmax = grid.lmax
    nlat, nphi = grid.shape
    nh = (nlat + 1) // 2
    plan = grid.legendre
    if isinstance(plan, _DensePlan):
        pos, fac, _ = _layout(lmax, True)
        z = np.zeros((lmax + 1, lmax + 1, 2))
        z.ravel()[pos] = c * fac
        if len(plan.syn) == 1:
            g = np.matmul(plan.syn[0], z)  # (m, ring, [Re, Im])
            spec = np.ascontiguousarray(g.transpose(1, 0, 2)).view(complex)[..., 0]
            return scipy.fft.irfft(spec, n=nphi, axis=1, workers=1, overwrite_x=True)
        g_e = np.matmul(plan.syn[0], z[:, 0::2])  # (m, northern ring, [Re, Im])
        g_o = np.matmul(plan.syn[1], z[:, 1::2])
        spec = np.empty((nlat, lmax + 1, 2))
        spec[:nh] = (g_e + g_o).transpose(1, 0, 2)
        spec[nh:] = (g_e - g_o)[:, : nlat - nh][:, ::-1].transpose(1, 0, 2)
        return scipy.fft.irfft(
            spec.view(complex)[..., 0], n=nphi, axis=1, workers=1, overwrite_x=True
        )
    nk2 = (lmax + 2) // 2
    pos, fac, _ = _layout(lmax, False)
    z = np.zeros((lmax + 1, 2, nk2, 2))
    z.ravel()[pos] = c * fac
    # coefficient rows [Re, Im] per order, parity and half-step: (m, parity, 2, k // 2)
    zt = z.transpose(0, 1, 3, 2)
    acc = np.zeros((2, lmax + 1, 2, nh))  # even / odd l − m, order, [Re, Im], ring
    for m0, k0, nc, n, skip, mu, sc in _chunks(grid):
        h0 = k0 // 2
        for p in (0, 1):
            nq = (nc + 1 - p) // 2
            if nq == 0:
                continue
            cf = zt[m0 : m0 + n, p, :, h0 : h0 + nq] * sc[:, None, p::2]
            acc[p, m0 : m0 + n, :, skip:] += np.matmul(cf, mu[p::2].transpose(1, 0, 2))
    g_n = acc[0] + acc[1]
    g_s = np.subtract(acc[0], acc[1], out=acc[1])
    spec = np.empty((nlat, lmax + 1, 2))
    spec[:nh] = g_n.transpose(2, 0, 1)
    # Southern ring j' = nlat−1−j mirrors northern ring j; the equator (odd nlat) is once.
    spec[nh:] = g_s.transpose(2, 0, 1)[: nlat - nh][::-1]
    return scipy.fft.irfft(
        spec.view(complex)[..., 0], n=nphi, axis=1, workers=1, overwrite_x=True
    )


def analysis(
    values: np.ndarray,
    *,
    grid: GLGrid,
    convention: SHConvention = PROJECT_CONVENTION,
    backend: str | None = None,
    nthreads: int | None = None,
) -> np.ndarray:
    """SH coefficients of a real map on a Gauss–Legendre grid (forward transform).

    Parameters
    ----------
    values : ndarray of shape (L+1, 2L+1)
        Finite map values.
    grid : GLGrid
    convention : SHConvention
        Convention of the returned coefficients (the project's by default).
    backend, nthreads
        As for :func:`synthesis`.

    Returns
    -------
    ndarray of shape ((L+1)²,)
        Exact for maps band-limited to ``grid.lmax``; complex for a complex convention.
    """
    if not isinstance(grid, GLGrid):
        raise SHInputError("grid", f"must be a GLGrid (gl_grid(L)), got {type(grid).__name__}")
    how, threads = resolve(backend, nthreads)
    f = check_finite("values", values)
    lmax = grid.lmax
    nlat, nphi = grid.shape
    if f.shape != (nlat, nphi):
        raise SHInputError("values", f"must be a map of shape {(nlat, nphi)} for the grid's "
                           f"L = {lmax}, got {f.shape}")
    out = ducc_analysis(f, lmax, threads) if how == "ducc0" else _reference_analysis(f, grid)
    if convention is not PROJECT_CONVENTION and convention != PROJECT_CONVENTION:
        return convert(out, source=PROJECT_CONVENTION, target=convention)
    return out


def _reference_analysis(f: np.ndarray, grid: GLGrid) -> np.ndarray:
    """The project's own analysis (semi-naive, module docstring) of a checked map."""
    lmax = grid.lmax
    nlat, nphi = grid.shape
    nh = (nlat + 1) // 2
    plan = grid.legendre
    # (ring, m) complex; n_φ // 2 + 1 = L + 1 columns
    spec = scipy.fft.rfft(f, axis=1, workers=1)
    if isinstance(plan, _DensePlan):
        pos, _, fac = _layout(lmax, True)
        s = np.ascontiguousarray(spec.T).view(float).reshape(lmax + 1, nlat, 2)
        if len(plan.ana) == 1:
            z = np.matmul(plan.ana[0], s)  # (m, k, [Re, Im])
        else:
            south = np.zeros((lmax + 1, nh, 2))
            south[:, : nlat - nh] = s[:, nh:][:, ::-1]
            z = np.empty((lmax + 1, lmax + 1, 2))
            z[:, 0::2] = np.matmul(plan.ana[0], s[:, :nh] + south)
            z[:, 1::2] = np.matmul(plan.ana[1], s[:, :nh] - south)
        out = z.ravel()[pos] * fac
    else:
        nk2 = (lmax + 2) // 2
        sv = spec.view(float).reshape(nlat, lmax + 1, 2)
        south = np.zeros((nh, lmax + 1, 2))
        south[: nlat - nh] = sv[nh:][::-1]
        wq = (grid.weights[:nh] * (2.0 * np.pi / nphi))[None, :, None]
        # (m, ring, [Re, Im]) for even and odd l − m; the equator ring (odd nlat) has no
        # mirror, so it enters both once.
        rhs = (
            np.ascontiguousarray((sv[:nh] + south).transpose(1, 0, 2)) * wq,
            np.ascontiguousarray((sv[:nh] - south).transpose(1, 0, 2)) * wq,
        )
        z = np.zeros((lmax + 1, 2, nk2, 2))
        for m0, k0, nc, n, skip, mu, sc in _chunks(grid):
            h0 = k0 // 2
            for p in (0, 1):
                nq = (nc + 1 - p) // 2
                if nq == 0:
                    continue
                prod = np.matmul(mu[p::2].transpose(1, 0, 2), rhs[p][m0 : m0 + n, skip:])
                z[m0 : m0 + n, p, h0 : h0 + nq] = prod * sc[:, p::2, None]
        pos, _, fac = _layout(lmax, False)
        out = z.ravel()[pos] * fac
    return out


def directions_to_angles(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (..., 3) → (θ colatitude from +z, φ azimuth from +x in [0, 2π))."""
    d = check_finite("directions", directions)
    if d.ndim == 0 or d.shape[-1] != 3:
        raise SHInputError("directions", f"must have shape (..., 3), got {d.shape}")
    norm = np.linalg.norm(d, axis=-1)
    # arctan2 keeps θ accurate near the poles, unlike arccos(z).
    theta = np.arctan2(np.hypot(d[..., 0], d[..., 1]), d[..., 2])
    phi = np.mod(np.arctan2(d[..., 1], d[..., 0]), 2.0 * np.pi)
    if np.any(norm == 0):
        raise SHInputError("directions", "holds a zero-length vector")
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
    lmax = check_degree("lmax", lmax)
    th = np.atleast_1d(check_finite("theta", theta)).ravel()
    ph = np.atleast_1d(check_finite("phi", phi)).ravel()
    if th.shape != ph.shape:
        raise SHInputError("phi", f"must have the shape of theta {th.shape}, got {ph.shape}")
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
    c, lmax = check_coefficients("coeffs", coeffs)
    th = check_finite("theta", theta)
    t_flat = th.ravel()
    ph = check_finite("phi", phi)
    try:
        p_flat = np.broadcast_to(ph, th.shape).ravel()
    except ValueError:
        raise SHInputError("phi", f"must broadcast to the shape of theta {th.shape}, got "
                           f"{ph.shape}") from None
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


def _tikhonov_svd(a: np.ndarray, ridge: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, float, float]:
    """SVD of the weighted design matrix and the Tikhonov filter factors.

    Returns (U, f, Vᵀ, rank, condition, dof) with f_i = s_i / (s_i² + ridge) (exactly the
    pseudo-inverse when ridge = 0), singular values below max(s)·max(shape)·ε treated as
    zero, and the effective degrees of freedom trace(hat) = Σ s_i² / (s_i² + ridge).
    """
    u, sv, vt = np.linalg.svd(a, full_matrices=False)
    tol = sv.max() * max(a.shape) * np.finfo(float).eps
    rank = int(np.sum(sv > tol))
    condition = float(sv.max() / sv.min()) if sv.min() > tol else float("inf")
    with np.errstate(divide="ignore"):
        filt = np.where(sv > tol, sv / (sv**2 + ridge), 0.0)
    dof = float(np.sum(np.where(sv > tol, sv**2 / (sv**2 + ridge), 0.0)))
    return u, filt, vt, rank, condition, dof


def _samples(theta: ArrayLike, phi: ArrayLike, weights: ArrayLike | None, n: int | None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Checked flat θ, φ and weights (≥ 0, default 1) of n samples (n: θ's size if None)."""
    th = check_finite("theta", theta).ravel()
    n = th.size if n is None else n
    if th.size != n:
        raise SHInputError("theta", f"must have {n} entries (one per value), got {th.size}")
    ph = check_finite("phi", phi).ravel()
    if ph.size != n:
        raise SHInputError("phi", f"must have {n} entries, got {ph.size}")
    if weights is None:
        return th, ph, np.ones(n)
    w = check_finite("weights", weights).ravel()
    if w.size != n:
        raise SHInputError("weights", f"must have {n} entries, got {w.size}")
    if np.any(w < 0):
        raise SHInputError("weights", "must be ≥ 0")
    return th, ph, w


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
    ``mask`` true (a camera sees only part of the sphere; such
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
    lmax = check_degree("lmax", lmax)
    f = np.asarray(values, dtype=float).ravel()
    th, ph, w = _samples(theta, phi, weights, f.size)
    ridge = check_scalar("ridge", ridge, low=0.0)
    # Non-finite sample values mark unusable data (documented): left out, not an error.
    use = np.isfinite(f)
    if mask is not None:
        m = np.asarray(mask, dtype=bool).ravel()
        if m.size != f.size:
            raise SHInputError("mask", f"must have {f.size} entries, got {m.size}")
        use &= m
    use &= w > 0

    if use.sum() == 0:
        raise SHInputError("values", "has no usable sample (finite, in mask, weight > 0)")
    y = real_sh_matrix(lmax, th[use], ph[use])
    sw = np.sqrt(w[use])
    a = y * sw[:, None]
    b = f[use] * sw
    u, filt, vt, rank, condition, dof = _tikhonov_svd(a, ridge)
    coeffs = vt.T @ (filt * (u.T @ b))
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
        v = check_finite("values", values)
        if v.ndim not in (1, 2) or v.shape[0] != self.sqrt_weights.size:
            raise SHInputError("values", f"must have shape ({self.sqrt_weights.size},) or "
                               f"({self.sqrt_weights.size}, K), got {v.shape}")
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
    lmax = check_degree("lmax", lmax)
    th, ph, w = _samples(theta, phi, weights, None)
    ridge = check_scalar("ridge", ridge, low=0.0)
    sw = np.sqrt(w)
    a = real_sh_matrix(lmax, th, ph) * sw[:, None]
    u, filt, vt, rank, condition, dof = _tikhonov_svd(a, ridge)
    pinv = (vt.T * filt) @ u.T
    return ScatteredFitOperator(lmax, pinv, sw, rank, condition, dof, float(ridge))
