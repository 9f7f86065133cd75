"""Microfacet distributions, Smith masking and combined visibility terms.

A microfacet BRDF is f = F(cos β) · D(h) · V(ωi, ωr) with the *combined visibility*
V = G₂ / (4 μi μr) (Walter et al., EGSR 2007, eq. 20). Evaluating V as one
finite expression instead of G₂ and 1/(4μiμr) separately is what keeps every model finite at
grazing (Heitz, JCGT 3(2), 2014).

Normalisation of every distribution: ∫ D(h) cos θh dω_h = 1 (Walter et al., EGSR 2007).

All functions take cos θh (``c``), cos θ of the directions (``mu``) and widths as arrays that
broadcast together, and return arrays of the broadcast shape. Derivatives with respect to the
width parameter (``d…_dalpha``) are provided for analytic Jacobians in fitting.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.geometry import MU_FLOOR as MU_FLOOR  # re-exported: rough_surface uses it

_SQRT_PI = float(np.sqrt(np.pi))
_DEN_FLOOR = 1e-300


# --------------------------------------------------------------------------- distributions
def ggx_d(c: ArrayLike, alpha: ArrayLike) -> NDArray[np.float64]:
    """GGX / Trowbridge–Reitz D(h) = α² / (π (c²(α²−1) + 1)²) (Walter et al. 2007, eq. 33)."""
    c = np.asarray(c, dtype=float)
    a2 = np.asarray(alpha, dtype=float) ** 2
    t = c * c * (a2 - 1.0) + 1.0
    return a2 / (np.pi * t * t)


def ggx_d_dalpha(c: ArrayLike, alpha: ArrayLike) -> NDArray[np.float64]:
    """∂D_GGX/∂α = 2α/(π t²) · (1 − 2α²c²/t), t = c²(α²−1) + 1."""
    c = np.asarray(c, dtype=float)
    a = np.asarray(alpha, dtype=float)
    t = c * c * (a * a - 1.0) + 1.0
    return 2.0 * a / (np.pi * t * t) * (1.0 - 2.0 * a * a * c * c / t)


def beckmann_d(c: ArrayLike, alpha: ArrayLike, tan2: ArrayLike | None = None) -> NDArray[Any]:
    """Beckmann D(h) = exp(−tan²θh/α²) / (π α² cos⁴θh) (Beckmann & Spizzichino 1963;
    Walter et al. 2007, eq. 25). ``alpha`` is the rms slope m.

    ``tan2`` may be passed when tan²θh is known more accurately than from ``c``
    (e.g. :attr:`Geometry.tan2_theta_h`). Returns 0 where cos θh = 0 (exp underflows first).
    """
    c = np.asarray(c, dtype=float)
    a = np.asarray(alpha, dtype=float)
    cs = np.maximum(c, MU_FLOOR)
    t2 = (1.0 - cs * cs) / (cs * cs) if tan2 is None else np.asarray(tan2, dtype=float)
    # exp(-t2/a²)/c⁴ computed in log space: the ratio is finite but both factors may not be.
    with np.errstate(over="ignore"):
        logd = -t2 / (a * a) - 4.0 * np.log(cs)
    return np.exp(logd) / (np.pi * a * a)


def beckmann_d_dalpha(c: ArrayLike, alpha: ArrayLike,
                      tan2: ArrayLike | None = None) -> NDArray[Any]:
    """∂D_Beckmann/∂α = D (2 tan²θh/α³ − 2/α)."""
    c = np.asarray(c, dtype=float)
    a = np.asarray(alpha, dtype=float)
    cs = np.maximum(c, MU_FLOOR)
    t2 = (1.0 - cs * cs) / (cs * cs) if tan2 is None else np.asarray(tan2, dtype=float)
    d = beckmann_d(c, alpha, t2)
    # d is 0 wherever t2 is huge, so the product is finite.
    return d * (2.0 * np.minimum(t2, 1e300) / a**3 - 2.0 / a)


def blinn_phong_d(c: ArrayLike, s: ArrayLike) -> NDArray[np.float64]:
    """Normalised Blinn–Phong NDF D(h) = (s+2)/(2π) cos^s θh (Blinn 1977)."""
    c = np.clip(np.asarray(c, dtype=float), 0.0, 1.0)
    s = np.asarray(s, dtype=float)
    return (s + 2.0) / (2.0 * np.pi) * c**s


def blinn_phong_d_ds(c: ArrayLike, s: ArrayLike) -> NDArray[np.float64]:
    """∂D/∂s = D (1/(s+2) + ln cos θh) (0 where cos θh = 0)."""
    c = np.clip(np.asarray(c, dtype=float), 0.0, 1.0)
    s = np.asarray(s, dtype=float)
    d = blinn_phong_d(c, s)
    logc = np.log(np.where(c > 0, c, 1.0))
    return np.where(c > 0, d * (1.0 / (s + 2.0) + logc), 0.0)


def beckmann_slope_from_blinn(s: ArrayLike) -> NDArray[np.float64]:
    """Equivalent Beckmann rms slope α = √(2/(s+2)) of a Blinn–Phong exponent (Walter 2007)."""
    return np.sqrt(2.0 / (np.asarray(s, dtype=float) + 2.0))


# ---------------------------------------------------------------------- Smith Λ, times μ
def ggx_mu_lambda(mu: ArrayLike, alpha: ArrayLike) -> NDArray[np.float64]:
    """μ·Λ_GGX(μ) = (√(α² + (1−α²)μ²) − μ)/2, finite at μ = 0 (Heitz 2014, eq. 72)."""
    mu = np.asarray(mu, dtype=float)
    a2 = np.asarray(alpha, dtype=float) ** 2
    return 0.5 * (np.sqrt(a2 + (1.0 - a2) * mu * mu) - mu)


def beckmann_mu_lambda(mu: ArrayLike, alpha: ArrayLike) -> NDArray[np.float64]:
    """μ·Λ_Beckmann(μ) = μ(erf(a) − 1)/2 + α sinθ e^{−a²}/(2√π), a = μ/(α sinθ)
    (Heitz 2014, eq. 80, multiplied by μ so that it is finite at grazing)."""
    # imported where it is used: scipy.special costs about 1 s of CPU to import, which a
    # process that imports the models without a Beckmann term (the bench server) saves
    from scipy.special import erf

    mu = np.clip(np.asarray(mu, dtype=float), 0.0, 1.0)
    al = np.asarray(alpha, dtype=float)
    s = np.sqrt(np.clip(1.0 - mu * mu, 0.0, 1.0))
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        a = np.where(s > 0, mu / (al * np.where(s > 0, s, 1.0)), np.inf)
        e = np.exp(-np.minimum(a * a, 800.0))
    return 0.5 * mu * (erf(a) - 1.0) + al * s * e / (2.0 * _SQRT_PI)


def beckmann_mu_lambda_dalpha(mu: ArrayLike, alpha: ArrayLike) -> NDArray[np.float64]:
    """∂(μΛ_Beckmann)/∂α = sinθ e^{−a²}/(2√π) (derived by hand; checked against finite
    differences in the tests)."""
    mu = np.clip(np.asarray(mu, dtype=float), 0.0, 1.0)
    al = np.asarray(alpha, dtype=float)
    s = np.sqrt(np.clip(1.0 - mu * mu, 0.0, 1.0))
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        a = np.where(s > 0, mu / (al * np.where(s > 0, s, 1.0)), np.inf)
        e = np.exp(-np.minimum(a * a, 800.0))
    return s * e / (2.0 * _SQRT_PI)


def smith_g1(mu: ArrayLike, alpha: ArrayLike, *, distribution: str = "ggx") -> NDArray[Any]:
    """Smith masking G₁ = 1/(1 + Λ) = μ/(μ + μΛ) (Heitz 2014, eq. 43)."""
    mu = np.maximum(np.asarray(mu, dtype=float), MU_FLOOR)
    ml = _mu_lambda(distribution)(mu, alpha)
    return mu / (mu + ml)


def _mu_lambda(distribution: str) -> Callable[[ArrayLike, ArrayLike], NDArray[np.float64]]:
    if distribution == "ggx":
        return ggx_mu_lambda
    if distribution == "beckmann":
        return beckmann_mu_lambda
    raise ValueError(f"unknown distribution {distribution!r}; use 'ggx' or 'beckmann'")


# ------------------------------------------------------------------- combined visibility
def smith_visibility(
    mu_i: ArrayLike, mu_r: ArrayLike, alpha: ArrayLike, *, distribution: str = "ggx"
) -> NDArray[np.float64]:
    """Height-correlated Smith V = G₂/(4μiμr), G₂ = 1/(1 + Λi + Λr) (Heitz 2014, eq. 99).

    Written as V = 1/(4(μiμr + μr·μiΛi + μi·μrΛr)), whose terms are all finite at μ = 0;
    for GGX it reduces to 0.5/(μr√(α² + (1−α²)μi²) + μi√(α² + (1−α²)μr²)), finite at μ = 0
    (Heitz 2014).
    """
    mi = np.maximum(np.asarray(mu_i, dtype=float), MU_FLOOR)
    mr = np.maximum(np.asarray(mu_r, dtype=float), MU_FLOOR)
    if distribution == "ggx":
        a2 = np.asarray(alpha, dtype=float) ** 2
        si = np.sqrt(a2 + (1.0 - a2) * mi * mi)
        sr = np.sqrt(a2 + (1.0 - a2) * mr * mr)
        return 0.5 / np.maximum(mr * si + mi * sr, _DEN_FLOOR)
    ml = _mu_lambda(distribution)
    den = mi * mr + mr * ml(mi, alpha) + mi * ml(mr, alpha)
    return 0.25 / np.maximum(den, _DEN_FLOOR)


def smith_visibility_dalpha(
    mu_i: ArrayLike, mu_r: ArrayLike, alpha: ArrayLike, *, distribution: str = "ggx"
) -> NDArray[np.float64]:
    """∂V/∂α of :func:`smith_visibility` (analytic)."""
    mi = np.maximum(np.asarray(mu_i, dtype=float), MU_FLOOR)
    mr = np.maximum(np.asarray(mu_r, dtype=float), MU_FLOOR)
    a = np.asarray(alpha, dtype=float)
    if distribution == "ggx":
        a2 = a * a
        si = np.sqrt(a2 + (1.0 - a2) * mi * mi)
        sr = np.sqrt(a2 + (1.0 - a2) * mr * mr)
        den = np.maximum(mr * si + mi * sr, _DEN_FLOOR)
        dsi = a * (1.0 - mi * mi) / si
        dsr = a * (1.0 - mr * mr) / sr
        return -0.5 * (mr * dsi + mi * dsr) / den**2
    if distribution != "beckmann":
        raise ValueError(f"unknown distribution {distribution!r}")
    den = mi * mr + mr * beckmann_mu_lambda(mi, a) + mi * beckmann_mu_lambda(mr, a)
    den = np.maximum(den, _DEN_FLOOR)
    dden = mr * beckmann_mu_lambda_dalpha(mi, a) + mi * beckmann_mu_lambda_dalpha(mr, a)
    return -0.25 * dden / den**2


def ggx_smith_visibility_parts(
    mu_i: ArrayLike, mu_r: ArrayLike, alpha: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(V, Si, Sr) of the GGX height-correlated visibility, S = √(α² + (1−α²)μ²), so that
    :func:`ggx_smith_dv_dalpha` can reuse them (fitting evaluates both at the same α)."""
    mi = np.maximum(np.asarray(mu_i, dtype=float), MU_FLOOR)
    mr = np.maximum(np.asarray(mu_r, dtype=float), MU_FLOOR)
    a2 = alpha * alpha
    si = np.sqrt(a2 + (1.0 - a2) * mi * mi)
    sr = np.sqrt(a2 + (1.0 - a2) * mr * mr)
    return 0.5 / np.maximum(mr * si + mi * sr, _DEN_FLOOR), si, sr


def ggx_smith_dv_dalpha(
    mu_i: ArrayLike, mu_r: ArrayLike, alpha: float, v: NDArray[Any], si: NDArray[Any],
    sr: NDArray[Any],
) -> NDArray[np.float64]:
    """∂V/∂α = −2V² α (μr(1−μi²)/Si + μi(1−μr²)/Sr) from the parts above."""
    mi = np.maximum(np.asarray(mu_i, dtype=float), MU_FLOOR)
    mr = np.maximum(np.asarray(mu_r, dtype=float), MU_FLOOR)
    return -2.0 * alpha * v * v * (mr * (1.0 - mi * mi) / si + mi * (1.0 - mr * mr) / sr)


def separable_smith_visibility(
    mu_i: ArrayLike, mu_r: ArrayLike, alpha: ArrayLike, *, distribution: str = "beckmann"
) -> NDArray[np.float64]:
    """Uncorrelated Smith V = G₁(ωi)G₁(ωr)/(4μiμr) = 1/(4(μi + μiΛi)(μr + μrΛr))
    (Heitz 2014, eq. 98; the form of Beckmann's 1965 shadowing)."""
    mi = np.maximum(np.asarray(mu_i, dtype=float), MU_FLOOR)
    mr = np.maximum(np.asarray(mu_r, dtype=float), MU_FLOOR)
    ml = _mu_lambda(distribution)
    return 0.25 / np.maximum((mi + ml(mi, alpha)) * (mr + ml(mr, alpha)), _DEN_FLOOR)


def vcavity_visibility(
    mu_i: ArrayLike, mu_r: ArrayLike, cos_theta_h: ArrayLike, cos_beta: ArrayLike
) -> NDArray[np.float64]:
    """V-cavity V = G/(4μiμr), G = min(1, 2 cosθh μr / cos β, 2 cosθh μi / cos β)
    (Torrance & Sparrow 1967; Cook & Torrance 1982).

    Written as min(1/(4μiμr), cosθh/(2 cos β μi), cosθh/(2 cos β μr)), finite unless both
    μ vanish (then bounded by the μ floor).
    """
    mi = np.maximum(np.asarray(mu_i, dtype=float), MU_FLOOR)
    mr = np.maximum(np.asarray(mu_r, dtype=float), MU_FLOOR)
    ch = np.asarray(cos_theta_h, dtype=float)
    cb = np.maximum(np.asarray(cos_beta, dtype=float), MU_FLOOR)
    v1 = 0.25 / (mi * mr)
    v2 = ch / (2.0 * cb * mi)
    v3 = ch / (2.0 * cb * mr)
    return np.minimum(v1, np.minimum(v2, v3))


def vcavity_g1(mu: ArrayLike, cos_theta_h: ArrayLike, cos_beta: ArrayLike) -> NDArray[Any]:
    """V-cavity masking of one direction, min(1, 2 cosθh μ / cos β)."""
    mu = np.asarray(mu, dtype=float)
    cb = np.maximum(np.asarray(cos_beta, dtype=float), MU_FLOOR)
    return np.minimum(1.0, 2.0 * np.asarray(cos_theta_h, dtype=float) * mu / cb)
