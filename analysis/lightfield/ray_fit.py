"""Joint least squares of point responses on a relay wall's rays: the model behind the
localiser's refit of its candidates (:mod:`.localize`) and the test of one extended object
against two points (:mod:`.extended`). Conventions as in :mod:`.localize`: y along the
wall, z < 0 in front of it (unfolded), mm; θ the ray angle on the wall, rad.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .field import LightField2D

__all__ = ["JointFit", "fit_points", "ray_model"]


@dataclass(frozen=True)
class JointFit:
    """Least-squares fit of a sum of point responses to the wall's rays (see
    :func:`fit_points`): positions (K, 2) as (y, z) in mm, amplitudes (K,) in radiance
    units, the residual sum of squares and the number of rays fitted."""

    positions: NDArray[Any]
    amplitudes: NDArray[Any]
    rss: float
    n_rays: int


def ray_model(
    lf_wall: LightField2D, use: NDArray[np.bool_], phi: NDArray[Any], pos: NDArray[Any]
) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    """``g = L cos θ`` of unit point responses on the rays in the solvable domain, and its
    derivatives in y and z.

    Row c sees a point at (y, z) at ``θ* = atan(u)``, ``u = (c − y)/(−z)``; its filtered
    delta ``K(θ − θ*)`` (:func:`point_response` without the obliquity) is a Fourier
    series in θ*, so ``∂K/∂θ*`` is the same series times ``−i p ω``; the chain rule adds
    ``∂θ*/∂y = (1/z)/(1 + u²)`` and ``∂θ*/∂z = ((c − y)/z²)/(1 + u²)``.

    Returns three (K, R, n_use) arrays: responses, ∂/∂y, ∂/∂z.

    Only the orders the filter passes (φ_p ≠ 0) are evaluated: elsewhere the coefficient is
    φ_p e^{…} = 0 whatever the phase, so the values are the same as evaluating every order
    (up to the sign of an exact zero), at a fraction of the cost when p̂ ≪ N/2 (at
    N = 1024 the phase factors of all N orders were most of the model's time;
    ``benchmarks/bench_ray_model.py``).
    """
    from .spectral import _phase, fourier_orders

    th = lf_wall.theta_rad
    n = th.size
    a, b = lf_wall.domain_rad
    omega = 2 * np.pi / (b - a)
    p = fourier_orders(n)
    c = np.asarray(lf_wall.y_mm, dtype=float)
    yk, zk = pos[:, 0][:, None], pos[:, 1][:, None]
    u = (c[None, :] - yk) / (-zk)
    t_star = np.arctan(u)
    phi_ = np.broadcast_to(np.asarray(phi, dtype=float), p.shape)
    nz = np.flatnonzero(phi_)
    # the passed orders only where they are few; otherwise scattering them back costs more
    # than the phase factors it saves (N = 128, p̂ = 45)
    sel = nz if 2 * nz.size <= n else slice(None)
    # the two coefficient sets of .spectral.synthesize (value, then ∂/∂θ*), each with
    # exactly the operations (and their order) of the full form
    coef = phi_[sel] * np.exp(-1j * p[sel] * omega * (t_star[..., None] - 0.5 * (a + b)))
    ph = np.conj(_phase(n))[sel]

    def synth(v: NDArray[Any]) -> NDArray[Any]:
        if isinstance(sel, slice):
            return np.fft.ifft(v, axis=-1) * n
        full = np.zeros((*v.shape[:-1], n), dtype=complex)
        full[..., sel] = v
        return np.fft.ifft(full, axis=-1) * n

    resp = synth(coef * ph).real[..., use] / (b - a)
    d_t = synth((coef * (-1j * p[sel] * omega)) * ph).real[..., use] / (b - a)
    w = 1.0 / (1.0 + u**2)
    return resp, d_t * (w / zk)[..., None], d_t * (w * (c[None, :] - yk) / zk**2)[..., None]


def fit_points(
    g: NDArray[Any], lf_wall: LightField2D, use: NDArray[np.bool_], phi: NDArray[Any],
    pos: NDArray[Any],
    bounds: tuple[tuple[float, float], tuple[float, float]],
) -> JointFit:
    """Joint least squares of K point responses with free (y, z) and amplitude.

    Minimises ``Σ_{c, θ ∈ [A, B]} (g(c, θ) − Σ_k a_k K(θ − θ*_k(c)))²`` over the rays of
    the solvable domain — the model whose one-source statistic is the matched filter
    (module doc) — by trust-region least squares (scipy ``least_squares``, analytic
    Jacobian from :func:`ray_model`), started from ``pos`` (K, 2) with the linear
    least-squares amplitudes there.  ``g`` (R, n_use) is the data on those rays;
    ``bounds`` the (y, z) box of the searched grid.
    """
    from scipy.optimize import least_squares

    k = pos.shape[0]
    flat = g.ravel()
    (ylo, yhi), (zlo, zhi) = bounds
    start = np.column_stack([np.clip(pos[:, 0], ylo, yhi), np.clip(pos[:, 1], zlo, zhi)])
    r0, _, _ = ray_model(lf_wall, use, phi, start)
    amp0 = np.linalg.lstsq(r0.reshape(k, -1).T, flat, rcond=None)[0]

    def unpack(x: NDArray[Any]) -> tuple[NDArray[Any], NDArray[Any]]:
        return x[:k], x[k:].reshape(k, 2)

    def resid(x: NDArray[Any]) -> NDArray[Any]:
        amp, p_ = unpack(x)
        r, _, _ = ray_model(lf_wall, use, phi, p_)
        return np.tensordot(amp, r, axes=1).ravel() - flat

    def jac(x: NDArray[Any]) -> NDArray[Any]:
        amp, p_ = unpack(x)
        r, dy, dz = ray_model(lf_wall, use, phi, p_)
        cols = np.empty((flat.size, 3 * k))
        cols[:, :k] = r.reshape(k, -1).T
        cols[:, k::2] = (amp[:, None, None] * dy).reshape(k, -1).T
        cols[:, k + 1::2] = (amp[:, None, None] * dz).reshape(k, -1).T
        return cols

    lo = np.concatenate([np.full(k, -np.inf), np.tile([ylo, zlo], k)])
    hi = np.concatenate([np.full(k, np.inf), np.tile([yhi, zhi], k)])
    x0 = np.concatenate([amp0, start.ravel()])
    # inverse-depth scale: z moves ≈ (D/δy)× further than y for the same misfit
    scale = np.concatenate([np.maximum(np.abs(amp0), 1e-12), np.tile([1.0, 10.0], k)])
    # the trust-region steps solved exactly (SVD of the small Jacobian) and the fit run to
    # tight tolerances: with lsmr's iterative steps stopped at ftol 1e-6 the stopping point
    # followed the rounding, and the brushed metal's pair came out one extended object with
    # one BLAS thread and a phantom beside it with two (ADR 0109)
    sol = least_squares(resid, x0, jac=jac, bounds=(lo, hi), x_scale=scale, max_nfev=40,
                        ftol=1e-10, xtol=1e-10, tr_solver="exact")
    amp, p_ = unpack(sol.x)
    return JointFit(p_.copy(), amp.copy(), float(np.sum(sol.fun**2)), flat.size)
