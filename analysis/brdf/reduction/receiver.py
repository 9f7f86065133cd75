"""The receiver factor: what a constant BRDF gives through the real beam footprint and aperture.

A reading integrates the BRDF over the illuminated footprint (growing as 1/cos θi) seen from
the receiver aperture; :func:`receiver_factor` is that integral for f = 1 and
:func:`receiver_model` wraps a model so a fit compares the data with what the receiver saw
(package docstring of :mod:`analysis.brdf.reduction`, item 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.geometry import Geometry, flat_angles, geometry_from_vectors, make_geometry
from analysis.brdf.model import BRDFModel

#: Radon's 7-point rule on the unit disk, exact for polynomials of degree ≤ 5 (Stroud 1971,
#: *Approximate Calculation of Multiple Integrals*, S2:5-1): the centre with weight 1/4 and
#: six points at radius √(2/3) with weight 1/8 (weights sum to 1: a mean over the disk).
_DISK_R = np.concatenate([[0.0], np.full(6, np.sqrt(2.0 / 3.0))])
_DISK_CHI = np.concatenate([[0.0], np.arange(6) * np.pi / 3.0])
_DISK_W = np.concatenate([[0.25], np.full(6, 0.125)])


@dataclass(frozen=True)
class ReceiverGeometry:
    """What one receiver reading integrates: a beam footprint seen through an aperture.

    A collimated Gaussian beam (1/e² radius w) lights a flat, under-filled sample; its
    irradiance on the sample plane is E(x) = 2Pᵢ cos θi /(πw²) · exp(−2(u² cos²θi + v²)/w²)
    (u along the plane of incidence, v across: the 1/cos θi footprint). A receiver whose
    aperture (diameter D) is centred at distance R from the sample centre along ωr and faces
    it collects P = ∫_spot ∫_aperture f(ωi, ω) E cos θ cos α / r² dA_ap dA, with ω, r the
    direction and distance from a spot point to an aperture point, θ its polar angle and α
    its angle to the aperture normal (ASTM E2387: the angular resolution is set by the
    aperture and the spot size seen from the receiver).

    Attributes
    ----------
    beam_radius_mm : float
        1/e² intensity radius w of the beam (mm).
    distance_mm : float
        R, sample centre to the aperture (camera pupil) centre (mm).
    aperture_diameter_mm : float
        D of the receiver aperture or camera entrance pupil (mm).
    solid_angle_sr : float
        The Ω the reduction divides by (:func:`solid_angle_sr` or
        :func:`camera_solid_angle_sr`).
    sample_aperture : bool
        True: the aperture is integrated (a power-meter aperture, a real lens pupil), with
        a degree-5 disk rule. False: radiance is taken along the ray through the aperture
        centre with étendue A cos α / r² (a pinhole camera model — the simulated camera,
        which traces chief rays).
    n_spot : int
        Gauss–Hermite nodes per footprint axis.
    """

    beam_radius_mm: float
    distance_mm: float
    aperture_diameter_mm: float
    solid_angle_sr: float
    sample_aperture: bool = True
    n_spot: int = 8

    def __post_init__(self) -> None:
        if not (self.beam_radius_mm > 0 and self.distance_mm > 0):
            raise ValueError("beam radius and distance must be > 0")
        if not (self.aperture_diameter_mm > 0 and self.solid_angle_sr > 0):
            raise ValueError("aperture diameter and solid angle must be > 0")
        if self.n_spot < 1:
            raise ValueError("n_spot must be >= 1")


def receiver_nodes(geometry: Geometry, receiver: ReceiverGeometry
                   ) -> tuple[Geometry, NDArray[np.float64]]:
    """Quadrature of a reading (:class:`ReceiverGeometry`) for every point of ``geometry``.

    The footprint is integrated by Gauss–Hermite in the beam's own coordinates (the
    Gaussian is its weight), the aperture by Radon's 7-point disk rule (or its centre).

    Returns
    -------
    nodes : Geometry, shape (M, N)
        Incident direction ωi (the beam is collimated) and the direction from each spot
        node to each aperture node; N = ``geometry`` flattened.
    weights : ndarray, shape (M, N)
        W with P / (Pᵢ Ω cos θr) = Σ_m W f(node m): E dA/Pᵢ · cos θ cos α A/r² / (Ω cos θr).
    """
    wi = np.stack([geometry.xi, geometry.yi, geometry.mu_i], axis=-1).reshape(-1, 3)
    wr = np.stack([geometry.xr, geometry.yr, geometry.mu_r], axis=-1).reshape(-1, 3)
    wi = wi / np.linalg.norm(wi, axis=-1, keepdims=True)
    wr = wr / np.linalg.norm(wr, axis=-1, keepdims=True)
    n = wi.shape[0]
    # footprint axes: u along the beam's projection on the sample, v across it
    proj = np.hypot(wi[:, 0], wi[:, 1])
    safe = proj > 1e-12
    eu = np.zeros((n, 3))
    eu[:, 0] = np.where(safe, wi[:, 0] / np.where(safe, proj, 1.0), 1.0)
    eu[:, 1] = np.where(safe, wi[:, 1] / np.where(safe, proj, 1.0), 0.0)
    ev = np.stack([-eu[:, 1], eu[:, 0], np.zeros(n)], axis=-1)
    x, w = np.polynomial.hermite.hermgauss(receiver.n_spot)
    s, t = (a.reshape(-1) for a in np.meshgrid(x, x, indexing="ij"))
    w_spot = np.outer(w, w).reshape(-1) / np.pi  # ∫ exp(−s²−t²)/π = 1
    half = receiver.beam_radius_mm / np.sqrt(2.0)
    u = s[:, None] * half / wi[None, :, 2]  # (Ms, N): exp(−2u²cos²θi/w²) = exp(−s²)
    v = np.broadcast_to(t[:, None] * half, u.shape)
    spot = u[..., None] * eu[None] + v[..., None] * ev[None]  # (Ms, N, 3), mm
    # aperture nodes on the plane ⟂ ωr through R ωr
    helper = np.where((np.abs(wr[:, 1]) < 0.9)[:, None], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    e1 = np.cross(wr, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(wr, e1)
    rho = 0.5 * receiver.aperture_diameter_mm
    area = np.pi * rho**2
    if receiver.sample_aperture:
        rk, ck, wk = _DISK_R * rho, _DISK_CHI, _DISK_W
    else:
        rk, ck, wk = np.zeros(1), np.zeros(1), np.ones(1)
    ap = (receiver.distance_mm * wr[None]
          + (rk * np.cos(ck))[:, None, None] * e1[None]
          + (rk * np.sin(ck))[:, None, None] * e2[None])  # (Ma, N, 3)
    d = ap[:, None] - spot[None]  # (Ma, Ms, N, 3): spot → aperture
    r2 = np.einsum("...k,...k->...", d, d)
    omega = d / np.sqrt(r2)[..., None]
    cos_t = np.clip(omega[..., 2], 0.0, None)
    cos_a = np.clip(np.einsum("...k,...k->...", omega, wr[None, None]), 0.0, None)
    weights = (wk[:, None, None] * w_spot[None, :, None] * area * cos_t * cos_a / r2
               / (receiver.solid_angle_sr * wr[None, None, :, 2]))
    m = weights.shape[0] * weights.shape[1]
    nodes = geometry_from_vectors(np.broadcast_to(wi, omega.shape).reshape(m, n, 3),
                                  omega.reshape(m, n, 3))
    return nodes, weights.reshape(m, n)


def receiver_factor(
    theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike, phi_r: ArrayLike,
    *, receiver: ReceiverGeometry,
) -> NDArray[np.float64]:
    """G = Σ W: the reading of a constant BRDF f = 1 in units of Pᵢ Ω cos θr, shape (n,).

    For a point receiver and a point spot G = 1; the finite footprint (1/r² and the
    obliquities across it), the aperture's projected solid angle (π sin²a against Ω) and
    the pinhole étendue make it differ by a few 10⁻⁴ on the sim bench, up to ~10⁻³ at
    grazing views. Dividing a reduced value by G turns it into a normalised average of f
    over what was integrated (:func:`receiver_model`).
    """
    g = make_geometry(*flat_angles(theta_i, phi_i, theta_r, phi_r))
    _, w = receiver_nodes(g, receiver)
    return w.sum(axis=0)


def receiver_model(model: BRDFModel, receiver: ReceiverGeometry) -> BRDFModel:
    """``model`` as the receiver sees it: f_meas = Σ W f(node) / Σ W (:func:`receiver_nodes`).

    Instrument-aware fitting: near a specular peak the reading is the average
    of f over the directions from the footprint to the aperture, not f at the nominal
    angles. The normalisation matches values reduced with :func:`receiver_factor` divided
    out. Same name, parameters and bounds as ``model``; the Jacobian is the same average of
    the model's Jacobian (analytic where the model's is).
    """
    key = ("receiver", receiver)

    def prepared(g: Geometry) -> tuple[Geometry, NDArray[np.float64]]:
        if key not in g.cache:
            nodes, w = receiver_nodes(g, receiver)
            g.cache[key] = (nodes, w / w.sum(axis=0))
        return g.cache[key]

    def value(p: NDArray[np.float64], g: Geometry) -> NDArray[np.float64]:
        nodes, w = prepared(g)
        return np.sum(model.value_fn(p, nodes) * w, axis=0).reshape(g.shape)

    jac = None
    if model.jac_fn is not None:
        mjac = model.jac_fn

        def jac(p: NDArray[np.float64], g: Geometry) -> NDArray[np.float64]:
            nodes, w = prepared(g)
            out = np.sum(mjac(p, nodes) * w[..., None], axis=0)
            return out.reshape((*g.shape, p.size))

    # a plain BRDFModel under the same name (a composite's parts would stay unaveraged)
    return BRDFModel(
        name=model.name, params=model.params, value_fn=value, jac_fn=jac,
        energy_bounded=model.energy_bounded, reciprocal=False, unit=model.unit,
        validity=model.validity, reference=model.reference,
        description=f"{model.description} Averaged over the beam footprint seen through a "
        f"{receiver.aperture_diameter_mm:g} mm receiver at {receiver.distance_mm:g} mm.")

