"""Continuous-geometry renderer of the light field scattered by a wall off hidden objects.

The unfolded flatland scene of Sasaki 2020 (PhD thesis, Univ. of Minnesota, eqs. 2-3, 2-6): hidden
objects at depths z < 0 in front of a scattering wall at z = 0, and a measurement plane at
z = d2 where the camera on its linear stage samples rays ``(y_m, θ_m)``.  For each camera
sample the renderer traces the ray back to its wall point ``c = y_m − d2 tan θ_m``, finds in
closed form the interval of incident angles θ_o whose rays hit each object (tangent angles
to a disc, end points of a bar), and integrates
``∫ f(c, θ_o − Θ(c), θ_m − Θ(c)) cos⁺(θ_o − Θ(c)) L_k(c, θ_o) dθ_o`` over that interval.
By default the specular lobe is integrated in its own variable over its window
(:mod:`hw_mocks.sim.lightfield_lobe`: bounded cost at any specular width, the perfect
mirror as its limit); ``renderer="reference"`` integrates the whole interval by composite
Gauss–Legendre quadrature with panels a fraction of the specular width (cost ∝ 1/width).

This is deliberately *not* the discretised operator of ``analysis.lightfield.forward``:
no angle grid, no interpolation, objects integrated over their exact angular extent,
including incident angles outside any reconstruction domain (no inverse crime).
Objects are assumed not to shadow one another (their contributions add).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.lightfield.brdf import MATERIALS, FlatlandBRDF, SpatiallyVaryingBRDF
from analysis.lightfield.field import LightField2D, theta_grid
from hw_mocks.sim import lightfield_lobe

__all__ = [
    "MATERIALS",
    "RENDERERS",
    "BarObject",
    "HiddenScene",
    "PointObject",
    "Wall",
]

_HALF_PI = np.pi / 2 - 1e-9
_GL_NODES = 8
_CHUNK = 2_000_000
#: The renderers of :meth:`HiddenScene.radiance` (the class docstring).
RENDERERS = ("lobe", "reference")


@dataclass(frozen=True)
class PointObject:
    """A small emitter (a flatland disc) at (y_mm, z_mm), z_mm < 0 (in front of the wall).

    ``profile="disc"``: uniform radiance over rays that hit the disc of ``radius_mm``;
    ``profile="gaussian"``: radiance ``R exp(−δ²/(2 r²))`` with δ the ray's perpendicular
    distance from the centre and r = ``radius_mm`` (a smooth, band-limited-like source).
    """

    y_mm: float
    z_mm: float
    radius_mm: float = 1.0
    radiance: float = 1.0
    profile: str = "disc"

    def __post_init__(self) -> None:
        if self.z_mm >= 0 or self.radius_mm <= 0:
            raise ValueError("need z_mm < 0 and radius_mm > 0")
        if self.profile not in ("disc", "gaussian"):
            raise ValueError("profile must be 'disc' or 'gaussian'")

    @property
    def uniform_radiance(self) -> float | None:
        """The radiance of every ray that meets a disc; None for the Gaussian profile."""
        return self.radiance if self.profile == "disc" else None

    def interval(self, c: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        """Incident-angle interval at wall points c whose rays meet the object (rad)."""
        dy = c - self.y_mm
        depth = -self.z_mm
        centre = np.arctan2(dy, depth)
        rho = np.hypot(dy, depth)
        reach = self.radius_mm if self.profile == "disc" else 5.0 * self.radius_mm
        half = np.arcsin(np.clip(reach / rho, 0.0, 1.0))
        return centre - half, centre + half

    def radiance_at(self, c: NDArray[np.float64], theta: NDArray[np.float64]) -> NDArray:
        """Radiance of the ray arriving at wall point c with angle θ (0 if it misses)."""
        dy = c - self.y_mm
        depth = -self.z_mm
        # perpendicular distance of the ray {(c + t sinθ, t cosθ)} from the centre
        delta = np.abs(dy * np.cos(theta) - depth * np.sin(theta))
        if self.profile == "disc":
            return np.where(delta <= self.radius_mm, self.radiance, 0.0)
        return self.radiance * np.exp(-0.5 * (delta / self.radius_mm) ** 2)


@dataclass(frozen=True)
class BarObject:
    """A bright bar: the segment y ∈ [y_min_mm, y_max_mm] at depth z_mm < 0, uniform radiance."""

    y_min_mm: float
    y_max_mm: float
    z_mm: float
    radiance: float = 1.0

    def __post_init__(self) -> None:
        if self.z_mm >= 0 or self.y_max_mm <= self.y_min_mm:
            raise ValueError("need z_mm < 0 and y_max_mm > y_min_mm")

    @property
    def uniform_radiance(self) -> float:
        """The radiance of every ray that meets the bar."""
        return self.radiance

    def interval(self, c: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        """Rays from c with ``c − |z| tan θ ∈ [y_min, y_max]``."""
        depth = -self.z_mm
        return np.arctan((c - self.y_max_mm) / depth), np.arctan((c - self.y_min_mm) / depth)

    def radiance_at(self, c: NDArray[np.float64], theta: NDArray[np.float64]) -> NDArray:
        """Radiance of the ray arriving at c with angle θ."""
        y = c + self.z_mm * np.tan(theta)
        return np.where((y >= self.y_min_mm) & (y <= self.y_max_mm), self.radiance, 0.0)


@dataclass(frozen=True)
class Wall:
    """The scattering wall: extent in y (mm), BRDF, local normal angle Θ(c) (rad)."""

    y_min_mm: float
    y_max_mm: float
    brdf: FlatlandBRDF | SpatiallyVaryingBRDF | Callable[..., NDArray]
    normal_angle_rad: float | Callable[[NDArray[np.float64]], NDArray[np.float64]] = 0.0

    def normal_at(self, c: NDArray[np.float64]) -> NDArray[np.float64]:
        """Θ at wall points c."""
        if callable(self.normal_angle_rad):
            return np.asarray(self.normal_angle_rad(c), dtype=float)
        return np.full(np.shape(c), float(self.normal_angle_rad))


def _gl_panels(n_panels: int) -> tuple[NDArray, NDArray]:
    x, w = np.polynomial.legendre.leggauss(_GL_NODES)
    x = (x + 1) / 2
    w = w / 2
    starts = np.arange(n_panels) / n_panels
    nodes = (starts[:, None] + x[None, :] / n_panels).ravel()
    weights = np.tile(w / n_panels, n_panels)
    return nodes, weights


@dataclass(frozen=True)
class HiddenScene:
    """Objects, wall and measurement-plane distance of the unfolded scene.

    Parameters
    ----------
    objects : sequence of PointObject / BarObject
    wall : Wall
    d2_mm : float — wall → measurement plane distance (mm)
    panel_rad : float, optional — the reference quadrature's Gauss–Legendre panel width
        (default: a quarter of the BRDF's specular width, or 2 mrad)
    renderer : ``"lobe"`` (default) or ``"reference"`` — the lobe-adaptive integration of
        :mod:`hw_mocks.sim.lightfield_lobe` (cost bounded at any specular width), or the
        panel quadrature over each object's whole interval described above (cost ∝ 1/σ;
        kept as the check of the other).  A wall whose BRDF the lobe renderer does not
        know (a plain callable) is rendered by the reference.
    """

    objects: tuple[PointObject | BarObject, ...]
    wall: Wall
    d2_mm: float
    panel_rad: float | None = None
    renderer: str = "lobe"
    _panel: float = field(init=False, repr=False, default=0.0)

    def __post_init__(self) -> None:
        if self.renderer not in RENDERERS:
            raise ValueError(f"renderer = {self.renderer!r}; choose one of {RENDERERS}")
        object.__setattr__(self, "objects", tuple(self.objects))
        base = getattr(self.wall.brdf, "base", self.wall.brdf)
        width = getattr(base, "specular_width_rad", None)
        panel = self.panel_rad or (0.25 * width if width else 2e-3)
        object.__setattr__(self, "_panel", float(panel))

    def incident_radiance(self, c_mm: ArrayLike, theta_rad: ArrayLike) -> NDArray[np.float64]:
        """Ground truth: radiance arriving at wall point c from direction θ (broadcasting)."""
        c = np.asarray(c_mm, dtype=float)
        t = np.asarray(theta_rad, dtype=float)
        c, t = np.broadcast_arrays(c, t)
        out = np.zeros(c.shape)
        for obj in self.objects:
            out = out + obj.radiance_at(c, t)
        return out

    def truth_field(
        self, wall_y_mm: NDArray[np.float64], domain_rad: tuple[float, float], n_theta: int
    ) -> LightField2D:
        """Ground-truth incident field at the wall on a grid (z = 0)."""
        th = theta_grid(domain_rad, n_theta)
        y = np.asarray(wall_y_mm, dtype=float)
        return LightField2D(self.incident_radiance(y[:, None], th[None, :]), y, th, domain_rad)

    def radiance(self, y_m_mm: ArrayLike, theta_m_rad: ArrayLike) -> NDArray[np.float64]:
        """Noise-free measured radiance at camera samples (y_m, θ_m) (broadcasting arrays).

        Returns the radiance leaving the wall toward the measurement plane along each
        ray; 0 for rays whose wall point lies off the wall.
        """
        ym, tm = np.broadcast_arrays(np.asarray(y_m_mm, float), np.asarray(theta_m_rad, float))
        shape = ym.shape
        ym = ym.ravel()
        tm = tm.ravel()
        out = np.zeros(ym.size)
        c = ym - self.d2_mm * np.tan(tm)
        on = (c >= self.wall.y_min_mm) & (c <= self.wall.y_max_mm)
        idx = np.nonzero(on)[0]
        if self.renderer == "lobe" and lightfield_lobe.supports(self.wall.brdf):
            out[idx] = lightfield_lobe.lobe_radiance(
                self.wall.brdf, self.wall.normal_at(c[idx]), self.objects, c[idx], tm[idx])
            return out.reshape(shape)
        for obj in self.objects:
            lo, hi = obj.interval(c[idx])
            lo = np.clip(lo, -_HALF_PI, _HALF_PI)
            hi = np.clip(hi, -_HALF_PI, _HALF_PI)
            span = float(np.max(hi - lo)) if idx.size else 0.0
            n_panels = max(1, int(np.ceil(span / self._panel)))
            nodes, weights = _gl_panels(n_panels)
            per = max(1, _CHUNK // nodes.size)
            for s in range(0, idx.size, per):
                sel = idx[s:s + per]
                a = lo[s:s + per, None]
                w = (hi - lo)[s:s + per, None]
                th_o = a + w * nodes[None, :]
                cc = c[sel][:, None]
                out[sel] += np.sum(
                    self._integrand(cc, th_o, tm[sel][:, None], obj) * w * weights[None, :],
                    axis=1,
                )
        return out.reshape(shape)

    def _integrand(self, c, th_o, th_m, obj) -> NDArray[np.float64]:
        tn = self.wall.normal_at(c)
        rel_o = th_o - tn
        rel_m = th_m - tn
        brdf = self.wall.brdf
        homogeneous = getattr(brdf, "homogeneous", True)
        f = brdf(rel_o, rel_m) if homogeneous else brdf(rel_o, rel_m, y_mm=c)
        return f * np.clip(np.cos(rel_o), 0.0, None) * obj.radiance_at(c, th_o)

    def measured_field(
        self, y_m_mm: NDArray[np.float64], domain_rad: tuple[float, float], n_theta: int
    ) -> LightField2D:
        """Noise-free measured light field on a (y_m, θ_m) grid at z = d2."""
        th = theta_grid(domain_rad, n_theta)
        y = np.asarray(y_m_mm, dtype=float)
        vals = self.radiance(y[:, None], th[None, :])
        return LightField2D(vals, y, th, domain_rad, self.d2_mm)
