"""Simulated sphere scenes: procedural environment lighting and rendered sphere radiance images.

Ground truth for the spherical-harmonic inverse-rendering analysis (Ramamoorthi & Hanrahan
2001; Mahajan, Ramamoorthi & Curless 2006). Images are rendered by numerical integration
over incoming directions, B(pixel) = ∫ L(ω) f(ω, v) (n·ω)⁺ dω, on a Gauss–Legendre product
quadrature much finer than any analysis order plus explicit sub-samples of each sharp
source, directly from the BRDF in the spatial domain: never with the SH convolution the
analysis inverts (no inverse crime; docs/architecture.md "The virtual bench").

Frames (shared with :mod:`analysis.sh.sphere_image`): world +x along image columns, +y up,
+z towards the distant (orthographic) viewer; pixel (row i, column j) has its centre at
(x, y) = (j, i). Radiance is in arbitrary linear units (the environment's units times the
BRDF's albedo); the simulated camera's sensor model turns it into counts.

API: environment (procedural :class:`EnvironmentMap` or an equirectangular radiance image,
:class:`EquirectEnvironment`) in, radiance image (H, W) out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.special import erf

from analysis.sh.legendre import gauss_legendre

__all__ = [
    "AreaLight",
    "EnvironmentMap",
    "EquirectEnvironment",
    "Lambertian",
    "LambertianMicrofacet",
    "Mirror",
    "Phong",
    "SharpSource",
    "SphereRender",
    "environment_coefficients",
    "random_environment",
    "render_sphere",
    "render_spheres",
    "shade",
]


def _unit(v: Sequence[float] | np.ndarray) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to ``axis`` (and to each other)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


@dataclass(frozen=True)
class AreaLight:
    """A soft-edged disc of light: radiance × ½(1 − tanh((angle − radius)/softness))."""

    direction: tuple[float, float, float]
    angular_radius: float
    radiance: float
    softness: float = 0.03


@dataclass(frozen=True)
class SharpSource:
    """A small uniform disc source (a lamp, the sun) of angular radius a few tenths of a degree
    to a few degrees; integrated by explicit sub-samples, not by the background grid."""

    direction: tuple[float, float, float]
    angular_radius: float
    radiance: float


@dataclass(frozen=True)
class EnvironmentMap:
    """Distant lighting: a sky gradient, soft area lights and sharp sources.

    The sky is piecewise linear in t = ω·up: horizon + (zenith − horizon)·t above the horizon
    and horizon + (horizon − ground)·t below it.
    """

    zenith: float = 0.6
    horizon: float = 0.35
    ground: float = 0.1
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    area_lights: tuple[AreaLight, ...] = ()
    sharp_sources: tuple[SharpSource, ...] = ()

    def smooth_radiance(self, directions: np.ndarray) -> np.ndarray:
        """Sky plus area lights at unit directions (..., 3)."""
        d = np.asarray(directions, dtype=float)
        t = d @ _unit(self.up)
        out = np.where(
            t >= 0,
            self.horizon + (self.zenith - self.horizon) * t,
            self.horizon + (self.horizon - self.ground) * t,
        )
        for a in self.area_lights:
            ang = np.arccos(np.clip(d @ _unit(a.direction), -1.0, 1.0))
            out = out + a.radiance * 0.5 * (1.0 - np.tanh((ang - a.angular_radius) / a.softness))
        return out

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """Full radiance including the sharp discs (point evaluation, e.g. for a mirror)."""
        d = np.asarray(directions, dtype=float)
        out = self.smooth_radiance(d)
        for s in self.sharp_sources:
            inside = d @ _unit(s.direction) >= np.cos(s.angular_radius)
            out = out + np.where(inside, s.radiance, 0.0)
        return out

    def sharp_samples(self, n_sub: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each sharp source as ``n_sub`` equal-area sub-samples over its disc.

        Returns directions (S, 3), solid-angle weights (S,) and radiance (S,).
        """
        extra_d, extra_w, extra_v = [np.zeros((0, 3))], [np.zeros(0)], [np.zeros(0)]
        for s in self.sharp_sources:
            axis = _unit(s.direction)
            e1, e2 = _frame(axis)
            k = np.arange(n_sub) + 0.5
            # equal-area rings in cos(angle) over the cap, golden-angle azimuths (Vogel)
            cos_a = 1.0 - (1.0 - np.cos(s.angular_radius)) * k / n_sub
            sin_a = np.sqrt(1.0 - cos_a**2)
            ang = k * np.pi * (3.0 - np.sqrt(5.0))
            sub = cos_a[:, None] * axis + sin_a[:, None] * (
                np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2
            )
            cap = 2.0 * np.pi * (1.0 - np.cos(s.angular_radius))
            extra_d.append(sub)
            extra_w.append(np.full(n_sub, cap / n_sub))
            extra_v.append(np.full(n_sub, s.radiance))
        return np.concatenate(extra_d), np.concatenate(extra_w), np.concatenate(extra_v)

    def quadrature(self, n_theta: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Directions (Q, 3), solid-angle weights (Q,) and radiance (Q,) for integration.

        The smooth part on an n_theta × 2·n_theta Gauss–Legendre product grid, plus the
        sub-samples of the sharp sources (:meth:`sharp_samples`).
        """
        dirs, w = _gl_directions(n_theta)
        vals = self.smooth_radiance(dirs)
        sd, sw, sv = self.sharp_samples()
        return np.concatenate([dirs, sd]), np.concatenate([w, sw]), np.concatenate([vals, sv])


@dataclass(frozen=True)
class EquirectEnvironment:
    """Lighting from an equirectangular radiance image (image-in).

    Row r spans colatitude θ ∈ [r, r+1)·π/H about the +y (up) axis, column c spans azimuth
    ∈ [c, c+1)·2π/W measured from +z towards +x; radiance is bilinear between pixel centres.
    """

    image: np.ndarray = field(repr=False)

    def _lookup(self, directions: np.ndarray) -> np.ndarray:
        img = np.asarray(self.image, dtype=float)
        h, w = img.shape
        d = np.asarray(directions, dtype=float)
        theta = np.arccos(np.clip(d[..., 1], -1.0, 1.0))
        phi = np.mod(np.arctan2(d[..., 0], d[..., 2]), 2.0 * np.pi)
        r = np.clip(theta / np.pi * h - 0.5, 0.0, h - 1.0)
        c = phi / (2.0 * np.pi) * w - 0.5
        r0 = np.floor(r).astype(int)
        c0 = np.floor(c).astype(int)
        fr, fc = r - r0, c - c0
        r1 = np.minimum(r0 + 1, h - 1)
        c0m, c1m = np.mod(c0, w), np.mod(c0 + 1, w)
        return ((1 - fr) * ((1 - fc) * img[r0, c0m] + fc * img[r0, c1m])
                + fr * ((1 - fc) * img[r1, c0m] + fc * img[r1, c1m]))

    def smooth_radiance(self, directions: np.ndarray) -> np.ndarray:
        return self._lookup(directions)

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        return self._lookup(directions)

    def sharp_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0)

    def quadrature(self, n_theta: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        dirs, w = _gl_directions(n_theta)
        return dirs, w, self._lookup(dirs)


class Environment(Protocol):
    """What the renderer needs from a lighting environment."""

    def radiance(self, directions: np.ndarray) -> np.ndarray: ...

    def smooth_radiance(self, directions: np.ndarray) -> np.ndarray: ...

    def sharp_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


def _gl_directions(n_theta: int) -> tuple[np.ndarray, np.ndarray]:
    theta, w = gauss_legendre(n_theta)
    n_phi = 2 * n_theta
    phi = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    tt, pp = np.meshgrid(theta, phi, indexing="ij")
    dirs = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], axis=-1)
    weights = np.broadcast_to(w[:, None] * (2.0 * np.pi / n_phi), tt.shape)
    return dirs.reshape(-1, 3), weights.reshape(-1).copy()


def random_environment(
    rng: np.random.Generator,
    *,
    n_area: int = 2,
    n_sharp: int = 2,
    sky_level: float = 0.4,
) -> EnvironmentMap:
    """A random procedural environment: sky gradient, soft area lights and sharp sources."""
    def direction() -> tuple[float, float, float]:
        v = rng.standard_normal(3)
        v /= np.linalg.norm(v)
        return (float(v[0]), float(v[1]), float(v[2]))

    areas = tuple(
        AreaLight(direction(), float(rng.uniform(0.15, 0.45)), float(rng.uniform(0.5, 2.0)),
                  float(rng.uniform(0.02, 0.06)))
        for _ in range(n_area)
    )
    sharps = tuple(
        SharpSource(direction(), float(np.deg2rad(rng.uniform(1.0, 3.0))),
                    float(rng.uniform(20.0, 60.0)))
        for _ in range(n_sharp)
    )
    z = float(rng.uniform(0.5, 1.5)) * sky_level
    return EnvironmentMap(
        zenith=z,
        horizon=float(rng.uniform(0.4, 0.9)) * z,
        ground=float(rng.uniform(0.1, 0.4)) * z,
        up=direction(),
        area_lights=areas,
        sharp_sources=sharps,
    )


@dataclass(frozen=True)
class Lambertian:
    """f = albedo/π."""

    albedo: float = 0.8


@dataclass(frozen=True)
class Phong:
    """Diffuse plus the reflection-space Phong lobe of Ramamoorthi & Hanrahan (SIGGRAPH 2001):
    kernel kd/π (n·ω)⁺ + ks (s+1)/(2π) ((R·ω)⁺)^s, with light from below the surface's
    horizon excluded (a physical sphere, not the idealised radially symmetric kernel)."""

    kd: float = 0.0
    ks: float = 1.0
    s: float = 50.0
    #: Exclude light from below the surface's horizon (physical). False gives the idealised
    #: radially symmetric kernel of the theory, for separating model error from noise.
    clip_horizon: bool = True


@dataclass(frozen=True)
class LambertianMicrofacet:
    """kd/π plus a Beckmann microfacet lobe ks·D G₂ F/(4 μi μo) (Walter et al. 2007), with
    height-correlated Smith G₂ (Heitz 2014) and Schlick Fresnel of normal reflectance f0."""

    kd: float = 0.5
    ks: float = 0.5
    alpha: float = 0.2
    f0: float = 1.0


@dataclass(frozen=True)
class Mirror:
    """A perfect mirror: the pixel shows reflectance × L(R)."""

    reflectance: float = 1.0


Brdf = Lambertian | Phong | LambertianMicrofacet | Mirror


def _beckmann_lambda(mu: np.ndarray, alpha: float) -> np.ndarray:
    mu = np.clip(mu, 1e-9, 1.0)
    # At normal incidence a → ∞ and a² overflowed; Λ(a) is below 1e−390 from a = 30 on,
    # i.e. exactly 0 in double precision, so a is capped there (same values, no overflow).
    a = np.minimum(mu / (alpha * np.sqrt(1.0 - mu * mu) + 1e-300), 30.0)
    return (erf(a) - 1.0) / 2.0 + np.exp(-a * a) / (2.0 * a * np.sqrt(np.pi))


def _kernel(brdf: Brdf, n: np.ndarray, v: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Kernel k(pixel, ω) with B = Σ_q w_q L_q k(·, ω_q), shape (P, Q)."""
    mu_i = n @ dirs.T  # (P, Q)
    above = mu_i > 0
    if isinstance(brdf, Lambertian):
        return np.where(above, brdf.albedo / np.pi * mu_i, 0.0)
    if isinstance(brdf, Phong):
        mu_o = np.sum(n * v, axis=1, keepdims=True)
        r = 2.0 * mu_o * n - v
        c = r @ dirs.T
        # (R·ω)^s below 1e−14 is dropped: skipping the power there is most of the cost
        c_min = np.exp(np.log(1e-14) / brdf.s)
        lobe = np.zeros_like(c)
        np.power(c, brdf.s, out=lobe, where=c > c_min)
        lobe *= brdf.ks * (brdf.s + 1.0) / (2.0 * np.pi)
        diffuse = np.where(above, brdf.kd / np.pi * mu_i, 0.0)
        return diffuse + (np.where(above, lobe, 0.0) if brdf.clip_horizon else lobe)
    if isinstance(brdf, LambertianMicrofacet):
        mu_o = np.sum(n * v, axis=1, keepdims=True)
        h = dirs[None, :, :] + v[:, None, :]
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        cos_h = np.clip(np.einsum("pqc,pc->pq", h, n), 1e-9, 1.0)
        tan2 = (1.0 - cos_h**2) / cos_h**2
        al2 = brdf.alpha**2
        d = np.exp(-tan2 / al2) / (np.pi * al2 * cos_h**4)
        g2 = 1.0 / (1.0 + _beckmann_lambda(mu_i, brdf.alpha)
                    + _beckmann_lambda(np.broadcast_to(mu_o, mu_i.shape), brdf.alpha))
        cos_d = np.clip(np.einsum("pqc,qc->pq", h, dirs), 0.0, 1.0)
        fres = brdf.f0 + (1.0 - brdf.f0) * (1.0 - cos_d) ** 5
        # the μi of the rendering equation cancels the 1/μi of the BRDF
        spec = brdf.ks * fres * d * g2 / (4.0 * np.clip(mu_o, 1e-9, None))
        return np.where(above, brdf.kd / np.pi * mu_i + spec, 0.0)
    raise TypeError(f"no kernel for {type(brdf).__name__}")


@dataclass(frozen=True)
class SphereRender:
    """Rendered sphere images.

    Attributes
    ----------
    radiance : ndarray of shape (H, W) or (K, H, W)
        Linear radiance; 0 off the sphere (black background).
    coverage : ndarray of shape (H, W)
        Fraction of each pixel's sub-samples that hit the sphere.
    center : (float, float)
    radius : float
    """

    radiance: np.ndarray
    coverage: np.ndarray
    center: tuple[float, float]
    radius: float


def _subpixel_normals(size: int, center: tuple[float, float], radius: float, ss: int):
    off = (np.arange(ss) + 0.5) / ss - 0.5
    yy, xx = np.mgrid[0:size, 0:size].astype(float)
    xs = xx[..., None, None] + off[None, None, None, :]
    ys = yy[..., None, None] + off[None, None, :, None]
    u, t = np.broadcast_arrays((xs - center[0]) / radius, -(ys - center[1]) / radius)
    rho2 = u * u + t * t
    hit = rho2 < 1.0
    nz = np.sqrt(np.clip(1.0 - rho2, 0.0, None))
    n = np.stack([u, t, nz], axis=-1).reshape(size, size, ss * ss, 3)
    return n, hit.reshape(size, size, ss * ss)


def render_spheres(
    environments: Sequence[Environment],
    brdf: Brdf,
    *,
    size: int = 64,
    radius: float | None = None,
    center: tuple[float, float] | None = None,
    n_theta: int = 128,
    supersample: int = 1,
    chunk: int = 96,
) -> SphereRender:
    """Render one sphere of a given BRDF under several environments (shared kernel).

    Parameters
    ----------
    environments : sequence of environments
    brdf : Lambertian | Phong | LambertianMicrofacet | Mirror
    size : int
        Image is size × size pixels.
    radius, center : optional
        Sphere image radius (default 0.45·size) and centre (default the image centre).
    n_theta : int
        Gauss–Legendre rings of the integration grid (2·n_theta longitudes); must resolve
        the narrowest lobe (Phong lobe width ≈ 1/√s rad) and the area lights' soft edges.
    supersample : int
        Sub-pixels per axis; pixel radiance is the mean over sub-pixels on the sphere.
    chunk : int
        Pixels per block of the (pixels × directions) kernel.

    Returns
    -------
    SphereRender
        ``radiance`` of shape (K, H, W) for K environments.
    """
    r = 0.45 * size if radius is None else float(radius)
    c = ((size - 1) / 2.0, (size - 1) / 2.0) if center is None else center
    normals, hit = _subpixel_normals(size, c, r, supersample)
    coverage = hit.mean(axis=-1)
    sel = hit.reshape(-1)
    n_all = normals.reshape(-1, 3)[sel]
    v_all = np.broadcast_to(np.array([0.0, 0.0, 1.0]), n_all.shape)
    n_env = len(environments)
    values = np.zeros((n_env, n_all.shape[0]))
    if isinstance(brdf, Mirror):
        refl = 2.0 * n_all[:, 2:3] * n_all - v_all
        for k, env in enumerate(environments):
            values[k] = brdf.reflectance * env.radiance(refl)
    else:
        # One kernel on the shared grid serves every environment's smooth part; each
        # environment's sharp sources get their own small kernel.
        dirs, w = _gl_directions(n_theta)
        wl = np.stack([w * env.smooth_radiance(dirs) for env in environments], axis=1)
        sharp = [env.sharp_samples() for env in environments]
        step = chunk if not isinstance(brdf, LambertianMicrofacet) else max(chunk // 4, 8)
        for p0 in range(0, n_all.shape[0], step):
            sl = slice(p0, p0 + step)
            ker = _kernel(brdf, n_all[sl], v_all[sl], dirs)
            values[:, sl] = (ker @ wl).T
            for k, (sd, sw, sv) in enumerate(sharp):
                if sd.shape[0]:
                    values[k, sl] += _kernel(brdf, n_all[sl], v_all[sl], sd) @ (sw * sv)
    full = np.zeros((n_env, size * size * supersample**2))
    full[:, sel] = values
    full = full.reshape(n_env, size, size, supersample**2)
    counts = hit.sum(axis=-1)
    radiance = np.where(counts > 0, full.sum(axis=-1) / np.maximum(counts, 1), 0.0)
    return SphereRender(radiance, coverage, c, r)


def shade(
    environment: Environment,
    brdf: Brdf,
    normals: np.ndarray,
    views: np.ndarray,
    *,
    n_theta: int = 128,
    chunk: int = 96,
) -> np.ndarray:
    """Outgoing radiance at surface points of given normal and view direction.

    B = ∫ L(ω) f(ω, v) (n·ω)⁺ dω by the same quadrature as :func:`render_spheres`
    (Gauss–Legendre grid for the smooth lighting, explicit sub-samples of the sharp
    sources), but for arbitrary per-point normals and views: a perspective camera, or an
    object turned relative to its lighting (rotate n and v into the lighting's frame).

    Parameters
    ----------
    environment : environment
    brdf : Lambertian | Phong | LambertianMicrofacet | Mirror
    normals, views : ndarray of shape (P, 3)
        Unit normals and unit directions towards the viewer, in the environment's frame.
    n_theta : int
        Gauss–Legendre rings of the integration grid (see :func:`render_spheres`).
    chunk : int
        Points per block of the (points × directions) kernel.

    Returns
    -------
    ndarray of shape (P,)
    """
    n_all = np.asarray(normals, dtype=float).reshape(-1, 3)
    v_all = np.asarray(views, dtype=float).reshape(-1, 3)
    if n_all.shape != v_all.shape:
        raise ValueError("normals and views must have the same shape (P, 3)")
    out = np.zeros(n_all.shape[0])
    if n_all.shape[0] == 0:
        return out
    if isinstance(brdf, Mirror):
        refl = 2.0 * np.sum(n_all * v_all, axis=1, keepdims=True) * n_all - v_all
        return brdf.reflectance * environment.radiance(refl)
    dirs, w = _gl_directions(n_theta)
    wl = w * environment.smooth_radiance(dirs)
    sd, sw, sv = environment.sharp_samples()
    step = chunk if not isinstance(brdf, LambertianMicrofacet) else max(chunk // 4, 8)
    for p0 in range(0, n_all.shape[0], step):
        sl = slice(p0, p0 + step)
        out[sl] = _kernel(brdf, n_all[sl], v_all[sl], dirs) @ wl
        if sd.shape[0]:
            out[sl] += _kernel(brdf, n_all[sl], v_all[sl], sd) @ (sw * sv)
    return out


def render_sphere(environment: Environment, brdf: Brdf, **kwargs) -> SphereRender:
    """Render one sphere under one environment; ``radiance`` of shape (H, W).

    Keyword arguments as for :func:`render_spheres`.
    """
    out = render_spheres([environment], brdf, **kwargs)
    return SphereRender(out.radiance[0], out.coverage, out.center, out.radius)


def environment_coefficients(
    environment: Environment | Sequence[Environment], lmax: int, *, n_theta: int = 160
) -> np.ndarray:
    """Ground-truth lighting coefficients L_lm (real, orthonormal, project convention).

    Quadrature of L(ω) Y_lm(ω) on the fine grid (exact for the band-limited part of the
    smooth lighting up to degree n_theta − lmax − 1) plus the sharp sources' sub-samples.

    Parameters
    ----------
    environment : environment or sequence of K environments
    lmax : int
    n_theta : int

    Returns
    -------
    ndarray of shape ((lmax+1)²,) or (K, (lmax+1)²)
    """
    from analysis.sh.transform import directions_to_angles, real_sh_matrix

    single = not isinstance(environment, Sequence)
    envs = [environment] if single else list(environment)
    dirs, w = _gl_directions(n_theta)
    vals = np.stack([env.smooth_radiance(dirs) * w for env in envs], axis=1)  # (Q, K)
    th, ph = directions_to_angles(dirs)
    out = np.zeros((len(envs), (lmax + 1) ** 2))
    step = 4096
    for p0 in range(0, th.size, step):
        y = real_sh_matrix(lmax, th[p0:p0 + step], ph[p0:p0 + step])
        out += vals[p0:p0 + step].T @ y
    for k, env in enumerate(envs):
        sd, sw, sv = env.sharp_samples()
        if sd.shape[0]:
            sth, sph = directions_to_angles(sd)
            out[k] += (sw * sv) @ real_sh_matrix(lmax, sth, sph)
    return out[0] if single else out
