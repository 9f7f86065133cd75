"""Flatland BRDFs for light-field scattering (one in-plane angle per direction).

Conventions
-----------
Angles are in radians in the *unfolded* scene of Sasaki 2020 (ch. 2): the
scattering plane is mirrored so that a specular ray continues straight on, i.e. a mirror
has ``f(θ_in, θ_out) ∝ δ(θ_out − θ_in)``.  Both arguments are measured from the (local)
surface normal.  A flatland BRDF has unit 1/rad and conserves energy as
``∫_{−π/2}^{π/2} f(θ_in, θ_out) cos θ_out dθ_out ≤ 1``; a flatland Lambertian surface of
albedo ρ therefore has ``f = ρ/2``.

The model is the separable diffuse + shift-invariant specular form of eq. (2-14),
``f(θ_o, θ_m) = f_wind(θ_o) f_spec(θ_m − θ_o) + f_diff(θ_o) f_diff(θ_m)``, with a Gaussian
specular lobe normalised on the real line, ``f_spec(ζ) = ρ_s N(ζ; 0, σ)``, a constant
``f_diff = √(ρ_d / 2)`` and an optional window ``f_wind(θ) = cos^k θ``.  The component
functions are those of :mod:`analysis.brdf.lightfield` (one implementation of eq. 2-14); this
module adds the light-field side: a parameter record, γ on a domain, the inhomogeneous form
and the four thesis materials.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import erf

from analysis.brdf import lightfield as _s2_14

__all__ = [
    "MATERIALS",
    "FlatlandBRDF",
    "SpatiallyVaryingBRDF",
    "material",
]


@dataclass(frozen=True)
class FlatlandBRDF:
    """Diffuse + Gaussian-specular flatland BRDF, eq. (2-14) of Sasaki 2020.

    Parameters
    ----------
    specular_reflectance : float
        ρ_s, the integral of the specular lobe over ζ = θ_out − θ_in (dimensionless).
    specular_width_rad : float
        σ of the Gaussian lobe in radians (> 0).
    diffuse_reflectance : float
        ρ_d, flatland Lambertian albedo; ``f_diff(θ) = √(ρ_d/2)`` (1/√rad).
    window_exponent : float
        k in ``f_wind(θ_in) = cos^k θ_in``; 0 (default) gives the flat window of eq. 2-32/33.
    name : str
        Free label, e.g. the material name.
    """

    specular_reflectance: float
    specular_width_rad: float
    diffuse_reflectance: float
    window_exponent: float = 0.0
    name: str = ""

    def __post_init__(self) -> None:
        values = {
            "specular_reflectance": self.specular_reflectance,
            "specular_width_rad": self.specular_width_rad,
            "diffuse_reflectance": self.diffuse_reflectance,
            "window_exponent": self.window_exponent,
        }
        for key, v in values.items():
            if not np.isfinite(v):
                raise ValueError(f"{key} = {v} must be finite")
        if self.specular_reflectance < 0 or self.diffuse_reflectance < 0:
            raise ValueError(f"reflectances must be non-negative (specular_reflectance = "
                             f"{self.specular_reflectance}, diffuse_reflectance = "
                             f"{self.diffuse_reflectance})")
        if not self.specular_width_rad > 0:
            raise ValueError(f"specular_width_rad = {self.specular_width_rad} must be positive")
        if self.window_exponent < 0:
            raise ValueError(f"window_exponent = {self.window_exponent} must be non-negative")

    @property
    def homogeneous(self) -> bool:
        """True: the same BRDF at every surface point."""
        return True

    def f_spec(self, zeta_rad: ArrayLike) -> NDArray[np.float64]:
        """Specular lobe ``ρ_s N(ζ; 0, σ)`` in 1/rad, ζ = θ_out − θ_in."""
        return _s2_14.f_spec(zeta_rad, self.specular_reflectance, self.specular_width_rad)

    def f_diff(self, theta_rad: ArrayLike) -> NDArray[np.float64]:
        """Diffuse factor ``√(ρ_d/2)`` (constant), so that f_diff·f_diff = ρ_d/2."""
        return _s2_14.f_diff(theta_rad, self.diffuse_reflectance)

    def f_wind(self, theta_rad: ArrayLike) -> NDArray[np.float64]:
        """Window on the incident angle, ``cos^k θ`` clipped at 0 beyond ±π/2."""
        return _s2_14.f_wind(theta_rad, self.window_exponent)

    def __call__(
        self,
        theta_in_rad: ArrayLike,
        theta_out_rad: ArrayLike,
        *,
        y_mm: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """BRDF value f(θ_in, θ_out) in 1/rad (broadcasting; ``y_mm`` is ignored)."""
        return _s2_14.flatland_brdf(
            theta_in_rad,
            theta_out_rad,
            rho_d=self.diffuse_reflectance,
            ks=self.specular_reflectance,
            width=self.specular_width_rad,
            q=self.window_exponent,
        )

    def degree_of_specularity(self, domain_rad: tuple[float, float]) -> float:
        """γ ≈ 1/(1 + Σ|D_p|²/S_pp) for a flat window (Sasaki 2020, eq. 2-37);
        here D_p = δ_p0 √(ρ_d(b−a)/2).

        The Gaussian lobe's S_00 on one period is ρ_s up to the tails beyond ±(b−a)/2.
        """
        a, b = domain_rad
        width = b - a
        s = self.specular_width_rad
        s00 = self.specular_reflectance * erf(width / 2 / (np.sqrt(2) * s))
        d2 = self.diffuse_reflectance * width / 2
        return float(s00 / (s00 + d2)) if s00 + d2 > 0 else 0.0


@dataclass(frozen=True)
class SpatiallyVaryingBRDF:
    """Inhomogeneous BRDF ``f(y_s, θ_in, θ_out)`` built from a base model and scale maps.

    ``f = s_spec(y) f_wind f_spec + s_diff(y) f_diff f_diff``; both scale callables take
    positions in mm and return non-negative factors (e.g. a stain of lower gloss).
    """

    base: FlatlandBRDF
    specular_scale: Callable[[NDArray[np.float64]], NDArray[np.float64]]
    diffuse_scale: Callable[[NDArray[np.float64]], NDArray[np.float64]]

    @property
    def homogeneous(self) -> bool:
        """False: the value depends on the surface point."""
        return False

    def at(self, y_mm: float) -> FlatlandBRDF:
        """The local homogeneous model at one surface point."""
        b = self.base
        ss = float(np.asarray(self.specular_scale(np.asarray([y_mm], dtype=float)))[0])
        sd = float(np.asarray(self.diffuse_scale(np.asarray([y_mm], dtype=float)))[0])
        return FlatlandBRDF(
            b.specular_reflectance * ss,
            b.specular_width_rad,
            b.diffuse_reflectance * sd,
            b.window_exponent,
            b.name,
        )

    def __call__(
        self,
        theta_in_rad: ArrayLike,
        theta_out_rad: ArrayLike,
        *,
        y_mm: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """f(y, θ_in, θ_out) in 1/rad; ``y_mm`` broadcasts with the angles."""
        if y_mm is None:
            raise ValueError("an inhomogeneous BRDF needs y_mm")
        y = np.asarray(y_mm, dtype=float)
        ti = np.asarray(theta_in_rad, dtype=float)
        to = np.asarray(theta_out_rad, dtype=float)
        b = self.base
        spec = b.f_wind(ti) * b.f_spec(to - ti)
        diff = b.f_diff(ti) * b.f_diff(to)
        return self.specular_scale(y) * spec + self.diffuse_scale(y) * diff


#: The four wall materials of the thesis experiments, as plausible flatland parameters.
#: Widths are the in-plane rms of the specular lobe; ρ_s, ρ_d are flatland albedos.
#: Brushed aluminium: strong, narrow lobe (cut across the brushing), little diffuse light.
#: Coated papers: a weak gloss lobe on a bright diffuse base (glossy and semi-matte grades).
#: Pearl paint behind glass: the ~4 % Fresnel glint of the glass plus a pearlescent base.
MATERIALS: dict[str, FlatlandBRDF] = {
    "brushed_metal": FlatlandBRDF(0.60, np.deg2rad(2.0), 0.08, 0.0, "brushed_metal"),
    "coated_paper_glossy": FlatlandBRDF(0.08, np.deg2rad(3.0), 0.75, 0.0, "coated_paper_glossy"),
    "coated_paper_matte": FlatlandBRDF(0.04, np.deg2rad(6.0), 0.80, 0.0, "coated_paper_matte"),
    "pearl_paint_glass": FlatlandBRDF(0.045, np.deg2rad(1.0), 0.30, 0.0, "pearl_paint_glass"),
}


def material(name: str) -> FlatlandBRDF:
    """Return one of :data:`MATERIALS` by name (KeyError lists the choices)."""
    try:
        return MATERIALS[name]
    except KeyError:
        raise KeyError(f"unknown material {name!r}; choose from {sorted(MATERIALS)}") from None
