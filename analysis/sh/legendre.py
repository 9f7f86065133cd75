"""Fully normalised associated Legendre functions by stable recurrences, and Gauss–Legendre nodes.

The functions are λ_l^m(cos θ) = √((2l+1)/(4π) (l−m)!/(l+m)!) P_l^m(cos θ), without the
Condon–Shortley phase (see :mod:`analysis.sh.convention`), so that
∫ λ_l^m(cos θ)² sin θ dθ = 1/(2π).

Recurrences (fully normalised three-term recurrences; Holmes &
Featherstone 2002):

* sectoral seed:  λ_0^0 = 1/√(4π),  λ_m^m = √((2m+1)/(2m)) sin θ · λ_{m−1}^{m−1};
* first step:     λ_{m+1}^m = √(2m+3) cos θ · λ_m^m;
* l-recurrence:   λ_l^m = a_lm (cos θ · λ_{l−1}^m − b_lm λ_{l−2}^m),
  a_lm = √((4l²−1)/(l²−m²)),  b_lm = √(((l−1)²−m²)/(4(l−1)²−1)).

Near the poles the sectoral seed sin^m θ underflows long before the values at higher l become
representable again (jmert/AssociatedLegendrePolynomials.jl #27). We carry a
separate integer exponent, the approach of libpsht/libsharp (Reinecke 2011,
arXiv:1010.2084 §3.1.1), which extends the range Holmes & Featherstone (2002, J. Geodesy 76,
279–299) obtain with a fixed 10^−280 scale factor: a value is stored as
``mantissa · 2^(600·e)`` with integer e ≤ 0; while e < 0 its magnitude is below 2^−300 and it
is left out of sums, and once the recurrence has grown the mantissa past 2^300 it is rescaled
and e incremented. No value is ever computed from sin^m θ directly or from factorials.

Two vectorised forms of the l-recurrence serve the transforms: :func:`iterate_degrees`
(one degree at a time, used for scattered points) and :func:`degree_chunks` (the
transforms' kernel: chunks of degrees in locally rescaled variables, see
:func:`chunk_scales`, so that numpy does two products and a difference per value on
contiguous arrays and the rescaling checks run once per chunk).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import ArrayLike

from analysis.sh.validation import SHInputError, check_degree, check_finite

__all__ = [
    "chunk_scales",
    "degree_chunks",
    "gauss_legendre",
    "iterate_degrees",
    "legendre_order",
    "legendre_table",
    "sectoral_seeds",
    "step_coefficients",
]

#: Exponent step of the scaled representation, in bits.
SCALE_BITS = 600
_BIG = 2.0**SCALE_BITS
_SMALL = 2.0**-SCALE_BITS
#: A scaled mantissa above this is rescaled (its true value is then ≥ 2^−300).
_UPPER = 2.0**300
#: A sectoral seed below this moves to the next (more negative) exponent.
_LOWER = 2.0**-450


def sectoral_seeds(sin_theta: np.ndarray, mmax: int) -> tuple[np.ndarray, np.ndarray]:
    """Sectoral values λ_m^m(θ) for m = 0 … mmax in scaled form.

    Parameters
    ----------
    sin_theta : ndarray of shape (N,)
        sin θ ≥ 0 at the evaluation points (pass sin θ computed from θ, not √(1−x²), so
        that points near the poles keep their relative accuracy).
    mmax : int

    Returns
    -------
    mantissa : ndarray of shape (mmax+1, N)
    exponent : ndarray of int64, shape (mmax+1, N)
        λ_m^m = mantissa · 2^(600·exponent); exponent ≤ 0.
    """
    sin_theta = check_finite("sin_theta", sin_theta)
    mmax = check_degree("mmax", mmax)
    s = np.asarray(sin_theta, dtype=float)
    mant = np.empty((mmax + 1, s.size))
    expo = np.zeros((mmax + 1, s.size), dtype=np.int64)
    cur = np.full(s.size, 1.0 / np.sqrt(4.0 * np.pi))
    cur_e = np.zeros(s.size, dtype=np.int64)
    mant[0] = cur
    for m in range(1, mmax + 1):
        cur = cur * (np.sqrt((2.0 * m + 1.0) / (2.0 * m)) * s)
        low = (np.abs(cur) < _LOWER) & (cur != 0.0)
        if low.any():
            cur = np.where(low, cur * _BIG, cur)
            cur_e = cur_e - low
        mant[m] = cur
        expo[m] = cur_e
    return mant, expo


def step_coefficients(m: ArrayLike, l: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients (a_lm, a_lm·b_lm) of the l-recurrence for l ≥ m+2 (arrays broadcast)."""
    m = np.asarray(m, dtype=float)
    l = np.asarray(l, dtype=float)
    a = np.sqrt((4.0 * l * l - 1.0) / ((l - m) * (l + m)))
    lm1 = l - 1.0
    b = np.sqrt(((lm1 - m) * (lm1 + m)) / (4.0 * lm1 * lm1 - 1.0))
    return a, a * b


def iterate_degrees(
    m0: int,
    m1: int,
    lmax: int,
    cos_theta: np.ndarray,
    seed_mant: np.ndarray,
    seed_exp: np.ndarray,
    *,
    check_every: int = 4,
) -> Iterator[tuple[int, int, np.ndarray]]:
    """Run the l-recurrence for orders m0 ≤ m < m1 at once, vectorised over orders and points.

    Yields, for k = l − m = 0, 1, …, (k, n_active, values) where ``values[:n_active]`` holds
    λ_{m+k}^m for the orders m0 … m0+n_active−1 (those with m + k ≤ lmax) at every point.
    Values whose true magnitude is below 2^−300 (still in scaled form) are yielded as 0:
    they cannot matter next to the O(1) values of the same transform. The yielded array is
    reused by the next step, so consumers must not keep a reference to it.

    Parameters
    ----------
    m0, m1 : int
        Orders to run (m0 < m1 ≤ lmax+1).
    lmax : int
    cos_theta : ndarray of shape (N,)
    seed_mant, seed_exp : ndarray of shape (m1−m0, N)
        Sectoral seeds for those orders from :func:`sectoral_seeds`.
    check_every : int
        Steps between rescaling checks; the growth over four steps stays far below the
        2^700 head-room between the rescale threshold and overflow.
    """
    x = np.asarray(cos_theta, dtype=float)[None, :]
    rows = m1 - m0
    m = np.arange(m0, m1, dtype=float)
    p2 = np.array(seed_mant, dtype=float, copy=True)
    e = np.array(seed_exp, dtype=np.int64, copy=True)
    scaled = bool((e < 0).any())
    live = (e == 0).astype(float) if scaled else None
    out = np.empty_like(p2)

    def emit(p: np.ndarray, n: int) -> np.ndarray:
        if live is None:
            return p
        np.multiply(p[:n], live[:n], out=out[:n])
        return out

    yield 0, rows, emit(p2, rows)
    n1 = min(m1, lmax) - m0  # rows with m+1 ≤ lmax
    if n1 <= 0:
        return
    p1 = np.empty_like(p2)
    p1[:n1] = np.sqrt(2.0 * m[:n1] + 3.0)[:, None] * x * p2[:n1]
    yield 1, n1, emit(p1, n1)
    tmp = np.empty_like(p2)
    # All step coefficients of the block at once (entries with m + k > lmax are unused).
    ks = np.arange(2, lmax - m0 + 1, dtype=float)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        a_tab, ab_tab = step_coefficients(m[None, :], m[None, :] + ks)
    for k in range(2, lmax - m0 + 1):
        n = min(m1, lmax - k + 1) - m0
        if n <= 0:
            break
        a, ab = a_tab[k - 2, :n], ab_tab[k - 2, :n]
        np.multiply(p1[:n], x, out=tmp[:n])
        tmp[:n] *= a[:, None]
        p2[:n] *= ab[:, None]
        np.subtract(tmp[:n], p2[:n], out=p2[:n])
        # p2 now holds λ_{m+k}; swap roles so p1 is the newest.
        p1, p2 = p2, p1
        if live is not None and k % check_every == 0:
            big = (e[:n] < 0) & (np.abs(p1[:n]) > _UPPER)
            if big.any():
                p1[:n][big] *= _SMALL
                p2[:n][big] *= _SMALL
                e[:n][big] += 1
                live[:n] = e[:n] == 0
                if live.all():
                    live = None
        yield k, n, emit(p1, n)


def legendre_order(m: int, lmax: int, theta: np.ndarray) -> np.ndarray:
    """λ_l^m(cos θ) for one order m and all degrees m ≤ l ≤ lmax.

    Parameters
    ----------
    m, lmax : int
        0 ≤ m ≤ lmax.
    theta : array_like of shape (N,)
        Colatitudes in radians, 0 ≤ θ ≤ π.

    Returns
    -------
    ndarray of shape (lmax−m+1, N)
        Row i holds degree l = m + i, to full relative precision down to the smallest
        normal double; values truly below it underflow gracefully (the scaled mantissa is
        converted with ``ldexp`` only at the end).
    """
    th = _check_theta(theta)
    lmax = check_degree("lmax", lmax)
    m = check_degree("m", m)
    if m > lmax:
        raise SHInputError("m", f"must be ≤ lmax = {lmax}, got {m}")
    x = np.cos(th)
    # The sectoral seed by the same scaled product as the transforms, for this m only.
    p2 = np.full(th.size, 1.0 / np.sqrt(4.0 * np.pi))
    e = np.zeros(th.size, dtype=np.int64)
    s = np.sin(th)
    for mm in range(1, m + 1):
        p2 = p2 * (np.sqrt((2.0 * mm + 1.0) / (2.0 * mm)) * s)
        low = (np.abs(p2) < _LOWER) & (p2 != 0.0)
        p2 = np.where(low, p2 * _BIG, p2)
        e = e - low
    out = np.empty((lmax - m + 1, th.size))
    out[0] = np.ldexp(p2, SCALE_BITS * e)
    if m == lmax:
        return out
    p1 = np.sqrt(2.0 * m + 3.0) * x * p2
    out[1] = np.ldexp(p1, SCALE_BITS * e)
    for l in range(m + 2, lmax + 1):
        a, ab = step_coefficients(m, l)
        p1, p2 = a * x * p1 - ab * p2, p1
        big = (e < 0) & (np.abs(p1) > _UPPER)
        if big.any():
            p1 = np.where(big, p1 * _SMALL, p1)
            p2 = np.where(big, p2 * _SMALL, p2)
            e = e + big
        out[l - m] = np.ldexp(p1, SCALE_BITS * e)
    return out


def _check_theta(theta: np.ndarray) -> np.ndarray:
    th = np.atleast_1d(check_finite("theta", theta))
    if th.ndim != 1:
        raise SHInputError("theta", f"must be one-dimensional, got shape {th.shape}")
    if np.any((th < 0) | (th > np.pi)):
        raise SHInputError("theta", "must hold colatitudes in [0, π]")
    return th


def legendre_table(lmax: int, theta: np.ndarray) -> np.ndarray:
    """λ_l^m(cos θ) for all 0 ≤ m ≤ l ≤ lmax at the given colatitudes.

    Parameters
    ----------
    lmax : int
    theta : array_like of shape (N,)
        Colatitudes in radians, 0 ≤ θ ≤ π.

    Returns
    -------
    ndarray of shape (lmax+1, lmax+1, N)
        ``table[l, m]``; entries with m > l are 0 (see :func:`legendre_order` for accuracy).
    """
    th = _check_theta(theta)
    lmax = check_degree("lmax", lmax)
    table = np.zeros((lmax + 1, lmax + 1, th.size))
    for m in range(lmax + 1):
        table[m:, m] = legendre_order(m, lmax, th)
    return table


def _legendre_and_theta_derivative(n: int, theta: np.ndarray
                                   ) -> tuple[np.ndarray, np.ndarray]:
    """P_n(cos θ) by the three-term (Bonnet) recurrence and dP_n/dθ, for n ≥ 1.

    dP_n/dθ = −sin θ P'_n(x) = −n (P_{n−1}(x) − x P_n(x)) / sin θ (A&S 8.5.4 with
    dx = −sin θ dθ).
    """
    x = np.cos(theta)
    p0 = np.ones_like(x)
    p1 = x.copy()
    for k in range(2, n + 1):
        p0, p1 = p1, ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k
    return p1, -n * (p0 - x * p1) / np.sin(theta)


def gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes as colatitudes θ_j (ascending) and weights w_j, for n points.

    Newton iteration on P_n(cos θ) in the variable θ, started from Tricomi's asymptotic
    approximation θ_j ≈ π(4j−1)/(4n+2) (Abramowitz & Stegun 22.16.6), with P_n and P_{n−1}
    from the three-term recurrence in x = cos θ. The rounding of x limits the polar nodes
    to an absolute error of about ε/θ (3.6e-14 rad, 3e-11 relative, at the first node for
    n = 2049 against mpmath), so the transform grids take ducc0's nodes instead
    (:func:`analysis.sh.ducc.gl_nodes`); this function stays as an independent check and
    for the simulator's quadrature. Weights
    w_j = 2 / ((dP_n/dθ)²) (A&S 25.4.29 with dx = −sin θ dθ), so Σ w_j = 2 and
    Σ_j w_j f(cos θ_j) = ∫_{−1}^{1} f(x) dx exactly for polynomials of degree ≤ 2n−1.

    Returns
    -------
    theta : ndarray of shape (n,)
    weights : ndarray of shape (n,)
    """
    n = check_degree("n", n, minimum=1)
    half = (n + 1) // 2
    j = np.arange(1, half + 1, dtype=float)
    theta = np.pi * (4.0 * j - 1.0) / (4.0 * n + 2.0)
    theta = theta + (n - 1.0) / (8.0 * n**3) * np.cos(theta) / np.maximum(np.sin(theta), 1e-300)
    for _ in range(100):
        pn, dp = _legendre_and_theta_derivative(n, theta)
        delta = pn / dp
        theta = theta - delta
        if np.max(np.abs(delta)) < 1e-15:
            break
    # One more evaluation at the converged nodes for the weights.
    _, dp = _legendre_and_theta_derivative(n, theta)
    w = 2.0 / dp**2
    # Mirror the northern nodes: θ → π − θ; the middle node (odd n) is θ = π/2 exactly.
    if n % 2 == 1:
        theta[-1] = 0.5 * np.pi
        th_all = np.concatenate([theta, np.pi - theta[-2::-1]])
        w_all = np.concatenate([w, w[-2::-1]])
    else:
        th_all = np.concatenate([theta, np.pi - theta[::-1]])
        w_all = np.concatenate([w, w[::-1]])
    return th_all, w_all


def chunk_scales(m0: int, m1: int, lmax: int, chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients of the locally rescaled l-recurrence run by :func:`degree_chunks`.

    Inside a chunk of ``chunk`` degrees starting at k0 (k = l − m, k0 a multiple of
    ``chunk``) the values are carried as μ_k = λ_{m+k}^m / A_k with
    A_k = Π_{j=k0}^{k} r_j, r_0 = 1, r_1 = √(2m+3), r_k = a_lm (k ≥ 2), so that the
    l-recurrence λ_l = a_lm (x λ_{l−1} − b_lm λ_{l−2}) of the module docstring becomes

        μ_k = x μ_{k−1} − β_k μ_{k−2},   β_k = a_lm b_lm A_{k−2} / A_k,

    (A_{k0−1} = A_{k0−2} = 1). The factor a_lm leaves the inner loop, which then costs two
    products and one difference per value; A (a product of at most ``chunk`` factors, far
    inside the double range) is folded into the coefficients of the transform instead. The
    seeds enter through k = 0 with μ_{−2} = λ_m^m, μ_{−1} = 0 and β_0 = −1.

    Returns
    -------
    beta : ndarray of shape (nk, m1−m0, 1)
    scale : ndarray of shape (m1−m0, nk)
        A_k for k = 0 … nk−1, nk = lmax − m0 + 1 (rows with m + k > lmax hold finite values
        of the recurrence continued past lmax).
    """
    m = np.arange(m0, m1, dtype=float)[:, None]
    nk = lmax - m0 + 1
    k = np.arange(nk, dtype=float)[None, :]
    l = m + k
    with np.errstate(invalid="ignore", divide="ignore"):
        a, ab = step_coefficients(m, l)
    r = np.where(k >= 2, a, 1.0)
    r[:, 1:2] = np.sqrt(2.0 * m + 3.0) if nk > 1 else r[:, 1:2]
    ab = np.where(k >= 2, ab, 0.0)
    ab[:, 0] = -1.0
    scale = np.empty_like(r)
    ratio = np.empty_like(r)  # A_k / A_{k−2}
    for k0 in range(0, nk, chunk):
        sl = slice(k0, min(k0 + chunk, nk))
        scale[:, sl] = np.cumprod(r[:, sl], axis=1)
        ratio[:, sl] = r[:, sl]
        ratio[:, k0 + 1 : sl.stop] *= r[:, k0 : sl.stop - 1]
    beta = (ab / ratio).T[:, :, None].copy()
    return beta, scale


def degree_chunks(
    m0: int,
    m1: int,
    lmax: int,
    cos_theta: np.ndarray,
    seed_mant: np.ndarray,
    seed_exp: np.ndarray,
    *,
    chunk: int,
    coefficients: tuple[np.ndarray, np.ndarray] | None = None,
) -> Iterator[tuple[int, int, int, int, np.ndarray, np.ndarray]]:
    """The l-recurrence for orders m0 ≤ m < m1 in chunks of degrees (the transforms' kernel).

    Same values as :func:`iterate_degrees`, computed as in :func:`chunk_scales` and handed
    out ``chunk`` degrees at a time so that the sums over l become matrix products. Each
    degree is a contiguous (orders × points) slab of the buffer: numpy's element-wise loops
    run several times faster on contiguous operands than on strided ones.

    Yields
    ------
    (k0, nc, n, skip, buf, scale)
        ``buf[2 + i, :n, skip:]`` holds μ_{k0+i} for i < nc, rows m0 … m0+n−1 (orders with
        m + k0 ≤ lmax; rows whose degree passes lmax inside the chunk hold finite values of
        the continued recurrence), and ``λ_{m+k0+i}^m = scale[:n, i] · buf[2 + i, :n]``.
        Values whose true magnitude is below 2^−300 (still in scaled form, see the module
        docstring) are yielded as 0, and the first ``skip`` points (polar rings where all
        of them are that small; the points must be ordered by distance from the nearer
        pole) are not filled in at all: their values are 0. ``buf`` (shape
        (chunk+2, m1−m0, N)) is reused by the next chunk.

    Parameters
    ----------
    m0, m1, lmax : int
    cos_theta : ndarray of shape (N,)
    seed_mant, seed_exp : ndarray of shape (m1−m0, N)
        Sectoral seeds from :func:`sectoral_seeds`.
    chunk : int
        Degrees per chunk (even, ≥ 2). Rescaling is checked once per chunk: the scaled
        values grow by far less than the 2^700 head-room between the rescale threshold and
        overflow over 64 steps (each step multiplies by at most a_lm(1 + b_lm) ≲ 2√(2m+3)).
    coefficients : (beta, scale), optional
        :func:`chunk_scales` of the same arguments, when the caller caches them.
    """
    x = np.asarray(cos_theta, dtype=float)
    rows, npt = m1 - m0, x.size
    nk = lmax - m0 + 1
    beta, scale = coefficients if coefficients is not None else chunk_scales(
        m0, m1, lmax, chunk
    )
    buf = np.empty((chunk + 2, rows, npt))
    tmp = np.empty((rows, npt))
    # x repeated over the rows: a full-size operand keeps the multiplication contiguous
    xs = np.repeat(x[None, :], rows, axis=0)
    buf[0] = seed_mant
    buf[1] = 0.0
    e = np.array(seed_exp, dtype=np.int64, copy=True)
    # Dead values (e < 0) sit on the polar rings: only the first n_dead columns need care.
    n_dead = _dead_columns(e)
    live = (e[:, :n_dead] == 0).astype(float)
    for k0 in range(0, nk, chunk):
        nc = min(chunk, nk - k0)
        n = min(m1, lmax - k0 + 1) - m0
        t, xn = tmp[:n], xs[:n]
        # views made once per chunk and positional out arguments: at ~10⁴ values per
        # operation numpy's per-call overhead is a sizeable share of the time
        slab = list(buf[: nc + 2, :n])
        bk = list(beta[k0 : k0 + nc, :n])
        mul, sub = np.multiply, np.subtract
        for i in range(nc):
            out = slab[i + 2]
            mul(slab[i + 1], xn, t)
            mul(slab[i], bk[i], out)
            sub(t, out, out)
        # Restart values for the next chunk: the true (scaled) λ of its two predecessors.
        if k0 + nc < nk:
            kl = k0 + nc  # here nc == chunk ≥ 2
            np.multiply(buf[nc, :n], scale[:n, kl - 2 : kl - 1], out=buf[0, :n])
            np.multiply(buf[nc + 1, :n], scale[:n, kl - 1 : kl], out=buf[1, :n])
        skip = 0
        if n_dead:
            d = n_dead
            # Leading rings dead for every row are left out (the caller skips them); the
            # rest of the polar band is masked.
            all_dead = (e[:n, :d] < 0).all(axis=0)
            skip = d if all_dead.all() else int(np.argmin(all_dead))
            buf[2 : nc + 2, :n, skip:d] *= live[:n, skip:d]
            p2, p1 = buf[0, :n, :d], buf[1, :n, :d]
            big = (e[:n, :d] < 0) & (np.abs(p1) > _UPPER)
            if big.any():
                p1[big] *= _SMALL
                p2[big] *= _SMALL
                e[:n, :d][big] += 1
                n_dead = _dead_columns(e[:n, :d])
                live = (e[:, :n_dead] == 0).astype(float)
        yield k0, nc, n, skip, buf, scale[:, k0 : k0 + nc]


def _dead_columns(e: np.ndarray) -> int:
    """1 + the last column holding a scaled (e < 0) value, 0 if none."""
    cols = np.flatnonzero((e < 0).any(axis=0))
    return int(cols[-1]) + 1 if cols.size else 0
