"""Scattering theories for rough surfaces: Beckmann–Kirchhoff (very rough, σ ≫ λ) and
Rayleigh–Rice (smooth, σ ≪ λ) with Gaussian and ABC (K-correlation) PSDs.

Conventions: :mod:`analysis.brdf.geometry`. Lengths for Rayleigh–Rice: wavelength and
correlation lengths in µm, rms roughness σ in nm (converted internally), PSDs in µm⁴,
spatial frequencies in 1/µm. Values in 1/sr.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf import microfacet as mf
from analysis.brdf.geometry import Geometry
from analysis.brdf.model import BRDFModel, ParamSpec


# ----------------------------------------------------------------- Beckmann–Kirchhoff
def beckmann_kirchhoff() -> BRDFModel:
    """Kirchhoff (tangent-plane) scattering in the geometric-optics limit σ ≫ λ
    (Beckmann & Spizzichino 1963), Gaussian slopes of rms m:

    f₀ = R [1 + ωi·ωr]² / (π m² μiμr (μi+μr)⁴) · exp(−|v_xy|² / (m² v_z²)),

    which equals R·D_Beckmann(h)/(4μiμr). The bare form grows as 1/μr at grazing and its DHR
    exceeds 1 there; following Beckmann (1965) it is multiplied by the uncorrelated Smith
    shadowing G₁(ωi)G₁(ωr) for the Beckmann slope distribution, which makes it finite at
    grazing and energy bounded (DHR ≤ R). R is a constant (angle-averaged) reflectance.
    """

    def value(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        m = float(p[1])
        d = mf.beckmann_d(g.cos_theta_h, m, g.tan2_theta_h)
        return p[0] * d * mf.separable_smith_visibility(g.mu_i, g.mu_r, m)

    def jac(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        # V = 1/(4 a_i a_r), a = μ + μΛ(μ): ∂V/∂m = −V (∂a_i/a_i + ∂a_r/a_r), ∂a = ∂(μΛ)/∂m
        m = float(p[1])
        mi = np.maximum(g.mu_i, mf.MU_FLOOR)
        mr = np.maximum(g.mu_r, mf.MU_FLOOR)
        a_i = mi + mf.beckmann_mu_lambda(mi, m)
        a_r = mr + mf.beckmann_mu_lambda(mr, m)
        v = 0.25 / np.maximum(a_i * a_r, mf._DEN_FLOOR)
        dv = -v * (mf.beckmann_mu_lambda_dalpha(mi, m) / a_i
                   + mf.beckmann_mu_lambda_dalpha(mr, m) / a_r)
        d = mf.beckmann_d(g.cos_theta_h, m, g.tan2_theta_h)
        dd = mf.beckmann_d_dalpha(g.cos_theta_h, m, g.tan2_theta_h)
        return np.stack([d * v, p[0] * (dd * v + d * dv)], axis=-1)

    return BRDFModel(
        name="beckmann_kirchhoff",
        params=(
            ParamSpec("R", "1", 0.0, 100.0, 0.5, description="surface reflectance"),
            ParamSpec("m", "1", 1e-3, 2.0, 0.3, log=True, description="rms surface slope"),
        ),
        value_fn=value,
        jac_fn=jac,
        description="Beckmann–Kirchhoff very-rough limit with Beckmann (Smith) shadowing.",
        validity="σ ≫ λ, correlation length ≫ λ; energy bounded for R ≤ 1",
        reference="Beckmann & Spizzichino 1963; Beckmann 1965",
    )


# ---------------------------------------------------------------------------- PSD models
def psd_gaussian(f: ArrayLike, sigma_um: float, ell_um: float) -> NDArray[np.float64]:
    """Isotropic 2-D PSD of a Gaussian ACF σ² exp(−τ²/ℓ²): S₂(f) = πℓ²σ² exp(−(πℓf)²)
    (µm⁴ for σ, ℓ in µm, f in 1/µm); ∫∫ S₂ d²f = σ² (Stover, *Optical Scattering*)."""
    f = np.asarray(f, dtype=float)
    return np.pi * ell_um**2 * sigma_um**2 * np.exp(-((np.pi * ell_um * f) ** 2))


def psd_abc(f: ArrayLike, a_um4: float, b_um: float, c: float) -> NDArray[np.float64]:
    """ABC / K-correlation PSD S₂(f) = A / (1 + (Bf)²)^{C/2} (Church, Takacs & Leonard 1989;
    Stover, *Optical Scattering*). Its total σ² = 2πA / (B²(C − 2)) for C > 2
    (:func:`abc_sigma2`)."""
    f = np.asarray(f, dtype=float)
    return a_um4 / (1.0 + (b_um * f) ** 2) ** (0.5 * c)


def abc_sigma2(a_um4: float, b_um: float, c: float, f_max: float = np.inf) -> float:
    """σ² = 2π ∫₀^{f_max} f S₂(f) df of the ABC PSD (closed form), µm²."""
    if c <= 2 and not np.isfinite(f_max):
        return float("inf")
    k = 1.0 - 0.5 * c
    if np.isfinite(f_max):
        u = 1.0 + (b_um * f_max) ** 2
        if abs(k) < 1e-12:
            return float(np.pi * a_um4 / b_um**2 * np.log(u))
        return float(np.pi * a_um4 / b_um**2 * (u**k - 1.0) / k)
    return float(2.0 * np.pi * a_um4 / (b_um**2 * (c - 2.0)))


# --------------------------------------------------------------------------- Rayleigh–Rice
def spatial_frequency(g: Geometry, wavelength_um: float) -> NDArray[np.float64]:
    """|f| of the grating equation, in 1/µm. With ωi, ωr both pointing away from the surface
    the scattered-minus-specular transverse wavevector is (ωr,xy + ωi,xy)/λ; in Stover's frame
    (specular at φs = 0) this is fx = (sinθs cosφs − sinθi)/λ, fy = sinθs sinφs/λ. It is
    symmetric in ωi, ωr, hence reciprocity."""
    return np.hypot(g.vx, g.vy) / wavelength_um


def rayleigh_rice(*, psd: str = "gaussian", wavelength_um: float = 0.6328,
                  q: float = 1.0) -> BRDFModel:
    """Rayleigh–Rice first-order vector perturbation BRDF (Church, Jenkinson & Zavada 1979;
    Elson & Bennett 1979; Stover, *Optical Scattering*):

    f = (16π²/λ⁴) μi μr Q S₂(f),

    with the polarisation/material factor Q taken as the constant ``q`` (Q ≈ R for highly
    reflective surfaces at small angles; q = 1 gives the Bennett–Porteus TIS
    (4πσ cosθi/λ)² when all roughness lies in the propagating band).

    Parameters (``psd="gaussian"``): ``sigma_nm`` rms roughness [nm], ``ell_um`` correlation
    length [µm]. (``psd="abc"``): ``A`` [µm⁴], ``B`` [µm], ``C`` [1].

    Validity: σ ≪ λ (TIS ≪ 1); the model is not energy bounded in general (it is a
    perturbation series), so ``energy_bounded`` is False.
    """
    if psd not in ("gaussian", "abc"):
        raise ValueError("psd must be 'gaussian' or 'abc'")
    lam = float(wavelength_um)
    pref = 16.0 * np.pi**2 / lam**4 * q

    if psd == "gaussian":

        def value(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
            fr = spatial_frequency(g, lam)
            s2 = psd_gaussian(fr, float(p[0]) * 1e-3, float(p[1]))
            return pref * g.mu_i * g.mu_r * s2

        params = (
            ParamSpec("sigma_nm", "nm", 1e-3, 1e3, 2.0, log=True, description="rms roughness"),
            ParamSpec("ell_um", "µm", 1e-3, 1e4, 5.0, log=True, description="correlation length"),
        )
    else:

        def value(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
            fr = spatial_frequency(g, lam)
            return pref * g.mu_i * g.mu_r * psd_abc(fr, float(p[0]), float(p[1]), float(p[2]))

        params = (
            ParamSpec("A", "µm^4", 1e-20, 1e6, 1e-4, log=True, description="PSD level"),
            ParamSpec("B", "µm", 1e-3, 1e4, 10.0, log=True, description="corner length"),
            ParamSpec("C", "1", 1.0, 8.0, 3.0, description="power-law slope"),
        )

    return BRDFModel(
        name=f"rayleigh_rice_{'gauss' if psd == 'gaussian' else 'abc'}",
        params=params,
        value_fn=value,
        energy_bounded=False,
        description=f"Rayleigh–Rice smooth-surface scatter, {psd} PSD, λ = {lam} µm, Q = {q}.",
        validity="σ ≪ λ; first order in (kσ); Q taken constant; not energy bounded (a "
        "perturbation series: TIS = (4πσ cos θi/λ)² is meaningful only while ≪ 1)",
        reference="Church, Jenkinson & Zavada 1979; Stover, Optical Scattering",
    )


def bennett_porteus_tis(
    theta_i: ArrayLike, sigma_um: float, wavelength_um: float
) -> NDArray[np.float64]:
    """Total integrated scatter (4πσ cosθi/λ)² (Bennett & Porteus, JOSA 51, 1961)."""
    return (4.0 * np.pi * sigma_um * np.cos(np.asarray(theta_i, dtype=float)) / wavelength_um) ** 2
