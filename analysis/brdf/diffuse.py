"""Diffuse and particulate models: Lambertian, Oren–Nayar, Lommel–Seeliger, Hapke.

Conventions: :mod:`analysis.brdf.geometry` (radians, polar angles from the normal, ωi and ωr
both pointing away from the surface). Values in 1/sr.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.geometry import MU_FLOOR, Geometry
from analysis.brdf.model import BRDFModel, ParamSpec

_INV_PI = 1.0 / np.pi


# ------------------------------------------------------------------------------ Lambertian
def lambertian() -> BRDFModel:
    """Lambertian f = ρ/π (Lambert 1760; Nicodemus et al. 1977). DHR = ρ for every θi."""

    def value(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        return np.full(g.shape, p[0] * _INV_PI)

    def jac(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        return np.full((*g.shape, 1), _INV_PI)

    return BRDFModel(
        name="lambert",
        params=(ParamSpec("rho", "1", 0.0, 10.0, 0.5, description="diffuse reflectance ρ"),),
        value_fn=value,
        jac_fn=jac,
        description="Lambertian diffuser, f = ρ/π.",
        validity="any geometry; energy bounded for ρ ≤ 1",
        reference="Lambert 1760",
    )


# ---------------------------------------------------------------------------- Oren–Nayar
def _on_ab(sigma: float) -> tuple[float, float, float, float]:
    s2 = sigma * sigma
    a = 1.0 - 0.5 * s2 / (s2 + 0.33)
    b = 0.45 * s2 / (s2 + 0.09)
    da = -0.33 * sigma / (s2 + 0.33) ** 2
    db = 0.45 * 2.0 * 0.09 * sigma / (s2 + 0.09) ** 2
    return a, b, da, db


def _on_term(g: Geometry) -> NDArray[Any]:
    # max(0, cos(φr−φi)) sin α tan β = max(0, xi xr + yi yr) / max(μi, μr): the stable form
    # (cos(φr−φi) sin θi sin θr = xi xr + yi yr), no tan β → ∞ at β → 90°.
    return np.maximum(0.0, g.xi * g.xr + g.yi * g.yr) / np.maximum(
        np.maximum(g.mu_i, g.mu_r), MU_FLOOR
    )


def oren_nayar() -> BRDFModel:
    """Oren–Nayar "qualitative" model (Oren & Nayar, SIGGRAPH 1994, eq. 30).

    f = ρ/π [A + B max(0, cos(φr−φi)) sin α tan β], A = 1 − 0.5σ²/(σ²+0.33),
    B = 0.45σ²/(σ²+0.09), α = max(θi, θr), β = min(θi, θr); σ is the facet-slope standard
    deviation in radians. σ = 0 gives the Lambertian ρ/π exactly.

    **Not energy conserving** (documented exception): with ρ = 1 the DHR is 0.78 at θi = 0
    and σ = 0.5, and exceeds 1 near grazing for σ ≈ 0.3 (1.004 at 89°,
    by quadrature in tests/analysis/brdf/test_models.py).
    """

    def value(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        a, b, _, _ = _on_ab(float(p[1]))
        return p[0] * _INV_PI * (a + b * _on_term(g))

    def jac(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        a, b, da, db = _on_ab(float(p[1]))
        t = _on_term(g)
        return np.stack([_INV_PI * (a + b * t), p[0] * _INV_PI * (da + db * t)], axis=-1)

    return BRDFModel(
        name="oren_nayar",
        params=(
            ParamSpec("rho", "1", 0.0, 10.0, 0.5, description="facet albedo ρ"),
            ParamSpec("sigma", "rad", 0.0, 1.5, 0.2, description="facet slope std σ"),
        ),
        value_fn=value,
        jac_fn=jac,
        energy_bounded=False,
        description="Oren–Nayar rough diffuse (qualitative model).",
        validity="rough diffuse surfaces, σ ≲ 0.6 rad; not energy conserving (DHR can exceed "
        "ρ near grazing); diverges as 1/max(μi, μr) only when both directions graze",
        reference="Oren & Nayar, SIGGRAPH 1994",
    )


# ----------------------------------------------------------------------- Lommel–Seeliger
def lommel_seeliger() -> BRDFModel:
    """Lommel–Seeliger f = (w/4π)/(μi + μr) (Hapke 2012 §8).

    DHR(μ0) = (w/2)[1 − μ0 ln((1+μ0)/μ0)] (:func:`lommel_seeliger_dhr`), ≤ w/2.
    """

    def value(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        return p[0] / (4.0 * np.pi) / (g.mu_i + g.mu_r)

    def jac(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        return (1.0 / (4.0 * np.pi) / (g.mu_i + g.mu_r))[..., None]

    return BRDFModel(
        name="lommel_seeliger",
        params=(ParamSpec("w", "1", 0.0, 1.0, 0.5, description="single-scattering albedo"),),
        value_fn=value,
        jac_fn=jac,
        description="Lommel–Seeliger single scattering by a particulate half-space.",
        validity="dark particulate surfaces (single scattering dominates); energy bounded",
        reference="Hapke, JGR 86(B4) 1981",
    )


def lommel_seeliger_dhr(mu0: ArrayLike, w: float) -> NDArray[np.float64]:
    """Closed-form DHR (w/2)[1 − μ0 ln((1+μ0)/μ0)]; the limit w/2 at μ0 = 0 is returned there."""
    m = np.asarray(mu0, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        xlog = np.where(m > 0, m * (np.log1p(m) - np.log(np.where(m > 0, m, 1.0))), 0.0)
    return 0.5 * w * (1.0 - xlog)


# --------------------------------------------------------------------------------- Hapke
def hapke_h2002(x: ArrayLike, w: float | ArrayLike) -> NDArray[np.float64]:
    """Hapke's 2002 approximation to Chandrasekhar's H function for isotropic scattering,
    H(x) ≈ [1 − w x (r₀ + (1 − 2r₀x)/2 · ln((1+x)/x))]⁻¹, r₀ = (1−γ)/(1+γ), γ = √(1−w)
    (Hapke, Icarus 157, 2002, eq. 13; within 1 % of the exact H for w ≤ 0.99, measured
    against :func:`chandrasekhar_h`). H(0) = 1.
    """
    x = np.asarray(x, dtype=float)
    w = np.asarray(w, dtype=float)
    gam = np.sqrt(1.0 - w)
    r0 = (1.0 - gam) / (1.0 + gam)
    with np.errstate(divide="ignore", invalid="ignore"):
        xlog = np.where(x > 0, x * (np.log1p(x) - np.log(np.where(x > 0, x, 1.0))), 0.0)
    return 1.0 / (1.0 - w * (x * r0 + 0.5 * (1.0 - 2.0 * r0 * x) * xlog))


def hapke_h1981(x: ArrayLike, w: float | ArrayLike) -> NDArray[np.float64]:
    """Hapke's 1981 approximation H(x) ≈ (1 + 2x)/(1 + 2γx), γ = √(1−w): error ≤ 4.0 % for
    w ≤ 0.99 (measured against :func:`chandrasekhar_h`)."""
    x = np.asarray(x, dtype=float)
    gam = np.sqrt(1.0 - np.asarray(w, dtype=float))
    return (1.0 + 2.0 * x) / (1.0 + 2.0 * gam * x)


@lru_cache(maxsize=32)
def _h_nodes(w: float, n_nodes: int) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    t, wt = np.polynomial.legendre.leggauss(n_nodes)
    mu = 0.5 * (t + 1.0)
    wt = 0.5 * wt
    gam = np.sqrt(1.0 - w)
    h = np.ones_like(mu)
    for _ in range(2000):
        integ = (wt * mu * h)[None, :] / (mu[:, None] + mu[None, :])
        h_new = 1.0 / (gam + 0.5 * w * integ.sum(axis=1))
        if np.max(np.abs(h_new - h)) < 1e-14:
            h = h_new
            break
        h = h_new
    return mu, wt, h


def chandrasekhar_h(x: ArrayLike, w: float, *, n_nodes: int = 200) -> NDArray[np.float64]:
    """Chandrasekhar's H function for isotropic scattering with albedo ``w`` < 1, by fixed-point
    iteration of 1/H(μ) = √(1−w) + (w/2) ∫₀¹ μ'H(μ')/(μ+μ') dμ' on Gauss–Legendre nodes
    (Chandrasekhar, *Radiative Transfer* 1960, ch. V). Reference for tests; slow-ish."""
    if not 0.0 <= w < 1.0:
        raise ValueError("w must lie in [0, 1)")
    mu, wt, h = _h_nodes(float(w), int(n_nodes))
    xx = np.asarray(x, dtype=float)
    integ = (wt * mu * h) / (xx[..., None] + mu)
    return 1.0 / (np.sqrt(1.0 - w) + 0.5 * w * integ.sum(axis=-1))


def hapke(*, h_function: str = "2002", opposition: bool = False) -> BRDFModel:
    """Isotropic Hapke model without macroscopic roughness (Hapke 1981, eq. 16).

    f = (w/4π)/(μi + μr) · [(1 + B(g)) p(g) + H(μi)H(μr) − 1] with an isotropic phase function
    p = 1, so without opposition f = (w/4π) H(μi)H(μr)/(μi + μr).

    H is **Hapke's 2002 approximation** (``h_function="2002"``, within 1 % of Chandrasekhar's H)
    or the 1981 one (``"1981"``, within 4 %). With exact H the DHR is 1 − √(1−w) H(μi) ≤ 1.

    With ``opposition=True`` the shadow-hiding surge B(g) = B₀/(1 + tan(g/2)/h) is added
    (Hapke 1981/1986), g the phase angle; this adds energy near backscatter and the model is then
    not energy bounded.
    """
    hfun = {"2002": hapke_h2002, "1981": hapke_h1981}.get(h_function)
    if hfun is None:
        raise ValueError("h_function must be '2002' or '1981'")

    def value(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        w = float(p[0])
        core = hfun(g.mu_i, w) * hfun(g.mu_r, w)
        if opposition:
            b0, hw = float(p[1]), float(p[2])
            # tan(g/2) = tan β = sin β / cos β with cos β = |v|/2.
            cb = g.cos_beta
            sb = np.sqrt(np.clip(1.0 - cb * cb, 0.0, 1.0))
            tan_half = sb / np.maximum(cb, MU_FLOOR)
            core = core + b0 / (1.0 + tan_half / hw)
        return w / (4.0 * np.pi) * core / (g.mu_i + g.mu_r)

    params = [ParamSpec("w", "1", 0.0, 0.9999, 0.5, description="single-scattering albedo")]
    if opposition:
        params += [
            ParamSpec("B0", "1", 0.0, 1.0, 0.5, description="opposition amplitude"),
            ParamSpec("h", "1", 1e-3, 1.0, 0.05, log=True, description="opposition width"),
        ]
    return BRDFModel(
        name="hapke_opposition" if opposition else "hapke",
        params=tuple(params),
        value_fn=value,
        energy_bounded=not opposition,
        description=f"Isotropic Hapke with the H-function approximation of {h_function}.",
        validity="particulate surfaces, isotropic single scattering; energy bounded up to the "
        "H approximation error (≤ 1 %) without the opposition term",
        reference="Hapke, JGR 86(B4) 1981; Icarus 157, 2002",
    )
