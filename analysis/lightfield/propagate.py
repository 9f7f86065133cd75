"""Free-space propagation (shear), sampling along shear curves, and projection.

Propagation by a distance d along +z is the ABCD shear that preserves radiance
(Durand et al., SIGGRAPH 2005; Sasaki 2020, ch. 1):
``P_d[L](y, θ) = L(y − d tan θ, θ)``.  Three evaluations are offered:

* ``"fourier"`` — an exact sub-sample shift of each angle column by the Fourier shift
  theorem (exact for a band-limited field; the column is zero-padded to twice its length so
  nothing wraps around),
* ``"linear"`` and ``"cubic"`` — interpolation along y (cubic B-spline interpolation via
  :func:`scipy.ndimage.map_coordinates`), zero outside the sampled y range.

Projection ``S[L](y) = ∫_a^b L(y, θ) dθ`` is the midpoint rule on the cell-centred grid.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from .field import LightField2D, LightField4D

__all__ = [
    "Interpolation",
    "project",
    "project_4d",
    "propagate",
    "propagate_4d",
    "sample_along_curves",
    "sample_columns",
]

Interpolation = Literal["linear", "cubic", "fourier"]


def sample_columns(
    values: NDArray[Any],
    y0_mm: float,
    dy_mm: float,
    y_query_mm: NDArray[np.float64],
    *,
    method: Literal["linear", "cubic"] = "linear",
) -> NDArray[Any]:
    """Interpolate each column ``values[:, j]`` at the positions ``y_query_mm[:, j]``.

    Parameters
    ----------
    values : ndarray of shape (N_y, N_θ)
        Samples on the uniform grid ``y0 + i·dy``.
    y_query_mm : ndarray of shape (N_q, N_θ)
        Query positions per column (mm).
    method : "linear" or "cubic"

    Returns
    -------
    ndarray of shape (N_q, N_θ)
        Interpolated values, 0 where the query lies outside ``[y0, y0 + (N_y−1)dy]``.
    """
    v = np.asarray(values)
    q = np.asarray(y_query_mm, dtype=float)
    n_y, n_t = v.shape
    if q.ndim != 2 or q.shape[1] != n_t:
        raise ValueError("y_query_mm must have shape (N_q, N_θ)")
    idx = (q - y0_mm) / dy_mm
    inside = (idx >= -1e-9) & (idx <= n_y - 1 + 1e-9)
    if np.iscomplexobj(v):
        re = sample_columns(v.real, y0_mm, dy_mm, q, method=method)
        im = sample_columns(v.imag, y0_mm, dy_mm, q, method=method)
        return re + 1j * im
    if method == "linear":
        i0 = np.clip(np.floor(idx).astype(np.int64), 0, n_y - 2)
        w = np.clip(idx - i0, 0.0, 1.0)
        cols = np.broadcast_to(np.arange(n_t), q.shape)
        out = (1.0 - w) * v[i0, cols] + w * v[i0 + 1, cols]
    elif method == "cubic":
        cols = np.broadcast_to(np.arange(n_t, dtype=float), q.shape)
        out = ndimage.map_coordinates(
            v.astype(float), [idx, cols], order=3, mode="nearest", prefilter=True
        )
    else:
        raise ValueError(f"unknown interpolation {method!r}")
    return np.where(inside, out, 0.0)


def _fourier_shift_columns(values: NDArray[Any],
                           shift_samples: NDArray[np.float64]) -> NDArray[Any]:
    """out[i, j] = values(i − shift_j) for a band-limited column, zero-padded ×2."""
    n_y = values.shape[0]
    n_pad = 2 * n_y
    spec = np.fft.fft(values, n=n_pad, axis=0)
    k = np.fft.fftfreq(n_pad)[:, None]
    out = np.fft.ifft(spec * np.exp(-2j * np.pi * k * shift_samples[None, :]), axis=0)[:n_y]
    return out if np.iscomplexobj(values) else out.real


def propagate(
    lf: LightField2D, distance_mm: float, *, method: Interpolation = "cubic"
) -> LightField2D:
    """Propagate by ``distance_mm`` along +z: ``L'(y, θ) = L(y − d tan θ, θ)``
    (a shear; Durand et al. 2005).

    The result lives on the same (y, θ) grids at ``z_mm + d``; radiance that would come from
    outside the sampled y range is 0 (or wraps into the zero padding for ``"fourier"``).
    """
    d = float(distance_mm)
    t = np.tan(lf.theta_rad)
    if method == "fourier":
        out = _fourier_shift_columns(lf.radiance, d * t / lf.dy_mm)
    else:
        q = lf.y_mm[:, None] - d * t[None, :]
        out = sample_columns(lf.radiance, lf.y_mm[0], lf.dy_mm, q, method=method)
    return lf.with_radiance(out, z_mm=lf.z_mm + d)


def sample_along_curves(
    lf: LightField2D,
    points_mm: ArrayLike,
    distance_mm: ArrayLike,
    *,
    method: Literal["linear", "cubic"] = "cubic",
) -> tuple[NDArray[Any], NDArray[np.bool_]]:
    """Sample ``L(c_r + d_r tan θ_j, θ_j)`` for every point c_r (the curve of eq. 2-6).

    Parameters
    ----------
    points_mm : array of shape (R,)
        The points c_r (mm) on the plane the curves converge to.
    distance_mm : float or array of shape (R,)
        Axial distance d_r from that plane to the plane of ``lf`` (mm, may vary per point).

    Returns
    -------
    values : ndarray of shape (R, N_θ)
    valid : bool ndarray of shape (R, N_θ)
        False where the curve leaves the sampled y range (the value there is 0).
    """
    c = np.atleast_1d(np.asarray(points_mm, dtype=float))
    d = np.broadcast_to(np.asarray(distance_mm, dtype=float), c.shape)
    q = c[:, None] + d[:, None] * np.tan(lf.theta_rad)[None, :]
    vals = sample_columns(lf.radiance, lf.y_mm[0], lf.dy_mm, q, method=method)
    lo, hi = lf.y_mm[0], lf.y_mm[-1]
    tol = 1e-9 * lf.dy_mm
    return vals, (q >= lo - tol) & (q <= hi + tol)


def project(lf: LightField2D) -> NDArray[Any]:
    """Projection over angle ``S[L](y) = ∫_a^b L(y, θ) dθ`` (midpoint rule), shape (N_y,)."""
    return lf.radiance.sum(axis=1) * lf.dtheta_rad


def propagate_4d(
    lf: LightField4D, distance_mm: float, *, method: Literal["linear", "fourier"] = "fourier"
) -> LightField4D:
    """4-D shear ``L'(x, y, u, v) = L(x − d tan u, y − d tan v, u, v)``; same grids, z + d.

    The shear separates into a shift along x that depends on u and one along y that depends
    on v, applied one after the other (each exact for ``"fourier"``).
    """
    d = float(distance_mm)
    rad = np.asarray(lf.radiance)
    nx, ny, nu, nv = rad.shape
    sx = d * np.tan(lf.u_rad) / lf.dx_mm
    sy = d * np.tan(lf.v_rad) / lf.dy_mm
    if method == "fourier":
        kx = np.fft.fftfreq(2 * nx)[:, None, None, None]
        ky = np.fft.fftfreq(2 * ny)[None, :, None, None]
        spec = np.fft.fft2(rad, s=(2 * nx, 2 * ny), axes=(0, 1))
        phase = np.exp(-2j * np.pi * (kx * sx[None, None, :, None] + ky * sy[None, None, None, :]))
        out = np.fft.ifft2(spec * phase, axes=(0, 1))[:nx, :ny]
        out = out if np.iscomplexobj(rad) else out.real
    elif method == "linear":
        ix = np.arange(nx)[:, None, None, None] - sx[None, None, :, None]
        iy = np.arange(ny)[None, :, None, None] - sy[None, None, None, :]
        iu = np.arange(nu)[None, None, :, None]
        iv = np.arange(nv)[None, None, None, :]
        coords = np.broadcast_arrays(ix, iy, iu, iv)
        out = ndimage.map_coordinates(
            rad.astype(float), [c.astype(float) for c in coords], order=1, mode="constant",
            cval=0.0,
        )
    else:
        raise ValueError(f"unknown method {method!r}")
    return lf.with_radiance(out, z_mm=lf.z_mm + d)


def project_4d(lf: LightField4D) -> NDArray[Any]:
    """Projection over both angles ``∬ L du dv``, shape (N_x, N_y)."""
    return lf.radiance.sum(axis=(2, 3)) * lf.du_rad * lf.dv_rad
