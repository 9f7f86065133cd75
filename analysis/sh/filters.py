"""BRDF filters A_l = Λ_l ρ_l of radially symmetric reflection kernels, and the 9-term irradiance.

Reflection by a radially symmetric kernel is a spherical convolution B_lm = A_l L_lm
(Mahajan, Ramamoorthi & Curless 2006, eqs. 4–5; Ramamoorthi & Hanrahan 2001). For a zonal kernel
K(t), t = cos of the angle to the kernel axis, Funk–Hecke gives A_l = 2π ∫_{−1}^{1} K(t) P_l(t) dt.

* Lambertian (axis = normal, K = max(t, 0)): closed form (Ramamoorthi & Hanrahan
  2001, "An efficient representation for irradiance environment maps").
* Phong in the reflected parameterisation (axis = reflected view direction,
  K = (s+1)/(2π) max(t, 0)^s, normalised so A_0 = 1): the exact Γ-ratio (Funk–Hecke; derived
  here and checked against quadrature in tests/analysis/sh)
  and the approximation exp(−l(l+1)/(2s)).
* Torrance–Sparrow, Beckmann slope σ: the approximation exp(−σ² l(l+1)) (closer to quadrature;
  Ramamoorthi & Hanrahan give exp(−(σl)²), which is less accurate).

Factorials and powers are evaluated in log space with ``gammaln``: they overflow for l > 170.
Every filter reports its band limit (the last degree whose |A_l| is at least ``tol``·|A_0|).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.special import gammaln, gammasgn

from analysis.sh.validation import (
    SHInputError,
    check_coefficients,
    check_degree,
    check_finite,
    check_scalar,
)

__all__ = [
    "PHONG_EXACT_MAX",
    "SHFilter",
    "band_limit",
    "irradiance_9",
    "irradiance_constants",
    "kernel_energy_fraction",
    "lambertian_filter",
    "phong_filter",
    "torrance_sparrow_filter",
]


@dataclass(frozen=True)
class SHFilter:
    """A radially symmetric reflection filter.

    Attributes
    ----------
    name : str
    values : ndarray of shape (lmax+1,)
        A_l for l = 0 … lmax (B_lm = A_l L_lm).
    band_limit : int
        Last degree with |A_l| ≥ tol·|A_0| (the filter's effective band limit).
    tol : float
        The tolerance used for ``band_limit``.
    parameterisation : {"normal", "reflected"}
        The direction the kernel is centred on (surface normal or reflected view vector).
    exact : bool
        Whether ``values`` are exact or an approximation.
    """

    name: str
    values: np.ndarray
    band_limit: int
    tol: float
    parameterisation: Literal["normal", "reflected"]
    exact: bool


def band_limit(values: np.ndarray, *, tol: float = 1e-2) -> int:
    """Last degree l with |A_l| ≥ tol·|A_0| (0 when none beyond l = 0 qualifies)."""
    a = np.abs(check_finite("values", values, ndim=1))
    tol = _tol(tol)
    if a.size == 0:
        raise SHInputError("values", "must hold A_0 at least, got an empty array")
    keep = np.nonzero(a >= tol * a[0])[0]
    return int(keep.max()) if keep.size else 0


def _tol(tol: float) -> float:
    return check_scalar("tol", tol, low=0.0, high=1.0)


def lambertian_filter(lmax: int, *, tol: float = 1e-2) -> SHFilter:
    """Exact clamped-cosine filter Â_l (Ramamoorthi & Hanrahan 2001).

    Â_0 = π, Â_1 = 2π/3, Â_l = 0 for odd l > 1, and for even l ≥ 2
    Â_l = 2π (−1)^{l/2−1} / ((l+2)(l−1)) · C(l, l/2) / 2^l, with the binomial in log space.
    These multiply lighting coefficients to give irradiance E_lm = Â_l L_lm; for radiance of
    albedo ρ multiply by ρ/π.
    """
    lmax = check_degree("lmax", lmax)
    tol = _tol(tol)
    l = np.arange(lmax + 1, dtype=float)
    a = np.zeros(lmax + 1)
    a[0] = np.pi
    if lmax >= 1:
        a[1] = 2.0 * np.pi / 3.0
    even = (l >= 2) & (l % 2 == 0)
    le = l[even]
    log_binom = gammaln(le + 1.0) - 2.0 * gammaln(le / 2.0 + 1.0) - le * np.log(2.0)
    sign = np.where((le / 2.0 - 1.0) % 2 == 0, 1.0, -1.0)
    a[even] = 2.0 * np.pi * sign / ((le + 2.0) * (le - 1.0)) * np.exp(log_binom)
    return SHFilter("lambertian", a, band_limit(a, tol=tol), tol, "normal", True)


def kernel_energy_fraction(values: np.ndarray, total: float) -> np.ndarray:
    """Cumulative fraction of a zonal kernel's energy ∫K² dω = Σ (2l+1) A_l²/(4π) up to each l.

    For the clamped cosine ``total`` is 2π/3 (87.50 % at l ≤ 1,
    99.22 % at l ≤ 2).
    """
    a = check_finite("values", values, ndim=1)
    total = check_scalar("total", total, low=0.0, low_open=True)
    l = np.arange(a.size)
    return np.cumsum((2 * l + 1) * a**2 / (4.0 * np.pi)) / total


#: Largest Phong exponent of the exact filter: its log-Γ terms (≈ s ln s) cancel, leaving
#: a relative error ≈ s ln s · ε (4e-8 here); beyond, use ``exact=False`` (a near-mirror).
PHONG_EXACT_MAX = 1e7


def phong_filter(lmax: int, s: float, *, exact: bool = True, tol: float = 1e-2) -> SHFilter:
    """Phong filter in the reflected parameterisation, A_0 = 1 (Ramamoorthi & Hanrahan 2001).

    Exact::

        A_l = (s+1) ∫₀¹ x^s P_l(x) dx
            = (s+1) √π Γ(s+1) / (2^{s+1} Γ((s−l)/2+1) Γ((s+l+3)/2)),

    evaluated in log space with the sign of 1/Γ((s−l)/2+1) from ``gammasgn``; the poles of
    that Γ (integer s, l > s, l − s even) are exact zeros. Approximate:
    exp(−l(l+1)/(2s)), better than R&H's exp(−l²/(2s)) for s ≳ 30.

    Parameters
    ----------
    lmax : int
    s : float
        Phong exponent > 0; at most :data:`PHONG_EXACT_MAX` for the exact filter.
    exact : bool
    """
    lmax = check_degree("lmax", lmax)
    s = check_scalar("s", s, low=0.0, low_open=True,
                     high=PHONG_EXACT_MAX if exact else None)
    tol = _tol(tol)
    l = np.arange(lmax + 1, dtype=float)
    if not exact:
        a = np.exp(-l * (l + 1.0) / (2.0 * s))
        return SHFilter(f"phong(s={s:g}) approx", a, band_limit(a, tol=tol), tol,
                        "reflected", False)
    arg = (s - l) / 2.0 + 1.0
    pole = (arg <= 0) & (arg == np.round(arg))
    safe_arg = np.where(pole, 0.5, arg)
    log_mag = (
        np.log(s + 1.0)
        + 0.5 * np.log(np.pi)
        + gammaln(s + 1.0)
        - (s + 1.0) * np.log(2.0)
        - gammaln(safe_arg)
        - gammaln((s + l + 3.0) / 2.0)
    )
    a = np.where(pole, 0.0, gammasgn(safe_arg) * np.exp(log_mag))
    return SHFilter(f"phong(s={s:g})", a, band_limit(a, tol=tol), tol, "reflected", True)


def torrance_sparrow_filter(lmax: int, sigma: float, *, tol: float = 1e-2) -> SHFilter:
    """Approximate Torrance–Sparrow filter exp(−σ² l(l+1)), σ the Beckmann slope.

    Valid near normal exitance (by quadrature: 0.942, 0.743, 0.334 at
    l = 2, 5, 10 for σ = 0.1 against 0.942, 0.741, 0.333); the lobe is not isotropic away from
    it, so this is an approximation by construction.
    """
    lmax = check_degree("lmax", lmax)
    sigma = check_scalar("sigma", sigma, low=0.0, low_open=True)
    tol = _tol(tol)
    l = np.arange(lmax + 1, dtype=float)
    a = np.ones(lmax + 1)
    a[1:] = np.exp(-(sigma * sigma) * (l[1:] * (l[1:] + 1.0)))  # l = 0 apart: σ² may be inf
    return SHFilter(f"torrance-sparrow(σ={sigma:g})", a, band_limit(a, tol=tol), tol,
                    "reflected", False)


def irradiance_constants() -> tuple[float, float, float, float, float]:
    """(c1 … c5) of R&H 2001 eq. 13, unrounded: products of Â_l and real-SH constants."""
    a0, a1, a2 = np.pi, 2.0 * np.pi / 3.0, np.pi / 4.0
    y22 = 0.25 * np.sqrt(15.0 / np.pi)
    y1 = np.sqrt(3.0 / (4.0 * np.pi))
    y20 = 0.25 * np.sqrt(5.0 / np.pi)
    y00 = 0.5 / np.sqrt(np.pi)
    return a2 * y22, a1 * y1 / 2.0, 3.0 * a2 * y20, a0 * y00, a2 * y20


def irradiance_9(lighting: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Irradiance E(n) from the 9 lighting coefficients (R&H 2001 eq. 13).

    E(n) = c1 L22 (x²−y²) + c3 L20 z² + c4 L00 − c5 L20
           + 2 c1 (L2,−2 xy + L21 xz + L2,−1 yz) + 2 c2 (L11 x + L1,−1 y + L10 z).

    Parameters
    ----------
    lighting : ndarray of shape (≥9,)
        Real lighting coefficients (project convention); only l ≤ 2 are used.
    normals : ndarray of shape (..., 3)
        Unit normals.

    Returns
    -------
    ndarray of shape (...)
        Irradiance; multiply by ρ/π for the radiance of a Lambertian surface of albedo ρ.
    """
    c, _ = check_coefficients("lighting", lighting)
    if c.ndim != 1 or c.size < 9:
        raise SHInputError("lighting", "must be one vector holding at least the 9 "
                           f"coefficients of l ≤ 2, got shape {c.shape}")
    n = check_finite("normals", normals)
    if n.ndim == 0 or n.shape[-1] != 3:
        raise SHInputError("normals", f"must have shape (..., 3), got {n.shape}")
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    c1, c2, c3, c4, c5 = irradiance_constants()
    l00, l1m1, l10, l11, l2m2, l2m1, l20, l21, l22 = c[:9]
    return (
        c1 * l22 * (x * x - y * y)
        + c3 * l20 * z * z
        + c4 * l00
        - c5 * l20
        + 2.0 * c1 * (l2m2 * x * y + l21 * x * z + l2m1 * y * z)
        + 2.0 * c2 * (l11 * x + l1m1 * y + l10 * z)
    )
