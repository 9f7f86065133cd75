"""Scattering of a flatland light field by a surface with a BRDF (Sasaki 2020, ch. 2).

``L_out(y_s, θ_out) = ∫_a^b f(y_s, θ_in − Θ(y_s), θ_out − Θ(y_s)) cos(θ_in − Θ(y_s))
L_in(y_s, θ_in) dθ_in`` — the scattering operator of Sasaki 2020 with the local
normal angle Θ of a tilted or curved surface as in eq. (2-6); angles in the unfolded
frame, ``cos`` clipped at 0 for rays arriving from behind the local surface.  The
integral is the midpoint rule on the incident field's cell-centred angle grid.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .field import LightField2D, theta_grid

__all__ = ["BRDFCallable", "scatter", "scattering_kernel"]

#: A flatland BRDF: ``f(theta_in, theta_out, *, y_mm=None) -> 1/rad`` (broadcasting).
BRDFCallable = Callable[..., NDArray[np.float64]]

_CHUNK_ELEMENTS = 4_000_000  # bound the (rows, N_out, N_in) kernel block to ~32 MB


def scattering_kernel(
    brdf: BRDFCallable,
    theta_in_rad: NDArray[np.float64],
    theta_out_rad: NDArray[np.float64],
    dtheta_in_rad: float,
    *,
    normal_angle_rad: ArrayLike = 0.0,
    y_mm: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Quadrature kernel ``K[..., m, j] = f(θ_j − Θ, θ_m − Θ) cos⁺(θ_j − Θ) Δθ``.

    ``normal_angle_rad`` and ``y_mm`` may be arrays of shape (R,), giving a kernel of shape
    (R, N_out, N_in); scalars give (N_out, N_in).
    """
    tn = np.asarray(normal_angle_rad, dtype=float)
    per_point = tn.ndim > 0 or (y_mm is not None and np.ndim(y_mm) > 0)
    ti = np.asarray(theta_in_rad, dtype=float)[None, :]
    to = np.asarray(theta_out_rad, dtype=float)[:, None]
    if per_point:
        n_r = max(tn.size, np.size(y_mm) if y_mm is not None else 1)
        tn = np.broadcast_to(tn.reshape(-1), (n_r,))[:, None, None]
        ti = ti[None]
        to = to[None]
        yy = None if y_mm is None else np.asarray(y_mm, dtype=float).reshape(-1)[:, None, None]
    else:
        yy = None if y_mm is None else np.asarray(y_mm, dtype=float)
    rel_in = ti - tn
    rel_out = to - tn
    f = brdf(rel_in, rel_out, y_mm=yy) if yy is not None else brdf(rel_in, rel_out)
    return f * np.clip(np.cos(rel_in), 0.0, None) * dtheta_in_rad


def scatter(
    lf_in: LightField2D,
    brdf: BRDFCallable,
    *,
    normal_angle_rad: ArrayLike = 0.0,
    theta_out_domain_rad: tuple[float, float] | None = None,
    n_theta_out: int | None = None,
) -> LightField2D:
    """Scatter an incident field at the surface into the outgoing field (same plane, same y).

    Parameters
    ----------
    lf_in : LightField2D
        Incident field at the surface plane, shape (N_y, N_θ).
    brdf : callable
        ``f(θ_in, θ_out, *, y_mm=None)``; an object with ``homogeneous = False`` is called
        with the surface positions.
    normal_angle_rad : float or array of shape (N_y,)
        Local normal angle Θ(y) of a tilted/curved surface (rad, from the +z axis).
    theta_out_domain_rad, n_theta_out : optional
        Output angle grid (defaults: the input grid).

    Returns
    -------
    LightField2D
        Outgoing field of shape (N_y, N_out) at the same ``z_mm``.
    """
    dom_out = lf_in.domain_rad if theta_out_domain_rad is None else theta_out_domain_rad
    n_out = lf_in.theta_rad.size if n_theta_out is None else int(n_theta_out)
    t_out = theta_grid(dom_out, n_out)
    tn = np.asarray(normal_angle_rad, dtype=float)
    homogeneous = bool(getattr(brdf, "homogeneous", True))
    rad = lf_in.radiance
    n_y, n_in = rad.shape
    if tn.ndim == 0 and homogeneous:
        k = scattering_kernel(brdf, lf_in.theta_rad, t_out, lf_in.dtheta_rad,
                              normal_angle_rad=float(tn))
        out = rad @ k.T
    else:
        tn_full = np.broadcast_to(tn, (n_y,))
        out = np.empty((n_y, n_out), dtype=np.result_type(rad, float))
        rows = max(1, _CHUNK_ELEMENTS // (n_out * n_in))
        for s in range(0, n_y, rows):
            sl = slice(s, min(n_y, s + rows))
            k = scattering_kernel(
                brdf, lf_in.theta_rad, t_out, lf_in.dtheta_rad,
                normal_angle_rad=tn_full[sl],
                y_mm=None if homogeneous else lf_in.y_mm[sl],
            )
            out[sl] = np.einsum("rmj,rj->rm", k, rad[sl])
    return LightField2D(out, lf_in.y_mm, t_out, dom_out, lf_in.z_mm)
