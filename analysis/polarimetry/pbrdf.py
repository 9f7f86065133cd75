"""Polarimetric BRDF model (microfacet Fresnel + depolarising diffuse) and its fit.

Model (Priest & Germer, "Polarimetric BRDF in the microfacet model: theory and
measurements", Proc. 2000 Meeting of the Military Sensing Symposia Specialty Group on
Passive Sensors 1, 169 (2002)): the Mueller-matrix BRDF (unit 1/sr) of a rough surface is

    F(ωi, ωr) = D(θh) · V(μi, μr) · R(−η_r) · F_facet(β) · R(η_i)  +  (ρ/π) · diag(1,0,0,0)

* ``D`` the facet-slope distribution (Beckmann with rms slope α, or GGX of width α;
  :mod:`analysis.brdf.microfacet`), ``V = G₂/(4μiμr)`` the height-correlated Smith
  visibility (Heitz 2014, eq. 99) in place of Priest & Germer's shadowing function;
  ``m00`` is then exactly the scalar microfacet BRDF with unpolarised Fresnel
  reflectance: with GGX it equals the registry model ``ggx_conductor+lambert``
  (:mod:`analysis.brdf.registry`, tested), so the scalar fits and model selection
  already cover ``m00``; this module fits the whole matrix.
* ``F_facet`` the Fresnel Mueller matrix of the facet at its local incidence angle β
  (``cos β = ωi·h``), in the facet's s/p frames (``e₁ = s``, perpendicular to the plane
  of ωi and ωr; ``e₂ = k × s``, k the propagation direction, for each beam):
  ``½[[Rs+Rp, Rs−Rp, 0, 0], [Rs−Rp, Rs+Rp, 0, 0], [0, 0, 2Re c, −2Im c],
  [0, 0, 2Im c, 2Re c]]`` with ``c = r_s r_p*``, from the Jones matrix diag(r_s, r_p)
  and ``V = 2 Im(E₁E₂*)`` for fields written with exp(−iωt) — the Stokes convention of
  :mod:`analysis.polarimetry.elements` (checked in the tests against the retarder matrix).
  ``r_s, r_p`` and the index convention ``n̂ = n + ik``, k ≥ 0, are those of
  :mod:`analysis.brdf.fresnel` (Born & Wolf).
* The global frames (the frames the polarimeter's azimuths refer to): for each beam,
  ``e₁`` lies in the plane containing the surface normal and the beam (for in-plane
  scans the scattering plane: +x of the beam frame is "p"), ``e₂ = −s_g`` with
  ``s_g = (−sin φ, cos φ, 0)``, so that ``e₁ × e₂ = k``. ``η`` is the angle from the
  global ``e₁`` to the facet's ``s`` about k (Priest & Germer's rotation of the facet
  Mueller matrix into the global frames). In this frame a smooth dielectric at Brewster's
  angle has ``m01 = −m00`` (only s light, which is −Q, is reflected).
* ``ρ`` the albedo of an ideal depolarising Lambertian layer.
* The polarimeter's frame. A calibrated polarimeter measures in its own frame, whose
  azimuth origin is the generator polariser's axis (ADR 0102): reference samples fix
  every angle relative to it, never to the sample. If that axis stands at ``φ_f`` from
  the plane of incidence, the measured matrix is ``R(φ_f) F R(−φ_f)``
  (:func:`analysis.polarimetry.elements.rotated` by ``−φ_f``). The fit estimates
  ``φ_f`` with the sample (a parameter in degrees, ``frame_deg``): a 0.3° frame turns
  m01 into m02 by sin 0.6° ≈ 1 %, several σ of a 36-step reduction (ADR 0107).

Parameters of the fit, in this order: ``n``, ``k`` (the complex index), ``alpha``
(roughness), ``albedo``, ``frame_deg``; any of them can be held fixed. Functions that
take a parameter vector also take the first four alone (the frame at 0). The fit minimises
``χ² = Σ_g rᵀ C_g⁻¹ r`` over the geometries g (r the 16 residuals of the Mueller matrix,
``C_g`` its 16×16 covariance from :func:`analysis.polarimetry.drr.reduce`), by whitening
with ``C_g^(−½)`` (pseudo-inverse: a normalised matrix's ``m00`` has zero variance), and
judges it with the project's goodness-of-fit gate
(:func:`analysis.brdf.goodness.goodness_of_fit`, ADR 0051).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize

from analysis.brdf.fresnel import fresnel
from analysis.brdf.goodness import GoodnessOfFit, goodness_of_fit
from analysis.brdf.microfacet import beckmann_d, ggx_d, smith_visibility
from analysis.brdf.reduction.receiver import LEVELS, ReceiverGeometry
from analysis.polarimetry.elements import rotation
from analysis.polarimetry.receiver_nodes import MuellerNodes, mueller_nodes
from analysis.polarimetry.validation import PolarimetryInputError, check_array

__all__ = ["PBRDF_BOUNDS", "PBRDF_PARAMS", "QUADRATURE_TOLERANCE", "PbrdfFit", "fit_pbrdf",
           "fresnel_mueller", "pbrdf", "pbrdf_on_receiver"]

#: Parameter names, in the order of the parameter vector.
PBRDF_PARAMS = ("n", "k", "alpha", "albedo", "frame_deg")
_LOWER = np.array([1.0 + 1e-6, 0.0, 1e-3, 0.0, -45.0])
_UPPER = np.array([10.0, 20.0, 1.5, 1.0, 45.0])
_DISTRIBUTIONS = ("beckmann", "ggx")
#: Each parameter's closed interval (lower, upper) of the fit: a start value outside it
#: is refused (callers that take start values from users check them against it).
PBRDF_BOUNDS: dict[str, tuple[float, float]] = {
    name: (float(lo), float(hi)) for name, lo, hi in zip(PBRDF_PARAMS, _LOWER, _UPPER,
                                                         strict=True)}


def fresnel_mueller(cos_beta: ArrayLike, n: complex) -> NDArray[np.float64]:
    """Fresnel Mueller matrices (shape (..., 4, 4)) in the facet's s/p frames (module doc)."""
    res = fresnel(cos_beta, n)
    c = res.rs * np.conj(res.rp)
    out = np.zeros((*np.shape(res.Rs), 4, 4))
    out[..., 0, 0] = out[..., 1, 1] = 0.5 * (res.Rs + res.Rp)
    out[..., 0, 1] = out[..., 1, 0] = 0.5 * (res.Rs - res.Rp)
    out[..., 2, 2] = out[..., 3, 3] = c.real
    out[..., 2, 3] = -c.imag
    out[..., 3, 2] = c.imag
    return out


def _rot(eta: NDArray[np.float64]) -> NDArray[np.float64]:
    c, s = np.cos(2 * eta), np.sin(2 * eta)
    out = np.zeros((*eta.shape, 4, 4))
    out[..., 0, 0] = out[..., 3, 3] = 1.0
    out[..., 1, 1] = out[..., 2, 2] = c
    out[..., 1, 2] = s
    out[..., 2, 1] = -s
    return out


def _frames(k: NDArray[np.float64], s_g: NDArray[np.float64]
            ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Global (e₁, e₂) of beams with propagation k and s axis ``s_g`` ⟂ k (module doc)."""
    return np.cross(k, s_g), -s_g


@dataclass(frozen=True)
class _Geometry:
    cos_theta_h: NDArray[np.float64]
    cos_beta: NDArray[np.float64]
    mu_i: NDArray[np.float64]
    mu_r: NDArray[np.float64]
    rot_in: NDArray[np.float64]   # R(η_i), shape (N, 4, 4)
    rot_out: NDArray[np.float64]  # R(−η_r)


def _s_axis(phi: NDArray[np.float64]) -> NDArray[np.float64]:
    """The global s axis ``s_g = (−sin φ, cos φ, 0)`` of beams at azimuth φ."""
    return np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi)], axis=-1)


def _geometry(theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike,
              phi_r: ArrayLike) -> _Geometry:
    arrs = [check_array(name, v) for name, v in (("theta_i", theta_i), ("phi_i", phi_i),
                                                  ("theta_r", theta_r), ("phi_r", phi_r))]
    ti, pi_, tr, pr = (a.ravel() for a in np.broadcast_arrays(*arrs))
    for name, t in (("theta_i", ti), ("theta_r", tr)):
        if np.any((t < 0) | (t > math.pi / 2)):
            raise PolarimetryInputError(name, "must lie in [0, π/2] rad (from the normal)")
    wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)], axis=-1)
    wr = np.stack([np.sin(tr) * np.cos(pr), np.sin(tr) * np.sin(pr), np.cos(tr)], axis=-1)
    return _vector_geometry(wi, wr, _s_axis(pi_), _s_axis(pr))


def _vector_geometry(wi: NDArray[np.float64], wr: NDArray[np.float64],
                     s_in: NDArray[np.float64], s_out: NDArray[np.float64]) -> _Geometry:
    """The geometry of unit vectors ωi, ωr (N, 3) whose beams' frames take the s axes
    ``s_in``, ``s_out`` (N, 3; unit, ⟂ each beam): each beam's own global s axis at the
    nominal angles, the receiver's at the nodes of a finite receiver
    (:mod:`analysis.polarimetry.receiver_nodes`)."""
    v = wi + wr
    vn = np.linalg.norm(v, axis=-1)
    h = np.where(vn[:, None] > 0, v / np.where(vn > 0, vn, 1.0)[:, None], [0.0, 0.0, 1.0])
    cross = np.cross(wi, wr)
    cn = np.linalg.norm(cross, axis=-1)
    k_in, k_out = -wi, wr
    e1_in, e2_in = _frames(k_in, s_in)
    e1_out, e2_out = _frames(k_out, s_out)
    # facet s: ⊥ to the plane of ωi and ωr; when they are parallel (retro-reflection)
    # every s is equivalent and the global s of the incident beam is used
    s_loc = np.where(cn[:, None] > 1e-12, cross / np.where(cn > 1e-12, cn, 1.0)[:, None],
                     -e2_in)
    eta_i = np.arctan2(np.sum(s_loc * e2_in, -1), np.sum(s_loc * e1_in, -1))
    eta_r = np.arctan2(np.sum(s_loc * e2_out, -1), np.sum(s_loc * e1_out, -1))
    return _Geometry(cos_theta_h=h[:, 2], cos_beta=np.clip(np.sum(wi * h, -1), 0.0, 1.0),
                     mu_i=wi[:, 2], mu_r=wr[:, 2], rot_in=_rot(eta_i),
                     rot_out=_rot(-eta_r))


def _evaluate(p: NDArray[np.float64], g: _Geometry, distribution: str) -> NDArray[np.float64]:
    n, k, alpha, albedo, frame_deg = (float(v) for v in p)
    d = (beckmann_d(g.cos_theta_h, alpha) if distribution == "beckmann"
         else ggx_d(g.cos_theta_h, alpha))
    vis = smith_visibility(g.mu_i, g.mu_r, alpha, distribution=distribution)
    f = fresnel_mueller(g.cos_beta, complex(n, k))
    spec = (d * vis)[:, None, None] * (g.rot_out @ f @ g.rot_in)
    spec[:, 0, 0] += albedo / math.pi
    if frame_deg != 0.0:  # the polarimeter's frame (module docstring)
        phi = math.radians(frame_deg)
        spec = rotation(phi) @ spec @ rotation(-phi)
    return spec


def _check_params(params: ArrayLike, distribution: str) -> NDArray[np.float64]:
    p = check_array("params", params)
    if p.shape == (4,):
        p = np.append(p, 0.0)
    if p.shape != (5,):
        raise PolarimetryInputError("params", f"must hold 4 or 5 values {PBRDF_PARAMS}, "
                                    f"got shape {p.shape}")
    if distribution not in _DISTRIBUTIONS:
        raise PolarimetryInputError("distribution", f"must be one of {_DISTRIBUTIONS}, "
                                    f"got {distribution!r}")
    for i, name in enumerate(PBRDF_PARAMS):
        if not _LOWER[i] <= p[i] <= _UPPER[i]:
            raise PolarimetryInputError(
                "params", f"{name} = {p[i]} outside [{_LOWER[i]}, {_UPPER[i]}]")
    return p


def pbrdf(params: ArrayLike, theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike,
          phi_r: ArrayLike, *, distribution: str = "beckmann") -> NDArray[np.float64]:
    """The Mueller-matrix BRDF (1/sr) at the given geometries (module docstring).

    Parameters
    ----------
    params : array_like of shape (5,) or (4,)
        ``(n, k, alpha, albedo, frame_deg)``: index n + ik (k ≥ 0), roughness (Beckmann
        rms slope or GGX width), Lambertian albedo of the depolarising layer, azimuth of
        the polarimeter's frame from the plane of incidence in degrees (0 if left out).
    theta_i, phi_i, theta_r, phi_r : array_like, broadcast together to N geometries
        Polar angles from the normal and azimuths, radians (conventions of
        :mod:`analysis.brdf.geometry`; the specular direction is φr = φi + π).

    Returns
    -------
    ndarray of shape (N, 4, 4)
    """
    p = _check_params(params, distribution)
    return _evaluate(p, _geometry(theta_i, phi_i, theta_r, phi_r), distribution)


def _node_geometry(nodes: MuellerNodes) -> _Geometry:
    return _vector_geometry(nodes.wi, nodes.wr, nodes.s_in, nodes.s_out)


def pbrdf_on_receiver(params: ArrayLike, theta_i: ArrayLike, phi_i: ArrayLike,
                      theta_r: ArrayLike, phi_r: ArrayLike, receiver: ReceiverGeometry, *,
                      level: int = 1, distribution: str = "beckmann",
                      normalise: bool = False) -> NDArray[np.float64]:
    """The Mueller-matrix BRDF (N, 4, 4) as a finite receiver reads it at the nominal
    geometries: :func:`pbrdf` integrated over the beam's footprint and the receiver's
    aperture in the receiver's frames (:mod:`analysis.polarimetry.receiver_nodes`), in
    units of P Ω cos θr as the reduction divides (``normalise``: the plain average).
    ``level`` indexes :data:`analysis.brdf.reduction.receiver.LEVELS`."""
    p = _check_params(params, distribution)
    nodes = _receiver_nodes(theta_i, phi_i, theta_r, phi_r, receiver, level, normalise)
    return nodes.average(_evaluate(p, _node_geometry(nodes), distribution))


def _receiver_nodes(theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike,
                    phi_r: ArrayLike, receiver: ReceiverGeometry, level: int,
                    normalise: bool = False) -> MuellerNodes:
    _geometry(theta_i, phi_i, theta_r, phi_r)  # the angles' checks, with their errors
    if not 0 <= level < len(LEVELS):
        raise PolarimetryInputError("level", f"must lie in 0..{len(LEVELS) - 1}, got {level}")
    return mueller_nodes(theta_i, phi_i, theta_r, phi_r, receiver, level=level,
                         normalise=normalise)


@dataclass(frozen=True)
class PbrdfFit:
    """The result of :func:`fit_pbrdf`.

    Attributes
    ----------
    params : ndarray of shape (5,)
        ``(n, k, alpha, albedo, frame_deg)`` at the minimum (fixed ones at their given
        values).
    sigma : ndarray of shape (5,)
        Standard errors (0 for fixed parameters).
    cov : ndarray of shape (5, 5)
        Covariance of the parameters (zero rows/columns for fixed ones).
    goodness : GoodnessOfFit
        χ², degrees of freedom, p-value and verdict (the project's gate).
    receiver_level : int or None
        The quadrature level of the finite-receiver model (None: point receiver).
    quadrature_error : float
        The largest change of a whitened residual (units of σ) from that level to the
        next at the fitted parameters: the a-posteriori bound of the quadrature's error
        (0 for a point receiver; :data:`QUADRATURE_TOLERANCE`).
    """

    params: NDArray[np.float64]
    sigma: NDArray[np.float64]
    cov: NDArray[np.float64]
    goodness: GoodnessOfFit
    receiver_level: int | None = None
    quadrature_error: float = 0.0


#: The finite-receiver fit refines its quadrature level until the next level moves no
#: whitened residual by more than this (in σ): the quadrature's error then changes χ²
#: by at most 2·0.1·|r| + 0.01 per residual, far inside the gate's √(2ν).
QUADRATURE_TOLERANCE = 0.1
#: The level a finite-receiver fit starts at (:data:`analysis.brdf.reduction.receiver.LEVELS`).
START_LEVEL = 1


def _whiteners(cov: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """Per geometry, C^(−½) on the covariance's range (pseudo-inverse square root)."""
    out = []
    for c in cov:
        vals, vecs = np.linalg.eigh(0.5 * (c + c.T))
        keep = vals > 1e-12 * max(float(vals[-1]), 1e-300)
        out.append((vecs[:, keep] / np.sqrt(vals[keep])).T)
    return out


def fit_pbrdf(m: ArrayLike, cov: ArrayLike, theta_i: ArrayLike, phi_i: ArrayLike,
              theta_r: ArrayLike, phi_r: ArrayLike, *, start: ArrayLike,
              fixed: Sequence[str] = (), distribution: str = "beckmann",
              receiver: ReceiverGeometry | None = None) -> PbrdfFit:
    """Fit the pBRDF to measured Mueller matrices with their full covariances.

    Parameters
    ----------
    m : array_like of shape (N, 4, 4)
        Measured Mueller-matrix BRDF, 1/sr.
    cov : array_like of shape (N, 16, 16)
        Covariance of each row-major ``vec(m[g])``.
    theta_i, phi_i, theta_r, phi_r : array_like of shape (N,)
        The geometries, radians.
    start : array_like of shape (5,) or (4,)
        Start values ``(n, k, alpha, albedo, frame_deg)`` (and the values of fixed
        parameters); four values start the frame at 0.
    fixed : sequence of str
        Names from :data:`PBRDF_PARAMS` held at their start value (e.g. ``("k",)`` for a
        dielectric).
    receiver : ReceiverGeometry or None
        The beam and receiver the readings integrated over: the model is
        :func:`pbrdf_on_receiver`, its quadrature level raised from :data:`START_LEVEL`
        until the next level moves no whitened residual by more than
        :data:`QUADRATURE_TOLERANCE` (the fit is repeated from its minimum at each new
        level; the top level's bound is the change from the level below). None: a point
        receiver at the nominal angles.

    Raises
    ------
    PolarimetryInputError
        Mis-shaped or non-finite input, unknown names in ``fixed``, start outside bounds.
    """
    mm = check_array("m", m)
    if mm.ndim != 3 or mm.shape[1:] != (4, 4):
        raise PolarimetryInputError("m", f"must have shape (N, 4, 4), got {mm.shape}")
    n_geo = mm.shape[0]
    cc = check_array("cov", cov, shape=(n_geo, 16, 16))
    p0 = _check_params(start, distribution)
    unknown = [f for f in fixed if f not in PBRDF_PARAMS]
    if unknown:
        raise PolarimetryInputError("fixed", f"names unknown parameters {unknown}; "
                                    f"use {PBRDF_PARAMS}")
    geo = _geometry(theta_i, phi_i, theta_r, phi_r)
    if geo.mu_i.size != n_geo:
        raise PolarimetryInputError("theta_i", f"must give {n_geo} geometries, "
                                    f"got {geo.mu_i.size}")
    free = np.array([name not in fixed for name in PBRDF_PARAMS])
    whit = _whiteners(cc)

    def full(x: NDArray[np.float64]) -> NDArray[np.float64]:
        p = p0.copy()
        p[free] = x
        return p

    def model_at(level: int | None) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
        if level is None:
            return lambda p: _evaluate(p, geo, distribution)
        assert receiver is not None
        nodes = _receiver_nodes(theta_i, phi_i, theta_r, phi_r, receiver, level)
        node_geo = _node_geometry(nodes)
        return lambda p: nodes.average(_evaluate(p, node_geo, distribution))

    def whitened(values: NDArray[np.float64]) -> NDArray[np.float64]:
        flat = values.reshape(n_geo, 16)
        return np.concatenate([wg @ flat[g] for g, wg in enumerate(whit)])

    level = None if receiver is None else START_LEVEL
    x0 = np.clip(p0[free], _LOWER[free] + 1e-9, _UPPER[free] - 1e-9)
    quadrature_error = 0.0
    while True:
        model = model_at(level)

        def residuals(x: NDArray[np.float64]) -> NDArray[np.float64]:
            return whitened(model(full(x)) - mm)  # noqa: B023 (used within this pass)

        res = optimize.least_squares(residuals, x0, bounds=(_LOWER[free], _UPPER[free]),
                                     method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12,
                                     gtol=1e-12)
        if level is None:
            break
        if level + 1 < len(LEVELS):
            finer = model_at(level + 1)(full(res.x))
            quadrature_error = float(np.max(np.abs(whitened(finer - model(full(res.x))))))
            if quadrature_error > QUADRATURE_TOLERANCE:
                level, x0 = level + 1, res.x
                continue
        break
    cov_free = np.linalg.pinv(res.jac.T @ res.jac)
    cov_full = np.zeros((5, 5))
    cov_full[np.ix_(free, free)] = cov_free
    gof = goodness_of_fit(res.fun, int(free.sum()))
    return PbrdfFit(params=full(res.x), sigma=np.sqrt(np.clip(np.diag(cov_full), 0, None)),
                    cov=cov_full, goodness=gof, receiver_level=level,
                    quadrature_error=quadrature_error)
