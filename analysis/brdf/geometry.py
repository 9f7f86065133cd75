"""Scattering geometry: directions, half vectors and the angle conventions used everywhere.

Conventions (stated once, used by every module of :mod:`analysis.brdf`)
------------------------------------------------------------------------
* Angles are in **radians**.
* The sample normal is +z; the tangent x-axis is azimuth φ = 0.
* θi, θr are polar angles measured **from the surface normal**, in [0, π/2].
* ωi is the unit vector pointing **towards the source**, ωr the unit vector pointing
  **towards the detector**; both lie in the upper hemisphere:
  ω = (sinθ cosφ, sinθ sinφ, cosθ).
* With both vectors pointing away from the surface, the **specular (mirror) direction is
  θr = θi, φr = φi + π**. In the plane of incidence φi = 0, a detector on the far side of
  the normal from the source therefore has φr = π.
* cos 2β = ωi·ωr = cosθi cosθr + sinθi sinθr cos(φr − φi) (Torrance & Sparrow 1967), where 2β is the
  angle between the two directions (the phase angle g of planetary photometry) and β the
  half angle; the unnormalised half vector is v = ωi + ωr, h = v/|v|, cos β = |v|/2 = ωi·h,
  and the facet-normal polar angle θh has cos θh = v_z/|v|.
* The in-plane (flatland) signed angles of Sasaki (2020, PhD thesis, Univ. of Minnesota,
  ch. 2) are s_i = atan2(−x_i, z_i) and s_r = atan2(x_r, z_r): the specular ray continues
  "straight through" (s_r = s_i).

Grazing incidence
-----------------
cos θ is floored at :data:`MU_FLOOR` (= 1e-12, i.e. within 1e-12 rad of grazing). Models
that diverge at grazing (every microfacet model when both directions graze, Oren–Nayar,
Lommel–Seeliger) therefore return large but finite values there, never NaN or inf; elsewhere
the floor changes nothing at double precision. When v = 0 exactly (both directions grazing and
exactly opposite, i.e. the grazing mirror configuration) the half vector is taken as the normal.
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

MU_FLOOR = 1e-12
"""Smallest cos θ used in any denominator (see the module docstring)."""

_ANGLE_TOL = 1e-9


def direction(theta: ArrayLike, phi: ArrayLike) -> NDArray[np.float64]:
    """Unit vector(s) (sinθ cosφ, sinθ sinφ, cosθ) with shape ``broadcast(theta, phi) + (3,)``."""
    t = np.asarray(theta, dtype=float)
    p = np.asarray(phi, dtype=float)
    st = np.sin(t)
    return np.stack(np.broadcast_arrays(st * np.cos(p), st * np.sin(p), np.cos(t)), axis=-1)


def angles_from_vector(vec: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Polar angle from +z and azimuth from +x of vectors of shape (..., 3) (need not be unit)."""
    v = np.asarray(vec, dtype=float)
    norm = np.linalg.norm(v, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cz = np.where(norm > 0, v[..., 2] / np.where(norm > 0, norm, 1.0), 1.0)
    theta = np.arccos(np.clip(cz, -1.0, 1.0))
    phi = np.arctan2(v[..., 1], v[..., 0])
    return theta, phi


def mirror_direction(theta_i: ArrayLike, phi_i: ArrayLike) -> tuple[NDArray[Any], NDArray[Any]]:
    """(θ, φ) of the specular direction for incidence (θi, φi): (θi, φi + π) wrapped to (−π, π]."""
    t = np.asarray(theta_i, dtype=float)
    p = np.asarray(phi_i, dtype=float) + np.pi
    return t, np.angle(np.exp(1j * p))


@dataclass(frozen=True)
class Geometry:
    """Precomputed geometry of a set of (ωi, ωr) pairs; every array has the same shape S.

    Building it once and reusing it is what makes repeated model evaluation (fitting)
    cheap: nothing in here depends on model parameters.

    Attributes
    ----------
    xi, yi, mu_i, xr, yr, mu_r : ndarray, shape S
        Components of ωi and ωr; ``mu_*`` are cos θ floored at :data:`MU_FLOOR`.
    cos_2beta : ndarray
        ωi·ωr (cosine of the phase angle).
    v_norm : ndarray
        |ωi + ωr| = 2 cos β.
    vx, vy, vz : ndarray
        Components of the unnormalised half vector v = ωi + ωr.
    cos_theta_h : ndarray
        cos θh = v_z / |v| (1 where v = 0).
    tan2_theta_h : ndarray
        tan² θh = (v_x² + v_y²) / v_z², finite because v_z ≥ 2·MU_FLOOR.
    cos_beta : ndarray
        ωi·h = |v|/2.
    cos_alpha : ndarray
        ωr · mirror(ωi) = μiμr − xi xr − yi yr (Phong lobe angle).
    s_i, s_r : ndarray
        Signed in-plane (flatland) angles, see the module docstring.
    cache : dict
        Scratch space for derived geometries (e.g. instrument offsets); excluded from equality.
    """

    xi: NDArray[np.float64]
    yi: NDArray[np.float64]
    mu_i: NDArray[np.float64]
    xr: NDArray[np.float64]
    yr: NDArray[np.float64]
    mu_r: NDArray[np.float64]
    cache: dict[Any, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def shape(self) -> tuple[int, ...]:
        return self.mu_i.shape

    @property
    def vx(self) -> NDArray[np.float64]:
        return self.xi + self.xr

    @property
    def vy(self) -> NDArray[np.float64]:
        return self.yi + self.yr

    @property
    def vz(self) -> NDArray[np.float64]:
        return self.mu_i + self.mu_r

    @property
    def cos_2beta(self) -> NDArray[np.float64]:
        return self._get("cos_2beta", self._cos_2beta)

    def _cos_2beta(self) -> NDArray[np.float64]:
        c = self.xi * self.xr + self.yi * self.yr + self.mu_i * self.mu_r
        return np.clip(c, -1.0, 1.0)

    @property
    def v_norm(self) -> NDArray[np.float64]:
        return self._get("v_norm", lambda: np.sqrt(self.vx**2 + self.vy**2 + self.vz**2))

    @property
    def cos_beta(self) -> NDArray[np.float64]:
        return self._get("cos_beta", lambda: np.clip(0.5 * self.v_norm, 0.0, 1.0))

    @property
    def cos_theta_h(self) -> NDArray[np.float64]:
        def compute() -> NDArray[np.float64]:
            n = self.v_norm
            safe = np.where(n > 0, n, 1.0)
            return np.where(n > 0, np.clip(self.vz / safe, 0.0, 1.0), 1.0)

        return self._get("cos_theta_h", compute)

    @property
    def tan2_theta_h(self) -> NDArray[np.float64]:
        return self._get("tan2_theta_h", lambda: (self.vx**2 + self.vy**2) / self.vz**2)

    @property
    def cos_alpha(self) -> NDArray[np.float64]:
        def compute() -> NDArray[np.float64]:
            c = self.mu_i * self.mu_r - self.xi * self.xr - self.yi * self.yr
            return np.clip(c, -1.0, 1.0)

        return self._get("cos_alpha", compute)

    @property
    def s_i(self) -> NDArray[np.float64]:
        return np.arctan2(-self.xi, self.mu_i)

    @property
    def s_r(self) -> NDArray[np.float64]:
        return np.arctan2(self.xr, self.mu_r)

    @property
    def sin_theta_i(self) -> NDArray[np.float64]:
        return np.sqrt(np.clip(self.xi**2 + self.yi**2, 0.0, 1.0))

    @property
    def sin_theta_r(self) -> NDArray[np.float64]:
        return np.sqrt(np.clip(self.xr**2 + self.yr**2, 0.0, 1.0))

    def _get(self, key: Hashable, compute: Any) -> NDArray[np.float64]:
        if key not in self.cache:
            self.cache[key] = compute()
        return self.cache[key]

    def swapped(self) -> Geometry:
        """The geometry with ωi and ωr exchanged (for reciprocity checks)."""
        return Geometry(self.xr, self.yr, self.mu_r, self.xi, self.yi, self.mu_i)

    def take(self, index: Any) -> Geometry:
        """A sub-geometry ``g[index]`` (boolean mask or integer index on the flat arrays)."""
        return Geometry(
            self.xi[index],
            self.yi[index],
            self.mu_i[index],
            self.xr[index],
            self.yr[index],
            self.mu_r[index],
        )

    @property
    def omega_i(self) -> NDArray[np.float64]:
        """ωi as shape S + (3,)."""
        return np.stack([self.xi, self.yi, self.mu_i], axis=-1)

    @property
    def omega_r(self) -> NDArray[np.float64]:
        """ωr as shape S + (3,)."""
        return np.stack([self.xr, self.yr, self.mu_r], axis=-1)


def _check_polar(theta: NDArray[np.float64], name: str) -> None:
    if theta.size == 0:
        return
    lo, hi = float(np.min(theta)), float(np.max(theta))  # NaN propagates into both
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError(f"{name} contains NaN or inf")
    if lo < -_ANGLE_TOL or hi > np.pi / 2 + _ANGLE_TOL:
        raise ValueError(f"{name} must lie in [0, pi/2] radians (upper hemisphere)")


def flat_angles(*arrays: ArrayLike) -> list[NDArray[np.float64]]:
    """The angle arrays as 1-D float64 copies broadcast to one length (per-point tables)."""
    out = np.broadcast_arrays(*(np.asarray(a, dtype=float).reshape(-1) for a in arrays))
    return [np.array(a, dtype=float) for a in out]


def make_geometry(
    theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike, phi_r: ArrayLike
) -> Geometry:
    """Geometry of (θi, φi, θr, φr) in radians, broadcast together (conventions above).

    Raises
    ------
    ValueError
        If a polar angle is outside [0, π/2] or not finite.
    """
    ti, pi_, tr, pr = np.broadcast_arrays(
        *(np.asarray(a, dtype=float) for a in (theta_i, phi_i, theta_r, phi_r))
    )
    _check_polar(ti, "theta_i")
    _check_polar(tr, "theta_r")
    ti = np.clip(ti, 0.0, np.pi / 2)
    tr = np.clip(tr, 0.0, np.pi / 2)
    sti, str_ = np.sin(ti), np.sin(tr)
    return Geometry(
        xi=sti * np.cos(pi_),
        yi=sti * np.sin(pi_),
        mu_i=np.maximum(np.cos(ti), MU_FLOOR),
        xr=str_ * np.cos(pr),
        yr=str_ * np.sin(pr),
        mu_r=np.maximum(np.cos(tr), MU_FLOOR),
    )


def geometry_from_vectors(omega_i: ArrayLike, omega_r: ArrayLike) -> Geometry:
    """Geometry from direction vectors of shape (..., 3); they are normalised here and
    their z components floored at :data:`MU_FLOOR` (a vector below the horizon is
    treated as grazing — callers mask such points)."""
    wi = np.asarray(omega_i, dtype=float)
    wr = np.asarray(omega_r, dtype=float)
    wi = wi / np.linalg.norm(wi, axis=-1, keepdims=True)
    wr = wr / np.linalg.norm(wr, axis=-1, keepdims=True)
    wi, wr = np.broadcast_arrays(wi, wr)
    return Geometry(
        xi=wi[..., 0].copy(),
        yi=wi[..., 1].copy(),
        mu_i=np.maximum(wi[..., 2], MU_FLOOR),
        xr=wr[..., 0].copy(),
        yr=wr[..., 1].copy(),
        mu_r=np.maximum(wr[..., 2], MU_FLOOR),
    )
