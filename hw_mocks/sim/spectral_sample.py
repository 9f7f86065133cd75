"""A sample whose BRDF depends on the wavelength of the light that reaches it.

Ground truth for spectral BRDF scans on the virtual bench. The sample is a rough
dielectric (or metal) with a diffuse body:

    f(ωi, ωr; λ) = ρ(λ)/π + F(ωi·h; n̂(λ)) · D(h) · G₂(ωi, ωr) / (4 cos θi cos θr)   (1/sr)

* ρ(λ): diffuse albedo, a constant or a table linearly interpolated in λ.
* n̂(λ) = n(λ) + i k(λ): a Cauchy dielectric n = A + B/λ² + C/λ⁴ (λ in µm; Born & Wolf,
  *Principles of Optics*, 7th ed., §2.3.4) with a constant k, or a table of n and k
  (e.g. a metal from a handbook), linearly interpolated. Sign convention: time
  dependence exp(−iωt), so absorption is k ≥ 0.
* F: unpolarised Fresnel reflectance (R_s + R_p)/2 of the interface at the facet's angle
  of incidence β, cos β = ωi·h (Hecht, *Optics*, 4th ed., §4.6.2, eqs. (4.34) and (4.40),
  with the complex index for an absorbing medium, Born & Wolf §14.2); written here with
  Snell's law for the complex transmission cosine, cos θt = √(1 − sin²β/n̂²).
* D: GGX (Trowbridge–Reitz) facet distribution, D = α²/(π cos⁴θh (α² + tan²θh)²) (Walter
  et al., EGSR 2007, eq. 33); G₂: height-correlated Smith masking–shadowing
  1/(1 + Λ(ωi) + Λ(ωr)), Λ = (√(1 + α² tan²θ) − 1)/2 (Walter et al. eq. 34; Heitz, JCGT
  3(2) 2014, eq. 99).

The light at the sample is a band (the source spectrum through the selected filter,
:mod:`hw_mocks.sim.filters`): uniform spectral power between λc ± Δλ/2. The BRDF the bench
sees is the power-weighted average over that band, evaluated with Gauss–Legendre nodes
(``band_nodes``): ⟨f⟩ = ⟨ρ⟩/π + ⟨F⟩ D G₂/(4 μi μr), since only ρ and F depend on λ. A line
source (Δλ = 0) uses its wavelength alone.

Written independently of :mod:`analysis.brdf` (which fits it: ``lambert+ggx_fresnel``),
in other algebraic forms, so that a misreading shared by the two cannot pass the
closed-loop tests; a test checks that the two agree.

Configuration (``[simulation.scene]`` with ``brdf = "spectral"``, table ``spectral``):
see :meth:`SpectralSample.from_config`. Wavelengths outside a table take the value at its
nearest end (constant extrapolation).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["SpectralSample", "SpectralTable"]

_MU_FLOOR = 1e-9


@dataclass(frozen=True)
class SpectralTable:
    """A quantity against wavelength: ``values`` at ``wavelengths_nm`` (strictly increasing),
    linearly interpolated, constant beyond the ends. One point is a constant."""

    wavelengths_nm: tuple[float, ...]
    values: tuple[float, ...]

    def __call__(self, wavelength_nm: NDArray[np.float64] | float) -> NDArray[np.float64]:
        return np.interp(wavelength_nm, self.wavelengths_nm, self.values)


def _table(key: str, values: Any, wavelengths: Any, *, low: float, high: float,
           wl_key: str) -> SpectralTable:
    """Validate a constant or a table of ``key`` (with ``wl_key`` wavelengths)."""
    if isinstance(values, int | float) and not isinstance(values, bool):
        if wavelengths is not None:
            raise ValueError(f"[simulation.scene.spectral] {wl_key} given but {key} is a "
                             f"single number: give {key} as a list of the same length")
        vals, wls = [float(values)], [550.0]
    else:
        if not isinstance(values, Sequence) or isinstance(values, str) or not values:
            raise ValueError(f"[simulation.scene.spectral] {key} must be a number or a "
                             f"non-empty list of numbers, got {values!r}")
        if wavelengths is None:
            raise ValueError(f"[simulation.scene.spectral] {key} is a list: give its "
                             f"wavelengths in {wl_key} (nm, increasing)")
        vals = [float(v) for v in values]
        wls = [float(w) for w in wavelengths]
        if len(wls) != len(vals):
            raise ValueError(f"[simulation.scene.spectral] {wl_key} has {len(wls)} entries "
                             f"and {key} {len(vals)}: they must have the same length")
        if not all(math.isfinite(w) and w > 0 for w in wls) or any(
                b <= a for a, b in itertools.pairwise(wls)):
            raise ValueError(f"[simulation.scene.spectral] {wl_key} must be positive "
                             f"wavelengths in nm, strictly increasing, got {wls}")
    for v in vals:
        if not (math.isfinite(v) and low <= v <= high):
            raise ValueError(f"[simulation.scene.spectral] {key} must lie in [{low:g}, "
                             f"{high:g}], got {v}")
    return SpectralTable(tuple(wls), tuple(vals))


@dataclass(frozen=True)
class SpectralSample:
    """Diffuse albedo ρ(λ) plus a GGX lobe with the Fresnel factor of n(λ) + i k(λ).

    Attributes
    ----------
    albedo : SpectralTable
        ρ(λ) in [0, 1].
    index_n, index_k : SpectralTable
        Real part n ≥ 1 and extinction k ≥ 0 of the relative index (tables; a Cauchy
        dispersion is given through :meth:`cauchy`).
    cauchy : tuple of float or None
        (A, B in µm², C in µm⁴) when n follows Cauchy's formula instead of ``index_n``.
    alpha : float
        GGX roughness, in (0, 2].
    band_nodes : int
        Gauss–Legendre nodes over a band of light.
    """

    albedo: SpectralTable
    index_n: SpectralTable
    index_k: SpectralTable
    alpha: float
    cauchy: tuple[float, float, float] | None = None
    band_nodes: int = 5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.alpha) and 0.0 < self.alpha <= 2.0):
            raise ValueError(f"[simulation.scene.spectral] alpha (GGX roughness) must lie in "
                             f"(0, 2], got {self.alpha}")
        if not 1 <= self.band_nodes <= 64:
            raise ValueError("[simulation.scene.spectral] band_nodes must be 1 to 64, got "
                             f"{self.band_nodes}")

    # -------------------------------------------------------------------- construction
    KEYS = frozenset({"albedo", "albedo_nm", "cauchy_a", "cauchy_b_um2", "cauchy_c_um4", "k",
                      "index_nm", "index_n", "index_k", "alpha", "band_nodes"})

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> SpectralSample:
        """From the ``[simulation.scene.spectral]`` table.

        Keys: ``albedo`` (number, or list with ``albedo_nm``), the index either as Cauchy
        coefficients ``cauchy_a`` (required for this form), ``cauchy_b_um2``,
        ``cauchy_c_um4`` (default 0) with an optional constant ``k``, or as a table
        ``index_nm``, ``index_n`` and optional ``index_k``; ``alpha`` (GGX roughness,
        required); ``band_nodes`` (default 5).

        Raises
        ------
        ValueError
            Unknown keys, both or neither index form, values out of range (each message
            names the key).
        """
        if not isinstance(config, Mapping):
            raise TypeError("[simulation.scene.spectral] must be a table, got "
                            f"{config!r}")
        unknown = set(config) - cls.KEYS
        if unknown:
            raise ValueError(f"unknown [simulation.scene.spectral] keys {sorted(unknown)}; "
                             f"known: {', '.join(sorted(cls.KEYS))}")
        if "alpha" not in config:
            raise ValueError("[simulation.scene.spectral] needs alpha (GGX roughness)")
        if "albedo" not in config:
            raise ValueError("[simulation.scene.spectral] needs albedo (a number in [0, 1] "
                             "or a list with albedo_nm)")
        albedo = _table("albedo", config["albedo"], config.get("albedo_nm"), low=0.0,
                        high=1.0, wl_key="albedo_nm")
        cauchy_form = any(k in config for k in ("cauchy_a", "cauchy_b_um2", "cauchy_c_um4"))
        table_form = any(k in config for k in ("index_nm", "index_n", "index_k"))
        if cauchy_form == table_form:
            raise ValueError("[simulation.scene.spectral] give the refractive index either as "
                             "Cauchy coefficients (cauchy_a, cauchy_b_um2, cauchy_c_um4, k) "
                             "or as a table (index_nm, index_n, index_k), "
                             + ("not both" if cauchy_form else "one of them"))
        cauchy = None
        if cauchy_form:
            if "cauchy_a" not in config:
                raise ValueError("[simulation.scene.spectral] the Cauchy form needs cauchy_a")
            coeffs = tuple(float(config.get(k, 0.0))
                           for k in ("cauchy_a", "cauchy_b_um2", "cauchy_c_um4"))
            a_, b_, c_ = coeffs
            if not all(math.isfinite(c) for c in coeffs) or a_ < 1.0 or b_ < 0 or c_ < 0:
                raise ValueError("[simulation.scene.spectral] need cauchy_a ≥ 1 and "
                                 f"cauchy_b_um2, cauchy_c_um4 ≥ 0 (normal dispersion), got "
                                 f"{coeffs}")
            cauchy = (a_, b_, c_)
            n_tab = SpectralTable((550.0,), (a_,))
            k_tab = _table("k", float(config.get("k", 0.0)), None, low=0.0, high=50.0,
                           wl_key="")
        else:
            if "k" in config:
                raise ValueError("[simulation.scene.spectral] k goes with the Cauchy form; "
                                 "with a table give index_k")
            if "index_n" not in config or "index_nm" not in config:
                raise ValueError("[simulation.scene.spectral] the table form needs index_nm "
                                 "and index_n (and optionally index_k)")
            # metals have n < 1 (aluminium 0.96, silver 0.05 in the visible): n > 0 only
            n_tab = _table("index_n", config["index_n"], config["index_nm"], low=1e-3,
                           high=50.0, wl_key="index_nm")
            k_vals = config.get("index_k", [0.0] * len(n_tab.values))
            k_tab = _table("index_k", k_vals, config["index_nm"], low=0.0, high=50.0,
                           wl_key="index_nm")
        try:
            nodes = int(config.get("band_nodes", 5))
            alpha = float(config["alpha"])
        except (TypeError, ValueError) as err:
            raise ValueError(f"[simulation.scene.spectral] alpha must be a number and "
                             f"band_nodes an integer: {err}") from None
        return cls(albedo=albedo, index_n=n_tab, index_k=k_tab, alpha=alpha, cauchy=cauchy,
                   band_nodes=nodes)

    # -------------------------------------------------------------------- the truth
    def refractive_index(self, wavelength_nm: NDArray[np.float64] | float
                         ) -> NDArray[np.complex128]:
        """n̂(λ) = n + ik (exp(−iωt) convention)."""
        lam = np.asarray(wavelength_nm, dtype=float)
        if self.cauchy is not None:
            a_, b_, c_ = self.cauchy
            um2 = (lam * 1e-3) ** 2
            n = a_ + b_ / um2 + c_ / (um2 * um2)
        else:
            n = self.index_n(lam)
        return n + 1j * self.index_k(lam)

    def band(self, wavelength_nm: float, bandwidth_nm: float
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(wavelengths, weights summing to 1) averaging over the band λc ± Δλ/2."""
        if bandwidth_nm <= 0.0 or self.band_nodes == 1:
            return np.array([float(wavelength_nm)]), np.array([1.0])
        x, w = np.polynomial.legendre.leggauss(self.band_nodes)
        return wavelength_nm + 0.5 * bandwidth_nm * x, 0.5 * w

    def fresnel(self, cos_beta: NDArray[np.float64], index: complex | NDArray
                ) -> NDArray[np.float64]:
        """Unpolarised reflectance at incidence cos β (module docstring's form)."""
        c = np.clip(np.asarray(cos_beta, dtype=float), 0.0, 1.0)
        m = np.asarray(index, dtype=complex)
        sin2 = 1.0 - c * c
        cos_t = np.sqrt(1.0 - sin2 / (m * m))
        # the transmitted wave must decay into the medium: Im(n̂ cos θt) ≥ 0 (and, without
        # absorption, propagate forwards): flip the root where the principal one does not
        mct = m * cos_t
        flip = (mct.imag < 0) | ((mct.imag == 0) & (mct.real < 0))
        cos_t = np.where(flip, -cos_t, cos_t)
        rs = (c - m * cos_t) / (c + m * cos_t)
        rp = (m * c - cos_t) / (m * c + cos_t)
        return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)

    def _lobe_shape(self, omega_i: NDArray, omega_r: NDArray
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(cos β, D·G₂/(4μiμr)) for unit vectors in the sample frame (normal +z)."""
        wi = np.asarray(omega_i, dtype=float)
        wr = np.asarray(omega_r, dtype=float)
        wi_b, wr_b = np.broadcast_arrays(wi, wr)
        mu_i = np.maximum(wi_b[..., 2], _MU_FLOOR)
        mu_r = np.maximum(wr_b[..., 2], _MU_FLOOR)
        half = wi_b + wr_b
        norm = np.maximum(np.linalg.norm(half, axis=-1), 1e-300)
        cos_h = np.clip(half[..., 2] / norm, _MU_FLOOR, 1.0)
        cos_beta = np.clip(np.einsum("...k,...k->...", wi_b, half) / norm, 0.0, 1.0)
        a2 = self.alpha * self.alpha
        tan2_h = (1.0 - cos_h * cos_h) / (cos_h * cos_h)
        d = a2 / (math.pi * cos_h**4 * (a2 + tan2_h) ** 2)

        def lam(mu: NDArray) -> NDArray:
            tan2 = (1.0 - mu * mu) / (mu * mu)
            return 0.5 * (np.sqrt(1.0 + a2 * tan2) - 1.0)

        g2 = 1.0 / (1.0 + lam(mu_i) + lam(mu_r))
        shape = d * g2 / (4.0 * mu_i * mu_r)
        lit = (wi_b[..., 2] > 0.0) & (wr_b[..., 2] > 0.0)
        return cos_beta, np.where(lit, shape, 0.0)

    def brdf_vectors(self, omega_i: NDArray, omega_r: NDArray, wavelength_nm: float,
                     bandwidth_nm: float = 0.0) -> NDArray[np.float64]:
        """Band-averaged f (1/sr) for unit vectors in the sample frame (shape (..., 3))."""
        lams, weights = self.band(wavelength_nm, bandwidth_nm)
        rho = float(np.dot(weights, self.albedo(lams)))
        cos_beta, shape = self._lobe_shape(omega_i, omega_r)
        index = self.refractive_index(lams)
        f_mean = sum(w * self.fresnel(cos_beta, m) for w, m in zip(weights, index,
                                                                    strict=True))
        lit = (np.asarray(omega_r)[..., 2] > 0.0) & (np.asarray(omega_i)[..., 2] > 0.0)
        return np.where(lit, rho / math.pi, 0.0) + f_mean * shape

    def at_light(self, wavelength_nm: float, bandwidth_nm: float = 0.0):
        """The BRDF under light of centre ``wavelength_nm`` and full width
        ``bandwidth_nm``: a function of (θi, φi, θr, φr) in radians (conventions of the
        goniometer scene) with ``from_vectors``."""

        def brdf(theta_i, phi_i, theta_r, phi_r):
            ti, pi_, tr, pr = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in
                                                    (theta_i, phi_i, theta_r, phi_r)))
            wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)],
                          axis=-1)
            wr = np.stack([np.sin(tr) * np.cos(pr), np.sin(tr) * np.sin(pr), np.cos(tr)],
                          axis=-1)
            return self.brdf_vectors(wi, wr, wavelength_nm, bandwidth_nm)

        def from_vectors(omega_i, omega_r):
            return self.brdf_vectors(omega_i, omega_r, wavelength_nm, bandwidth_nm)

        # attributes the scene reads, set on the function object
        brdf.from_vectors = from_vectors  # type: ignore[attr-defined]
        brdf.wavelength_nm = wavelength_nm  # type: ignore[attr-defined]
        return brdf

    def truth(self, wavelength_nm: float) -> dict[str, float]:
        """The parameters at one wavelength, named as the analysis model
        ``lambert+ggx_fresnel`` (``ggx_conductor`` with k) names them."""
        m = complex(self.refractive_index(wavelength_nm))
        return {"rho": float(self.albedo(wavelength_nm)), "n": m.real, "k": m.imag,
                "alpha": self.alpha}
