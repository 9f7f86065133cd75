"""The separable-diffuse + windowed shift-invariant specular flatland BRDF

f(θo, θm) = f_wind(θo) f_spec(θm − θo) + f_diff(θo) f_diff(θm)     (Sasaki 2020, eq. 2-14)

Sasaki, *Information extraction from non-line-of-sight objects using plenoptic data from
scattered light*, PhD thesis, University of Minnesota, 2020; equations numbered as there.

θo is the signed in-plane angle of the incoming ray and θm that of the outgoing ray, both in
(−π/2, π/2) from the normal, with the sign chosen so that mirror reflection is θm = θo (the
"unfolded" geometry of the light-field work). In the 3-D conventions of
:mod:`analysis.brdf.geometry` these are s_i = atan2(−x_i, z_i) and s_r = atan2(x_r, z_r); out
of the plane of incidence the model is evaluated on these projected angles (it is a 2-D model).

Components (this module's choice of the shapes the thesis leaves open):

* f_spec(ζ) = ks · exp(−ζ²/(2w²)) / (√(2π) w)   — unit-area Gaussian in ζ (radians);
* f_wind(θ) = cos^q θ                             — slowly varying window, q ≥ 0;
* f_diff(θ) = √(ρd/2)                              — flatland Lambertian: ∫ (ρd/2) cos θ dθ = ρd.

Unit: 1/rad (flatland). Flatland reflectance ∫ f cos θm dθm ≤ ρd + ks, so the model is
energy bounded (in flatland) for ρd + ks ≤ 1. Reciprocity f(θo, θm) = f(θm, θo) holds
exactly only for q = 0 (the window breaks it at order q·w·tan θ) — ``reciprocal`` is False.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.geometry import Geometry
from analysis.brdf.model import BRDFModel, ParamSpec

_SQRT_2PI = float(np.sqrt(2.0 * np.pi))


def f_spec(zeta: ArrayLike, ks: float, width: float) -> NDArray[np.float64]:
    """Shift-invariant specular kernel ks·N(ζ; 0, w²), ζ = θm − θo in radians (1/rad)."""
    z = np.asarray(zeta, dtype=float)
    return ks * np.exp(-0.5 * (z / width) ** 2) / (_SQRT_2PI * width)


def f_wind(theta: ArrayLike, q: float) -> NDArray[np.float64]:
    """Window cos^q θ (dimensionless); q = 0 gives f_wind ≡ 1."""
    return np.maximum(np.cos(np.asarray(theta, dtype=float)), 0.0) ** q


def f_diff(theta: ArrayLike, rho_d: float) -> NDArray[np.float64]:
    """Separable diffuse factor √(ρd/2) (1/√rad), constant in θ."""
    return np.full(np.shape(theta), np.sqrt(0.5 * rho_d))


def flatland_brdf(
    theta_o: ArrayLike, theta_m: ArrayLike, *, rho_d: float, ks: float, width: float, q: float
) -> NDArray[np.float64]:
    """Eq. 2-14 on signed flatland angles (radians), 1/rad, broadcast shape."""
    to = np.asarray(theta_o, dtype=float)
    tm = np.asarray(theta_m, dtype=float)
    return f_wind(to, q) * f_spec(tm - to, ks, width) + f_diff(to, rho_d) * f_diff(tm, rho_d)


def separable_specular() -> BRDFModel:
    """:class:`BRDFModel` of eq. 2-14 with parameters (rho_d, ks, width [rad], q)."""

    def value(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        return flatland_brdf(
            g.s_i, g.s_r, rho_d=float(p[0]), ks=float(p[1]), width=float(p[2]), q=float(p[3])
        )

    def jac(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        _rho_d, ks, w, q = (float(x) for x in p)
        to, tm = g.s_i, g.s_r
        z = tm - to
        wind = f_wind(to, q)
        gauss = np.exp(-0.5 * (z / w) ** 2) / (_SQRT_2PI * w)
        spec = wind * ks * gauss
        logc = np.log(np.maximum(np.cos(to), 1e-300))
        return np.stack(
            np.broadcast_arrays(
                0.5,
                wind * gauss,
                spec * ((z * z) / w**3 - 1.0 / w),
                spec * logc,
            ),
            axis=-1,
        )

    return BRDFModel(
        name="lightfield_separable",
        params=(
            ParamSpec("rho_d", "1", 0.0, 10.0, 0.3, description="diffuse reflectance"),
            ParamSpec("ks", "1", 0.0, 100.0, 0.5, description="specular scale"),
            ParamSpec("width", "rad", 1e-4, 1.0, 0.05, log=True, description="lobe width"),
            ParamSpec("q", "1", 0.0, 10.0, 0.0, description="window exponent"),
        ),
        value_fn=value,
        jac_fn=jac,
        energy_bounded=False,
        reciprocal=False,
        unit="1/rad",
        description="Flatland separable diffuse + windowed shift-invariant specular "
        "(Sasaki 2020, eq. 2-14).",
        validity="in-plane (2-D) scattering off a wall; flatland energy bounded for ρd + ks ≤ 1; "
        "reciprocal only for q = 0",
        reference="Sasaki 2020, PhD thesis, Univ. of Minnesota, eq. 2-14",
    )
