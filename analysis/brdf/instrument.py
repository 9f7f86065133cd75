"""Instrument-aware models: average a BRDF over the detector aperture and the beam divergence.

A detector of half-angle a at ωr collects P ∝ ∫_cone f(ωi, ω) cos θ dω, and the reduction
divides by Ω cos θr of the cone centre, so the measured BRDF is

f_meas(ωi, ωr) = (1/Ω) ∫_cone(ωr, a) f(ωi, ω) cos θ / cos θr dω,

and likewise for a beam whose directions fill a cone of half-angle b about ωi, weighted by
cos θ'/cos θi (irradiance of each beam direction). Both cones are uniform (top-hat) in solid
angle. Near a sharp specular peak the measured lobe is this average, not the BRDF
(ASTM E2387 and ISO 19986 ask for the receiver solid angle to be reported with BRDF data).

Quadrature per cone: Gauss–Legendre in (1 − cos δ) (uniform in solid angle) with ``n_radial``
rings × ``n_azimuth`` equally spaced azimuths (offset by half a step on alternate rings).
Offset directions that fall below the horizon get weight 0 (the aperture is clipped).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from analysis.brdf.geometry import Geometry, geometry_from_vectors
from analysis.brdf.model import BRDFModel


@dataclass(frozen=True)
class ConeQuadrature:
    """Offsets (δ, χ) and weights (summing to 1) of a uniform cone of half-angle ``half_angle``."""

    half_angle: float
    delta: NDArray[np.float64]
    chi: NDArray[np.float64]
    weights: NDArray[np.float64]


def cone_quadrature(half_angle: float, *, n_radial: int = 3, n_azimuth: int = 8) -> ConeQuadrature:
    """Nodes of ∫_cone g dω / Ω; a zero half angle gives the single node δ = 0."""
    if half_angle < 0:
        raise ValueError("half_angle must be non-negative (radians)")
    if half_angle == 0:
        return ConeQuadrature(0.0, np.zeros(1), np.zeros(1), np.ones(1))
    t, w = np.polynomial.legendre.leggauss(n_radial)
    one_minus_c = 0.5 * (t + 1.0) * (1.0 - np.cos(half_angle))
    delta = np.arccos(1.0 - one_minus_c)
    chi = 2.0 * np.pi * (np.arange(n_azimuth)[None, :] + 0.5 * (np.arange(n_radial)[:, None] % 2))
    chi = chi / n_azimuth
    dd = np.repeat(delta, n_azimuth)
    ww = np.repeat(0.5 * w / n_azimuth, n_azimuth)
    return ConeQuadrature(float(half_angle), dd, chi.reshape(-1), ww)


def _offset_dirs(center: NDArray[Any], q: ConeQuadrature) -> NDArray[Any]:
    """Directions of shape (len(q), N, 3) around unit vectors ``center`` (N, 3)."""
    helper = np.where(
        (np.abs(center[:, 0]) < 0.9)[:, None], np.array([1.0, 0.0, 0.0]), np.array([0, 1.0, 0])
    )
    e1 = np.cross(center, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(center, e1)
    cd, sd = np.cos(q.delta)[:, None, None], np.sin(q.delta)[:, None, None]
    cc, sc = np.cos(q.chi)[:, None, None], np.sin(q.chi)[:, None, None]
    return cd * center[None] + sd * (cc * e1[None] + sc * e2[None])


def _offset_geometries(
    g: Geometry, qd: ConeQuadrature, qs: ConeQuadrature
) -> tuple[Geometry, NDArray[np.float64]]:
    """Stacked geometry of shape (M, N) for all (source, detector) node pairs and the weights
    (M, N) including cos-ratio factors and horizon clipping."""
    wi = np.stack([g.xi, g.yi, g.mu_i], axis=-1).reshape(-1, 3)
    wr = np.stack([g.xr, g.yr, g.mu_r], axis=-1).reshape(-1, 3)
    wi = wi / np.linalg.norm(wi, axis=-1, keepdims=True)
    wr = wr / np.linalg.norm(wr, axis=-1, keepdims=True)
    di = _offset_dirs(wi, qs)  # (Ms, N, 3)
    dr = _offset_dirs(wr, qd)  # (Md, N, 3)
    ms, md = di.shape[0], dr.shape[0]
    di_all = np.repeat(di, md, axis=0)
    dr_all = np.tile(dr, (ms, 1, 1))
    w = np.repeat(qs.weights, md)[:, None] * np.tile(qd.weights, ms)[:, None]
    ci = di_all[..., 2]
    cr = dr_all[..., 2]
    w = w * np.clip(ci, 0.0, None) / wi[None, :, 2] * np.clip(cr, 0.0, None) / wr[None, :, 2]
    return geometry_from_vectors(di_all, dr_all), w


def convolve_instrument(
    model: BRDFModel,
    *,
    aperture_half_angle: float,
    divergence_half_angle: float = 0.0,
    n_radial: int = 3,
    n_azimuth: int = 8,
    near_specular: float | None = None,
) -> BRDFModel:
    """The model as the instrument sees it (module docstring), as a new :class:`BRDFModel`.

    Parameters
    ----------
    model : BRDFModel
    aperture_half_angle : float
        Detector acceptance half-angle, radians.
    divergence_half_angle : float
        Beam divergence half-angle, radians (0: collimated).
    n_radial, n_azimuth : int
        Quadrature per cone (``n_radial × n_azimuth`` nodes).
    near_specular : float or None
        If given, the averaging is applied only where ωr lies within this angle (radians) of
        the mirror direction of ωi; elsewhere the model is evaluated directly (much cheaper,
        and exact to the extent the BRDF is smooth on the aperture's scale there).

    The Jacobian is the same average of the model's Jacobian (analytic if the model's is).
    """
    qd = cone_quadrature(aperture_half_angle, n_radial=n_radial, n_azimuth=n_azimuth)
    qs = cone_quadrature(divergence_half_angle, n_radial=n_radial, n_azimuth=n_azimuth)
    key = ("instrument", qd.half_angle, qs.half_angle, n_radial, n_azimuth, near_specular)

    def prepared(g: Geometry) -> tuple[NDArray[Any], Geometry, NDArray[Any]]:
        if key not in g.cache:
            if near_specular is None:
                mask = np.ones(g.shape, dtype=bool)
            else:
                mask = g.cos_alpha >= np.cos(near_specular)
            sub = g.take(mask)
            og, w = _offset_geometries(sub, qd, qs)
            g.cache[key] = (mask, og, w)
        return g.cache[key]

    def value(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        mask, og, w = prepared(g)
        out = model.value_fn(p, g) if near_specular is not None else np.empty(g.shape)
        out = np.array(out, dtype=float, copy=True)
        if og.shape[-1]:
            out[mask] = np.sum(model.value_fn(p, og) * w, axis=0)
        return out

    jac: Callable[[NDArray[Any], Geometry], NDArray[Any]] | None = None
    if model.jac_fn is not None:
        mjac = model.jac_fn

        def jac(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
            mask, og, w = prepared(g)
            out = np.array(mjac(p, g), dtype=float, copy=True)
            if og.shape[-1]:
                out[mask] = np.sum(mjac(p, og) * w[..., None], axis=0)
            return out

    # a plain BRDFModel (not a copy of a composite, whose parts would be unconvolved)
    return BRDFModel(
        name=f"{model.name}@instrument",
        params=model.params,
        value_fn=value,
        jac_fn=jac,
        energy_bounded=model.energy_bounded,
        reciprocal=model.reciprocal and divergence_half_angle == aperture_half_angle,
        unit=model.unit,
        validity=model.validity,
        reference=model.reference,
        description=f"{model.description} Averaged over a {aperture_half_angle:g} rad detector "
        f"aperture and {divergence_half_angle:g} rad beam divergence (half-angles).",
    )
