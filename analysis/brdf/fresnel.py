"""Fresnel reflection at a planar interface with a complex refractive index.

Conventions
-----------
* Time dependence exp(−iωt), hence an absorbing medium has index **n̂ = n + ik with k ≥ 0**
  (physics texts; Mitsuba and ellipsometry use exp(+iωt) and n − ik — pass
  ``np.conj`` of such an index: intensities agree, phases change sign).
* ``n`` is the *relative* index n_t / n_i (incident medium index 1 by default).
* n̂ cos θt = √(n̂² − sin²θi), principal square root (Im ≥ 0 for k ≥ 0): Born & Wolf,
  *Principles of Optics*.
* r_s = (cos θi − n̂ cos θt) / (cos θi + n̂ cos θt),
  r_p = (n̂² cos θi − n̂ cos θt) / (n̂² cos θi + n̂ cos θt).
  With these signs r_p = −r_s at normal incidence and r_p = r_s = −1 at grazing incidence.
* R_s = |r_s|², R_p = |r_p|², unpolarised R = (R_s + R_p)/2. The ellipsometric phase
  difference is Δ = arg(r_p / r_s).

Limits checked by the tests: R(0) = ((n−1)² + k²)/((n+1)² + k²); R_p = 0 at Brewster's
angle tan θB = n for a dielectric; R → 1 at grazing; total internal reflection for n < 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class FresnelResult:
    """Amplitude and power reflection coefficients, all of the broadcast input shape.

    Attributes
    ----------
    rs, rp : complex ndarray
        Amplitude reflection coefficients (sign convention in the module docstring).
    Rs, Rp, R : ndarray
        Power reflectances for s, p and unpolarised light.
    delta : ndarray
        Δ = arg(r_p / r_s) in radians, in (−π, π].
    """

    rs: NDArray[np.complex128]
    rp: NDArray[np.complex128]
    Rs: NDArray[np.float64]
    Rp: NDArray[np.float64]
    R: NDArray[np.float64]
    delta: NDArray[np.float64]


def _safe_ratio(num: NDArray[Any], den: NDArray[Any]) -> NDArray[Any]:
    # den = 0 only for n = 1 at exactly grazing incidence (no interface); the limit
    # along grazing is −1 there, as for every other index.
    ok = den != 0
    return np.where(ok, num / np.where(ok, den, 1.0), -1.0 + 0j)


def fresnel(cos_theta_i: ArrayLike, n: complex | ArrayLike) -> FresnelResult:
    """Full complex-index Fresnel coefficients (Born & Wolf, *Principles of Optics*).

    Parameters
    ----------
    cos_theta_i : array_like
        cos θi in [0, 1] (values are clipped to that range).
    n : complex or array_like of complex
        Relative index n + ik (k ≥ 0), broadcast against ``cos_theta_i``.

    Returns
    -------
    FresnelResult
    """
    c = np.clip(np.asarray(cos_theta_i, dtype=float), 0.0, 1.0)
    nn = np.asarray(n, dtype=complex)
    s2 = 1.0 - c * c
    nct = np.sqrt(nn * nn - s2)  # principal branch, Im >= 0 for k >= 0
    rs = _safe_ratio(c - nct, c + nct)
    n2c = nn * nn * c
    rp = _safe_ratio(n2c - nct, n2c + nct)
    Rs = np.abs(rs) ** 2
    Rp = np.abs(rp) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        delta = np.angle(rp * np.conj(rs))
    return FresnelResult(rs=rs, rp=rp, Rs=Rs, Rp=Rp, R=0.5 * (Rs + Rp), delta=delta)


def fresnel_unpolarized(cos_theta_i: ArrayLike, n: complex | ArrayLike) -> NDArray[np.float64]:
    """Unpolarised reflectance (R_s + R_p)/2 (see :func:`fresnel`)."""
    return fresnel(cos_theta_i, n).R


def fresnel_unpolarized_dn(
    cos_theta_i: ArrayLike, n: complex | ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(R, ∂R/∂n, ∂R/∂k) of the unpolarised reflectance for n̂ = n + ik (analytic).

    With u = n̂ cos θt = √(n̂² − sin²θi) and du/dn̂ = n̂/u, the amplitude coefficients of
    :func:`fresnel` are holomorphic in n̂ away from u = 0:

        dr_s/dn̂ = −2 cos θi n̂ / (u (cos θi + u)²),
        dr_p/dn̂ = 2 n̂ cos θi (2u² − n̂²) / (u (n̂² cos θi + u)²),

    (derived by hand from Born & Wolf §1.5.2, eqs. (20)–(21); checked against finite
    differences in the tests), so for |r|² with n̂ = n + ik: ∂|r|²/∂n = 2 Re(r̄ dr/dn̂) and
    ∂|r|²/∂k = 2 Re(r̄ · i dr/dn̂) = −2 Im(r̄ dr/dn̂). Singular only at u = 0 (n̂² = sin²θi,
    an index below 1 at the critical angle); callers keep n ≥ 1.
    """
    c = np.clip(np.asarray(cos_theta_i, dtype=float), 0.0, 1.0)
    nn = np.asarray(n, dtype=complex)
    u = np.sqrt(nn * nn - (1.0 - c * c))
    res = fresnel(c, nn)
    with np.errstate(divide="ignore", invalid="ignore"):
        drs = -2.0 * c * nn / (u * (c + u) ** 2)
        drp = 2.0 * nn * c * (2.0 * u * u - nn * nn) / (u * (nn * nn * c + u) ** 2)
    gs = np.conj(res.rs) * drs
    gp = np.conj(res.rp) * drp
    dn = np.real(gs + gp)  # ½(2 Re ḡs + 2 Re ḡp)
    dk = -np.imag(gs + gp)
    return res.R, np.nan_to_num(dn), np.nan_to_num(dk)


def normal_incidence_reflectance(n: complex | ArrayLike) -> NDArray[np.float64]:
    """R₀ = |(n̂ − 1)/(n̂ + 1)|² = ((n−1)² + k²)/((n+1)² + k²)."""
    nn = np.asarray(n, dtype=complex)
    return np.abs((nn - 1.0) / (nn + 1.0)) ** 2


def schlick(cos_theta_i: ArrayLike, r0: ArrayLike) -> NDArray[np.float64]:
    """Schlick's approximation R ≈ R₀ + (1 − R₀)(1 − cos θ)⁵ (Schlick, CGF 13(3) 1994).

    Only for comparison: it has no polarisation and errs by up to 0.09 for Al near 83°
    (tests/analysis/brdf/test_fresnel.py).
    """
    c = np.clip(np.asarray(cos_theta_i, dtype=float), 0.0, 1.0)
    r0a = np.asarray(r0, dtype=float)
    return r0a + (1.0 - r0a) * (1.0 - c) ** 5


def brewster_angle(n: float) -> float:
    """Brewster's angle arctan(n) in radians for a real relative index n."""
    return float(np.arctan(n))
