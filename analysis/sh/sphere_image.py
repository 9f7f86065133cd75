"""From a camera image of a sphere to directions and spherical-harmonic coefficients.

Geometry (Mahajan et al. 2008 §7): a single view of a convex
sphere of known centre and radius gives, per pixel, the surface normal n and the reflected
view direction R = 2(n·v)n − v. The image is then a function of R (reflected
parameterisation, for mirror-like lobes such as Phong) or of n (normal parameterisation, for
the diffuse part), and is fitted with real spherical harmonics from the observed pixels only
(:func:`analysis.sh.transform.fit_scattered`).

Frames and conventions:

* Pixel (row i, column j) has its centre at (x, y) = (j, i) in pixel units; image rows grow
  downwards.
* World frame: +x along image columns, +y up (against image rows), +z towards the viewer.
  A distant (orthographic) viewer has v = +z for every pixel.
* With ``intrinsics`` (3×3 pinhole matrix K, fx, fy, cx, cy in pixels) the view direction
  varies per pixel: the ray through pixel (x, y) is d ∝ ((x−cx)/fx, −(y−cy)/fy, −1) and
  v = −d; the sphere is placed at unit distance along the ray through its image centre
  with the angular radius arctan(radius/fx).
* Directions on the sphere are (θ colatitude from +z, φ azimuth from +x), as everywhere in
  :mod:`analysis.sh`.

For an orthographic view the pixels are uniform in R-solid-angle (dΩ_R = 4(n·v)dΩ_n and
the pixel area is r²(n·v)dΩ_n), so unit weights are already a quadrature in R; grazing pixels
(n·v → 0) map to R → −v, the only region a single view cannot see.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from analysis.sh.filters import lambertian_filter
from analysis.sh.transform import (
    ScatteredFitOperator,
    SHFit,
    directions_to_angles,
    evaluate,
    fit_scattered,
    scattered_fit_operator,
)
from analysis.sh.validation import (
    SHInputError,
    check_coefficients,
    check_degree,
    check_finite,
    check_scalar,
)

__all__ = [
    "SphereGeometry",
    "image_fit_operator",
    "image_to_sh",
    "images_to_sh",
    "irradiance_image",
    "mirror_sphere_lighting",
    "sh_to_image",
    "sphere_geometry",
    "sphere_samples",
]

Parameterisation = Literal["reflected", "normal"]


def _parameterisation(value: str) -> str:
    if value not in ("reflected", "normal"):
        raise SHInputError("parameterisation", f"must be 'reflected' or 'normal', got {value!r}")
    return value


def _geometry(geometry: object) -> SphereGeometry:
    if not isinstance(geometry, SphereGeometry):
        raise SHInputError("geometry", "must be a SphereGeometry (sphere_geometry())")
    return geometry


@dataclass(frozen=True)
class SphereGeometry:
    """Per-pixel geometry of a sphere image.

    Attributes
    ----------
    on_sphere : ndarray of bool, shape (H, W)
        Pixel centre lies on the sphere.
    observed : ndarray of bool, shape (H, W)
        On the sphere and viewed at less than ``max_view_angle`` from the normal.
    normals, view, reflected : ndarray of shape (H, W, 3)
        Unit normal n, unit direction to the viewer v, reflected view direction R
        (zero off the sphere).
    cos_view : ndarray of shape (H, W)
        n·v (0 off the sphere).
    max_view_angle : float
        The grazing cut-off in radians.
    """

    on_sphere: np.ndarray
    observed: np.ndarray
    normals: np.ndarray
    view: np.ndarray
    reflected: np.ndarray
    cos_view: np.ndarray
    max_view_angle: float


def sphere_geometry(
    shape: tuple[int, int],
    *,
    center: tuple[float, float],
    radius: float,
    intrinsics: np.ndarray | None = None,
    max_view_angle_deg: float = 80.0,
) -> SphereGeometry:
    """Pixel → normal → reflected direction for a sphere seen in an image.

    Parameters
    ----------
    shape : (H, W)
    center : (x, y)
        Image of the sphere centre in pixels (column, row).
    radius : float
        Radius of the sphere's image in pixels.
    intrinsics : ndarray of shape (3, 3), optional
        Pinhole camera matrix; omit for a distant (orthographic) viewer.
    max_view_angle_deg : float
        Pixels with angle(n, v) above this are not "observed" (grazing, unreliable).
    """
    try:
        h, w = shape
    except (TypeError, ValueError):
        raise SHInputError("shape", f"must be (H, W), got {shape!r}") from None
    h, w = check_degree("shape", h, minimum=1), check_degree("shape", w, minimum=1)
    cen = check_finite("center", center)
    if cen.shape != (2,):
        raise SHInputError("center", f"must be (x, y) in pixels, got {center!r}")
    radius = check_scalar("radius", radius, low=0.0, low_open=True)
    max_view_angle_deg = check_scalar("max_view_angle_deg", max_view_angle_deg, low=0.0,
                                      high=90.0, low_open=True)
    if intrinsics is not None:
        intrinsics = check_finite("intrinsics", intrinsics)
        if intrinsics.shape != (3, 3) or intrinsics[0, 0] <= 0 or intrinsics[1, 1] <= 0:
            raise SHInputError("intrinsics", "must be a 3 × 3 pinhole matrix with focal "
                               "lengths > 0")
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    cx, cy = cen
    if intrinsics is None:
        u = (xx - cx) / radius
        t = -(yy - cy) / radius
        rho2 = u * u + t * t
        on = rho2 < 1.0
        nz = np.sqrt(np.clip(1.0 - rho2, 0.0, None))
        normals = np.stack([u, t, nz], axis=-1)
        view = np.broadcast_to(np.array([0.0, 0.0, 1.0]), normals.shape).copy()
    else:
        k = np.asarray(intrinsics, dtype=float)
        fx, fy, kx, ky = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        d = np.stack([(xx - kx) / fx, -(yy - ky) / fy, -np.ones_like(xx)], axis=-1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        c = np.array([(cx - kx) / fx, -(cy - ky) / fy, -1.0])
        c /= np.linalg.norm(c)
        sin_a = np.sin(np.arctan(radius / fx))
        dc = d @ c
        disc = dc * dc - (1.0 - sin_a * sin_a)
        on = disc > 0
        tt = dc - np.sqrt(np.clip(disc, 0.0, None))
        p = tt[..., None] * d
        normals = (p - c) / sin_a
        normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
        view = -d
    cos_v = np.sum(normals * view, axis=-1)
    refl = 2.0 * cos_v[..., None] * normals - view
    zero = ~on
    normals = np.where(zero[..., None], 0.0, normals)
    refl = np.where(zero[..., None], 0.0, refl)
    cos_v = np.where(zero, 0.0, cos_v)
    max_angle = np.deg2rad(max_view_angle_deg)
    observed = on & (cos_v > np.cos(max_angle))
    return SphereGeometry(on, observed, normals, view, refl, cos_v, float(max_angle))


def _valid(image: np.ndarray, geometry: SphereGeometry, valid: np.ndarray | None) -> np.ndarray:
    geometry = _geometry(geometry)
    img = np.asarray(image, dtype=float)
    if img.shape != geometry.on_sphere.shape:
        raise SHInputError("image", f"must have the geometry's shape "
                           f"{geometry.on_sphere.shape}, got {img.shape}")
    # Non-finite pixels mark unusable data (saturated, outside the HDR range): left out.
    use = geometry.observed & np.isfinite(img)
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        if v.shape != img.shape:
            raise SHInputError("valid", f"must have the image's shape {img.shape}, got "
                               f"{v.shape}")
        use &= v
    return use


def sphere_samples(
    image: np.ndarray,
    geometry: SphereGeometry,
    *,
    parameterisation: Parameterisation = "reflected",
    valid: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observed pixels of an HDR radiance image as samples on the sphere of directions.

    Parameters
    ----------
    image : ndarray of shape (H, W)
        Linear (HDR) radiance; non-finite pixels are ignored.
    geometry : SphereGeometry
    parameterisation : {"reflected", "normal"}
    valid : bool ndarray of shape (H, W), optional
        Extra validity (e.g. not saturated in any usable exposure).

    Returns
    -------
    theta, phi, values : ndarray of shape (N,)
    """
    use = _valid(image, geometry, valid)
    dirs = (geometry.reflected if _parameterisation(parameterisation) == "reflected"
            else geometry.normals)
    th, ph = directions_to_angles(dirs[use])
    return th, ph, np.asarray(image, dtype=float)[use]


def image_to_sh(
    image: np.ndarray,
    geometry: SphereGeometry,
    *,
    lmax: int,
    parameterisation: Parameterisation = "reflected",
    valid: np.ndarray | None = None,
    variance: np.ndarray | None = None,
    ridge: float = 0.0,
) -> SHFit:
    """SH coefficients of a sphere image (B_lm) by a masked least-squares fit.

    Parameters
    ----------
    image : ndarray of shape (H, W)
        Linear (HDR) radiance.
    geometry : SphereGeometry
    lmax : int
    parameterisation : {"reflected", "normal"}
    valid : bool ndarray of shape (H, W), optional
        Usable pixels (e.g. unsaturated in some exposure of the HDR bracket).
    variance : ndarray of shape (H, W), optional
        Per-pixel noise variance of an HDR merge; the fit then weights pixels by 1/variance
        (pixels with variance ≤ 0 or non-finite are dropped). Default: equal weights, which
        for an orthographic view in the reflected parameterisation are also uniform in
        solid angle.
    ridge : float
        Regularises the degrees that the unobserved cap around −v leaves poorly determined.
    """
    th, ph, vals = sphere_samples(image, geometry, parameterisation=parameterisation,
                                  valid=valid)
    weights = None
    if variance is not None:
        var = np.asarray(variance, dtype=float)
        if var.shape != geometry.on_sphere.shape:
            raise SHInputError("variance", f"must have the image's shape "
                               f"{geometry.on_sphere.shape}, got {var.shape}")
        use = _valid(image, geometry, valid)
        v = var[use]
        weights = np.where(np.isfinite(v) & (v > 0), 1.0 / np.where(v > 0, v, 1.0), 0.0)
    return fit_scattered(vals, th, ph, lmax=lmax, weights=weights, ridge=ridge)


def sh_to_image(
    coeffs: np.ndarray,
    geometry: SphereGeometry,
    *,
    parameterisation: Parameterisation = "reflected",
) -> np.ndarray:
    """Render SH coefficients back onto the sphere's pixels (NaN off the sphere).

    Returns
    -------
    ndarray of shape (H, W)
    """
    geometry = _geometry(geometry)
    c, _ = check_coefficients("coeffs", coeffs)
    out = np.full(geometry.on_sphere.shape, np.nan)
    dirs = (geometry.reflected if _parameterisation(parameterisation) == "reflected"
            else geometry.normals)
    th, ph = directions_to_angles(dirs[geometry.on_sphere])
    out[geometry.on_sphere] = evaluate(c, th, ph)
    return out


def irradiance_image(lighting: np.ndarray, geometry: SphereGeometry) -> np.ndarray:
    """Lambertian irradiance E(n) at each pixel's normal from lighting coefficients.

    E_lm = Â_l L_lm with the exact clamped-cosine filter up to the lighting's band limit;
    fitted in the reflected parameterisation this gives the D_lm of M12. NaN off the sphere.
    """
    lig, lmax = check_coefficients("lighting", lighting)
    a = lambertian_filter(lmax).values
    l_idx = np.repeat(np.arange(lmax + 1), 2 * np.arange(lmax + 1) + 1)
    return sh_to_image(lig * a[l_idx], geometry, parameterisation="normal")


def mirror_sphere_lighting(
    image: np.ndarray,
    geometry: SphereGeometry,
    *,
    lmax: int,
    reflectance: float = 1.0,
    valid: np.ndarray | None = None,
    ridge: float = 0.0,
) -> SHFit:
    """Lighting L_lm from an HDR image of a mirror sphere (light probe).

    A mirror pixel shows L(R)·reflectance (R the reflected view direction, i.e. the direction
    the light arrives from), so the lighting is the reflected-parameterisation fit of
    image/reflectance. Directions near −v (behind the sphere) are unobserved; ``ridge``
    keeps the fit bounded there.
    """
    reflectance = check_scalar("reflectance", reflectance, low=0.0, low_open=True)
    img = np.asarray(image, dtype=float) / reflectance
    return image_to_sh(img, geometry, lmax=lmax, parameterisation="reflected", valid=valid,
                       ridge=ridge)


def image_fit_operator(
    geometry: SphereGeometry,
    *,
    lmax: int,
    parameterisation: Parameterisation = "reflected",
    ridge: float = 0.0,
) -> ScatteredFitOperator:
    """The fit of :func:`image_to_sh` for every observed pixel, precomputed once.

    For stacks of images of one geometry with no per-image invalid pixels
    (:func:`images_to_sh`).
    """
    geometry = _geometry(geometry)
    dirs = (geometry.reflected if _parameterisation(parameterisation) == "reflected"
            else geometry.normals)
    th, ph = directions_to_angles(dirs[geometry.observed])
    return scattered_fit_operator(th, ph, lmax=lmax, ridge=ridge)


def images_to_sh(images: np.ndarray, operator: ScatteredFitOperator,
                 geometry: SphereGeometry) -> np.ndarray:
    """B_lm of a stack of images (K, H, W) → ((L+1)², K) with a shared fit operator.

    Raises if an observed pixel is not finite (use :func:`image_to_sh` per image then).
    """
    geometry = _geometry(geometry)
    imgs = np.asarray(images, dtype=float)
    if imgs.ndim != 3 or imgs.shape[1:] != geometry.on_sphere.shape:
        raise SHInputError("images", f"must have shape (K, *{geometry.on_sphere.shape}), got "
                           f"{imgs.shape}")
    vals = imgs[:, geometry.observed].T  # (N, K)
    if not np.all(np.isfinite(vals)):
        raise SHInputError("images", "has non-finite observed pixels: fit these images one "
                           "by one with image_to_sh, which leaves them out")
    return operator.apply(vals)
