"""Angular (positioning) uncertainty of reduced BRDF values from the local slope of the data."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.geometry import flat_angles


def _cluster(x: NDArray[Any], tol: float) -> NDArray[np.int64]:
    """Integer labels grouping values whose sorted neighbours lie within ``tol`` (one label
    per set angle despite read-back jitter)."""
    order = np.argsort(x, kind="stable")
    lab = np.concatenate([[0], np.cumsum(np.diff(x[order]) > tol)])
    out = np.empty(x.size, dtype=np.int64)
    out[order] = lab
    return out


def _combine(*labels: NDArray[Any]) -> NDArray[np.int64]:
    """One label per distinct tuple of labels."""
    _, inv = np.unique(np.stack(labels, axis=1), axis=0, return_inverse=True)
    return inv.reshape(-1).astype(np.int64)


def angular_uncertainty(
    brdf: ArrayLike,
    theta_i: ArrayLike,
    theta_r: ArrayLike,
    *,
    sigma_theta_i: float = 0.0,
    sigma_theta_r: float = 0.0,
    phi_i: ArrayLike | None = None,
    phi_r: ArrayLike | None = None,
    tol_rad: float = 1e-3,
    max_step_i_rad: float = np.radians(5.0),
) -> NDArray[np.float64]:
    """|∂f/∂θr| σθr ⊕ |∂f/∂θi| σθi from the local slope of the measured values.

    Slopes are second-order finite differences (:func:`numpy.gradient` on the non-uniform
    grid) along θr at fixed incidence and fixed relative azimuth φr − φi — in the plane of
    incidence along the signed θr, across the normal — and along θi at a fixed receiver
    direction; a group with a single point has slope 0. Angles closer than ``tol_rad``
    (default 10⁻³ rad ≈ 0.06°, above stage read-back jitter, below any scan step) count as
    the same set angle: their readings are averaged before differencing, never differenced
    over the jitter. Without ``phi_i``/``phi_r`` all points are taken as in-plane on one
    side. The slope of noisy data overestimates the true slope slightly, which errs on the
    safe side (angular errors matter through steep BRDF slopes: Basic et al., Applied Optics 62(13),
    2023).

    Along θi a difference is taken only between set angles at most ``max_step_i_rad``
    apart (default 5°): incidence grids are coarse (20–30° steps), and a difference across
    them is not the local slope (a glossy lobe moves with θi by more than its width). A
    point without a near neighbour in θi gets no θi term here; the instrument-aware fit
    takes the θi slope from the model (effective variance,
    :func:`analysis.brdf.reduction.fit_forward`).

    Returns
    -------
    ndarray, shape (n,)
    """
    f = np.asarray(brdf, dtype=float).reshape(-1)
    ti = np.asarray(theta_i, dtype=float).reshape(-1)
    tr = np.asarray(theta_r, dtype=float).reshape(-1)
    if sigma_theta_i == 0.0 and sigma_theta_r == 0.0:
        return np.zeros_like(f)
    if phi_i is not None and phi_r is not None:
        pi_, pr = flat_angles(phi_i, phi_r)
        dphi = np.broadcast_to(np.angle(np.exp(1j * (pr - pi_))), f.shape)
        # in the plane of incidence when the receiver is within tol of it
        plane = np.abs(np.sin(tr) * np.sin(dphi)) <= tol_rad
        signed = np.where(np.abs(dphi) > np.pi / 2, tr, -tr)
        azimuth = np.where(plane, -1, _cluster(dphi, tol_rad))
        coord_r = np.where(plane, signed, tr)
    else:
        azimuth = np.zeros(f.shape, dtype=np.int64)
        coord_r = tr

    def slopes(groups: NDArray[Any], coord: NDArray[Any], max_step: float = np.inf) -> NDArray[Any]:
        out = np.zeros_like(f)
        for k in np.unique(groups):
            sel = np.flatnonzero(groups == k)
            if sel.size < 2:
                continue
            order = sel[np.argsort(coord[sel], kind="stable")]
            x = coord[order]
            inv = _cluster(x, tol_rad)  # repeats of one set angle
            if inv.max() < 1:
                continue
            cnt = np.bincount(inv)
            ym = np.bincount(inv, weights=f[order]) / cnt
            xm = np.bincount(inv, weights=x) / cnt
            grad = np.gradient(ym, xm, edge_order=1)
            if np.isfinite(max_step):
                gap = np.diff(xm)
                near = np.zeros(xm.size, dtype=bool)
                near[:-1] |= gap <= max_step
                near[1:] |= gap <= max_step
                grad = np.where(near, grad, 0.0)
            out[order] = grad[inv]
        return out

    ti_lab = _cluster(ti, tol_rad)
    d_r = (slopes(_combine(ti_lab, azimuth), coord_r) if sigma_theta_r
           else np.zeros_like(f))
    d_i = (slopes(_combine(_cluster(coord_r, tol_rad), azimuth), ti, max_step_i_rad)
           if sigma_theta_i
           else np.zeros_like(f))
    return np.hypot(d_r * sigma_theta_r, d_i * sigma_theta_i)

