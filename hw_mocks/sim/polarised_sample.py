"""Samples with a Mueller-matrix BRDF, and the transmissive references of a polarimeter.

Ground truth for polarimetric scans on the virtual bench (conventions of
:mod:`hw_mocks.sim.polarisation`: bases (h, v, k) with v the lab +y made perpendicular to
the beam). Written independently of :mod:`analysis.polarimetry`.

Microfacet pBRDF (Priest & Germer, "Polarimetric BRDF in the microfacet model: theory
and measurements", Proc. MSS Specialty Group on Passive Sensors, 2000, eqs. (1)–(9))::

    F(ωi, ωr) = D(θh) G(θi, θr) / (4 cos θi cos θr) · M_facet(ωi, ωr)     (1/sr)

* M_facet is the Mueller matrix of Fresnel reflection on the facet whose normal is the
  half vector h = (ωi + ωr)/|ωi + ωr|, at the local angle β, cos β = ωi·h. The facet's
  plane of incidence contains ωi and ωr: its s vector is s = (ωi × ωr)/|ωi × ωr|, and its
  p vectors p = k × s for the incident (k = −ωi) and reflected (k = ωr) beam. In that
  s/p frame the reflection is diag(r_s, r_p) with Fresnel's coefficients (Hecht,
  *Optics*, 4th ed., eqs. (4.34) and (4.40), whose r_p sign goes with p = k × s on both
  beams, so that a mirror at normal incidence keeps the field's direction),
  r_s = (cos β − n̂ cos t)/(cos β + n̂ cos t), r_p = (n̂ cos β − cos t)/(n̂ cos β + cos t),
  cos t = √(1 − sin²β / n̂²), n̂ = n + i k (absorbing media, Born & Wolf §14.2). The 3-D
  map r_s s sᵀ + r_p p_r p_iᵀ is projected on the incident and scattered beams' lab bases
  (the rotations of Priest & Germer's eq. (5)) and turned into a Mueller matrix.
* D: Beckmann distribution of facet slopes, D = exp(−tan²θh / m²) / (π m² cos⁴θh), m the
  rms slope (Beckmann & Spizzichino 1963; Walter et al., EGSR 2007, eq. 25).
* G: Smith's shadowing for the Beckmann surface, G = G₁(θi) G₁(θr),
  G₁ = 1/(1 + Λ), Λ(a) = (e^{−a²}/(a√π) − erfc a)/2, a = 1/(m tan θ) (Smith, IEEE TAP
  15, 1967; Walter et al. eq. 27 written with Λ).

A depolarising diffuse layer adds (ρ/π) · diag(1, d, −d, −d): ρ the albedo and d the
polarisation it keeps (0 for an ideal depolariser, at most 1/3 so the matrix stays
physical; the sign pattern is a mirror's in these bases).

Transmissive references (the beam passes the sample position straight to the detector
arm at 180°): ``air`` (the identity), ``polariser`` (orientation, extinction) and
``retarder`` (orientation, retardance; a quarter-wave plate at 90°).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import erfc

from hw_mocks.sim.polarisation import (
    analysed_intensity,
    jones_to_mueller,
    polariser_mueller,
    retarder_mueller,
    transverse_basis,
)

__all__ = ["MicrofacetPolarisedSample", "reference_mueller"]

_MU_FLOOR = 1e-9


def _smith_g1(tan_theta: NDArray[np.float64], m: float) -> NDArray[np.float64]:
    with np.errstate(divide="ignore", invalid="ignore"):
        a = 1.0 / (m * np.abs(tan_theta))
        lam = 0.5 * (np.exp(-a * a) / (a * math.sqrt(math.pi)) - erfc(a))
    return np.where(np.isfinite(a), 1.0 / (1.0 + lam), 1.0)


@dataclass(frozen=True)
class MicrofacetPolarisedSample:
    """Fresnel microfacet pBRDF (index n + i k, rms slope m) plus a depolarising diffuse
    layer (albedo, kept polarisation d); ``specular`` scales the facet term (0 leaves the
    diffuse layer alone)."""

    n: float = 1.5
    k: float = 0.0
    slope_rms: float = 0.2
    albedo: float = 0.0
    depolarisation_keep: float = 0.0
    specular: float = 1.0

    def __post_init__(self) -> None:
        checks = {
            "n": math.isfinite(self.n) and self.n > 0.0,
            "k": math.isfinite(self.k) and self.k >= 0.0,
            "slope_rms": math.isfinite(self.slope_rms) and 0.0 < self.slope_rms <= 2.0,
            "albedo": 0.0 <= self.albedo <= 1.0,
            "depolarisation_keep": 0.0 <= self.depolarisation_keep <= 1.0 / 3.0,
            "specular": 0.0 <= self.specular <= 1.0,
        }
        bad = [key for key, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"[simulation.scene.pbrdf] out of range: {', '.join(bad)} (n > 0, "
                             "k ≥ 0, slope_rms in (0, 2], albedo and specular in [0, 1], "
                             "depolarisation_keep in [0, 1/3])")

    KEYS = frozenset({"n", "k", "slope_rms", "albedo", "depolarisation_keep", "specular"})

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> MicrofacetPolarisedSample:
        unknown = set(cfg) - cls.KEYS
        if unknown:
            raise ValueError(f"[simulation.scene.pbrdf] unknown keys {sorted(unknown)}; "
                             f"known {sorted(cls.KEYS)}")
        return cls(**{key: float(value) for key, value in cfg.items()})

    def mueller(self, wi: NDArray[np.float64], wr: NDArray[np.float64],
                up: NDArray[np.float64]) -> NDArray[np.float64]:
        """Mueller BRDF (…, 4, 4) in 1/sr for the unit direction ``wi`` (3,) towards the
        source and unit directions ``wr`` (…, 3) towards the observer, all in the sample
        frame (normal +z); ``up`` is the lab +y in that frame. Input Stokes vectors in the
        incident beam's basis, output in the scattered beam's."""
        wi = np.asarray(wi, dtype=float)
        wr = np.asarray(wr, dtype=float)
        out = np.zeros((*wr.shape[:-1], 4, 4))
        if self.albedo > 0.0:
            out += self._diffuse()
        if self.specular > 0.0:
            scale, jones = self._facets(wi, wr, up)
            out += (self.specular * scale)[..., None, None] * jones_to_mueller(jones)
        return out

    def intensity(self, wi: NDArray[np.float64], wr: NDArray[np.float64],
                  up: NDArray[np.float64], analyser: NDArray[np.float64],
                  generator: NDArray[np.float64]) -> NDArray[np.float64]:
        """a · F(ωi, ωr) · g (1/sr), shape ``wr.shape[:-1]``: what a detector behind the
        analyser row ``a`` reads of the generator's Stokes vector ``g`` (the arguments of
        :meth:`mueller`), without forming the 4×4 matrices."""
        wi = np.asarray(wi, dtype=float)
        wr = np.asarray(wr, dtype=float)
        out = np.zeros(wr.shape[:-1])
        if self.albedo > 0.0:
            out += float(analyser @ self._diffuse() @ generator)
        if self.specular > 0.0:
            scale, jones = self._facets(wi, wr, up)
            out += self.specular * scale * analysed_intensity(jones, analyser, generator)
        return out

    def _diffuse(self) -> NDArray[np.float64]:
        d = self.depolarisation_keep
        return (self.albedo / math.pi) * np.diag([1.0, d, -d, -d])

    def _facets(self, wi: NDArray[np.float64], wr: NDArray[np.float64],
                up: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.complex128]]:
        """D G / (4 μi μr) and the facets' Jones matrices in the beams' lab bases."""
        mu_i = max(float(wi[2]), _MU_FLOOR)
        mu_r = np.maximum(wr[..., 2], _MU_FLOOR)
        h = wi + wr
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        cos_h = np.clip(h[..., 2], _MU_FLOOR, 1.0)
        tan2_h = (1.0 - cos_h**2) / cos_h**2
        m2 = self.slope_rms**2
        dist = np.exp(-tan2_h / m2) / (math.pi * m2 * cos_h**4)
        tan_i = math.sqrt(max(1.0 - mu_i**2, 0.0)) / mu_i
        tan_r = np.sqrt(np.maximum(1.0 - mu_r**2, 0.0)) / mu_r
        shadow = _smith_g1(np.asarray(tan_i), self.slope_rms) * _smith_g1(tan_r, self.slope_rms)
        cos_b = np.clip(h @ wi, 0.0, 1.0)
        index = complex(self.n, self.k)
        cos_t = np.sqrt(1.0 - (1.0 - cos_b**2) / index**2 + 0j)
        r_s = (cos_b - index * cos_t) / (cos_b + index * cos_t)
        r_p = (index * cos_b - cos_t) / (index * cos_b + cos_t)
        # the facet's s vector; in exact backscatter (ωr = ωi) any vector ⟂ ωi will do
        s = np.cross(np.broadcast_to(wi, wr.shape), wr)
        norm = np.linalg.norm(s, axis=-1, keepdims=True)
        fallback = transverse_basis(-wi, up)[1]
        s = np.where(norm > 1e-12, s / np.maximum(norm, 1e-300), fallback)
        k_i = -wi
        p_i = np.cross(np.broadcast_to(k_i, s.shape), s)
        p_r = np.cross(wr, s)
        h_i, v_i = transverse_basis(k_i, up)
        h_r, v_r = transverse_basis(wr, up)
        jones = np.empty((*wr.shape[:-1], 2, 2), dtype=complex)
        for a, out_vec in enumerate((h_r, v_r)):
            os_ = np.sum(out_vec * s, axis=-1)
            op = np.sum(out_vec * p_r, axis=-1)
            for b, in_vec in enumerate((h_i, v_i)):
                jones[..., a, b] = (r_s * os_ * (s @ in_vec)
                                    + r_p * op * (p_i @ in_vec))
        return dist * shadow / (4.0 * mu_i * mu_r), jones


def reference_mueller(kind: str, cfg: Mapping[str, Any]) -> NDArray[np.float64]:
    """Mueller matrix of a transmissive reference sample in the beam's basis: ``air``;
    ``polariser`` (``orientation_deg``, ``extinction``); ``retarder``
    (``orientation_deg``, ``retardance_deg``, default 90: a quarter-wave plate)."""
    keys = {"air": set(), "polariser": {"orientation_deg", "extinction"},
            "retarder": {"orientation_deg", "retardance_deg"}}
    if kind not in keys:
        raise ValueError(f"[simulation.scene] reference sample must be one of "
                         f"{', '.join(keys)}, got {kind!r}")
    unknown = set(cfg) - keys[kind]
    if unknown:
        raise ValueError(f"[simulation.scene.{kind}] unknown keys {sorted(unknown)}; known "
                         f"{sorted(keys[kind]) or 'none'}")
    theta = math.radians(float(cfg.get("orientation_deg", 0.0)))
    if kind == "polariser":
        return polariser_mueller(theta, float(cfg.get("extinction", 0.0)))
    if kind == "retarder":
        return retarder_mueller(theta, math.radians(float(cfg.get("retardance_deg", 90.0))))
    return np.eye(4)
