"""Forward model of the unfolded NLOS scene: object →d1→ wall →d2→ measurement plane.

Eq. (2-3) of Sasaki 2020 (PhD thesis, Univ. of Minnesota):
``L_meas(y_m, θ_m) = ∫_a^b f(θ_o, θ_m) cos θ_o L_obj(y_m − d2 tan θ_m − d1 tan θ_o, θ_o) dθ_o``,
and its per-point form (eq. 2-6) with the local normal angle Θ(c).  Coordinates: the wall
(scattering plane) is at z = 0, the object plane at z = −d1, the measurement plane at
z = +d2; y in mm, θ in rad from the +z axis in the unfolded frame.

This module is the *discretised* operator (midpoint rule in θ, linear or cubic
interpolation in y).  Simulated measurements for validation come from the continuous
renderer in ``hw_mocks.sim.lightfield_scene``, never from this operator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse

from .field import LightField2D
from .propagate import Interpolation, propagate, sample_columns
from .scatter import BRDFCallable, scatter, scattering_kernel

__all__ = ["UnfoldedScene"]


@dataclass(frozen=True)
class UnfoldedScene:
    """Geometry and wall of the unfolded scene (eq. 2-3/eq. 2-6).

    Parameters
    ----------
    brdf : callable
        Flatland BRDF ``f(θ_in, θ_out, *, y_mm=None)`` in the unfolded frame (1/rad).
    d1_mm : float
        Object plane → wall distance (mm, > 0).
    d2_mm : float
        Wall → measurement plane distance (mm, ≥ 0).
    normal_angle_rad : float or array of shape (N_wall,)
        Local wall normal angle Θ(c) (rad).
    """

    brdf: BRDFCallable
    d1_mm: float
    d2_mm: float
    normal_angle_rad: ArrayLike = 0.0

    def __post_init__(self) -> None:
        if not self.d1_mm > 0 or self.d2_mm < 0:
            raise ValueError("need d1_mm > 0 and d2_mm >= 0")

    def wall_incident(
        self, lf_obj: LightField2D, *, method: Interpolation = "cubic"
    ) -> LightField2D:
        """Incident field at the wall: the object-plane field propagated by d1."""
        return propagate(lf_obj, self.d1_mm, method=method)

    def measure_from_wall(
        self,
        lf_wall_in: LightField2D,
        y_meas_mm: NDArray[np.float64],
        *,
        method: Interpolation = "cubic",
    ) -> LightField2D:
        """Scatter the wall's incident field and propagate by d2 onto the y_meas grid.

        ``L_meas(y_m, θ_m) = L_out(y_m − d2 tan θ_m, θ_m)``; zero where that wall point lies
        outside the wall grid.  Returns a field of shape (N_meas, N_θ) at z = d2.
        """
        out = scatter(lf_wall_in, self.brdf, normal_angle_rad=self.normal_angle_rad)
        y_m = np.asarray(y_meas_mm, dtype=float)
        q = y_m[:, None] - self.d2_mm * np.tan(out.theta_rad)[None, :]
        interp = "cubic" if method == "fourier" else method
        vals = sample_columns(out.radiance, out.y_mm[0], out.dy_mm, q, method=interp)
        return LightField2D(vals, y_m, out.theta_rad, out.domain_rad, self.d2_mm)

    def forward(
        self,
        lf_obj: LightField2D,
        y_meas_mm: NDArray[np.float64],
        *,
        method: Interpolation = "cubic",
    ) -> LightField2D:
        """Measured light field of an object-plane field (discretised eq. 2-3)."""
        return self.measure_from_wall(self.wall_incident(lf_obj, method=method), y_meas_mm,
                                      method=method)

    def operator_matrix(
        self,
        wall_y_mm: NDArray[np.float64],
        theta_rad: NDArray[np.float64],
        dtheta_rad: float,
        y_meas_mm: NDArray[np.float64],
    ) -> sparse.csr_matrix:
        """Sparse matrix of the discretised wall-incident → measurement map (linear interp).

        Unknowns: the incident field at the wall ``L_in(c_i, θ_j)`` flattened row-major
        (index ``i·N_θ + j``); data: ``L_meas(y_k, θ_m)`` flattened as ``k·N_θ + m``.
        Shape (N_meas·N_θ, N_wall·N_θ); ``2·N_θ`` non-zeros per row at most.
        """
        c = np.asarray(wall_y_mm, dtype=float)
        th = np.asarray(theta_rad, dtype=float)
        y_m = np.asarray(y_meas_mm, dtype=float)
        n_c, n_t, n_m = c.size, th.size, y_m.size
        if np.ndim(self.normal_angle_rad) > 0 or not getattr(self.brdf, "homogeneous", True):
            raise ValueError("operator_matrix supports a homogeneous, untilted wall only")
        k = scattering_kernel(self.brdf, th, th, dtheta_rad,
                              normal_angle_rad=float(np.asarray(self.normal_angle_rad)))
        dc = c[1] - c[0]
        idx = (y_m[:, None] - self.d2_mm * np.tan(th)[None, :] - c[0]) / dc  # (n_m, n_t)
        i0 = np.floor(idx).astype(np.int64)
        w1 = idx - i0
        rows, cols, vals = [], [], []
        row_ids = (np.arange(n_m)[:, None] * n_t + np.arange(n_t)[None, :])
        for off, w in ((0, 1.0 - w1), (1, w1)):
            ii = i0 + off
            ok = (ii >= 0) & (ii < n_c) & (idx >= -1e-9) & (idx <= n_c - 1 + 1e-9) & (w != 0)
            r_sel = row_ids[ok]
            m_sel = np.nonzero(ok)[1]
            i_sel = ii[ok]
            w_sel = w[ok]
            # each (row, wall point) pair couples to every incident angle j
            rows.append(np.repeat(r_sel, n_t))
            cols.append((i_sel[:, None] * n_t + np.arange(n_t)[None, :]).ravel())
            vals.append((w_sel[:, None] * k[m_sel, :]).ravel())
        return sparse.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(n_m * n_t, n_c * n_t),
        )
