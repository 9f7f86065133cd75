"""Lu–Chipman polar decomposition ``M = M_Δ · M_R · M_D`` with propagated uncertainties.

Lu & Chipman 1996 (J. Opt. Soc. Am. A 13, 1106): a Mueller matrix is split into a
diattenuator ``M_D`` (eqs. 18–19), a retarder ``M_R`` and a depolariser ``M_Δ`` (eqs.
35–37 for ``m_Δ``, eq. 40 for its polarisance part), in that order of light passage
(diattenuator first). The scalar results are

* transmittance ``m00``;
* diattenuation ``D = |(m01, m02, m03)| / m00`` (eq. 12);
* retardance ``R = arccos(tr(M_R)/2 − 1)`` in radians (eq. 42) and its fast axis, the
  unit Stokes vector ``a_i = Σ ε_ijk (m_R)_jk / (2 sin R)`` (eq. 43); for a linear
  retarder ``a = (cos 2θ, sin 2θ, 0)`` with θ the fast-axis angle of
  :mod:`analysis.polarimetry.elements`;
* depolarisation power ``Δ = 1 − |tr(m_Δ)| / 3`` (eq. 52).

Uncertainties: first-order propagation ``J Σ Jᵀ`` of the 16×16 covariance of ``vec(M)``
through a central-difference Jacobian of the scalar results (linear propagation; the
tests compare it with Monte Carlo). It is accurate where the results are smooth in M:
not at R = 0 or π (the axis is undefined there) nor at D → 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.polarimetry.validation import (
    PolarimetryInputError,
    check_covariance,
    check_mueller,
)

__all__ = ["PARAMETERS", "PolarDecomposition", "decompose"]

#: Names of the scalar results, in the order of :attr:`PolarDecomposition.params`.
PARAMETERS = ("transmittance", "diattenuation", "retardance", "retardance_axis_deg",
              "depolarisation_power")

#: Above this diattenuation M_D is treated as singular (an ideal polariser).
_D_MAX = 1.0 - 1e-9


@dataclass(frozen=True)
class PolarDecomposition:
    """The result of :func:`decompose`.

    Attributes
    ----------
    m_depolariser, m_retarder, m_diattenuator : ndarray of shape (4, 4)
        The three factors, ``M = M_Δ · M_R · M_D`` (``M_D`` carries ``m00``).
    diattenuation_vector : ndarray of shape (3,)
        ``(m01, m02, m03) / m00``.
    polarisance_vector : ndarray of shape (3,)
        The polarisance of ``M_Δ`` (Lu & Chipman eq. 40).
    retardance_axis : ndarray of shape (3,)
        Unit fast-axis Stokes vector of ``M_R`` (zero vector where R = 0: undefined).
    params : ndarray of shape (5,)
        The scalars named in :data:`PARAMETERS`: transmittance, D, R (rad), the linear
        retardance axis ``½ atan2(a₂, a₁)`` in degrees (−90, 90], Δ.
    sigma : ndarray of shape (5,) or None
        Their standard deviations (linear propagation), ``None`` without a covariance.
    param_cov : ndarray of shape (5, 5) or None
        Their covariance, ``None`` without a covariance.
    """

    m_depolariser: NDArray[np.float64]
    m_retarder: NDArray[np.float64]
    m_diattenuator: NDArray[np.float64]
    diattenuation_vector: NDArray[np.float64]
    polarisance_vector: NDArray[np.float64]
    retardance_axis: NDArray[np.float64]
    params: NDArray[np.float64]
    sigma: NDArray[np.float64] | None
    param_cov: NDArray[np.float64] | None

    def value(self, name: str) -> float:
        """The scalar result called ``name`` (one of :data:`PARAMETERS`)."""
        return float(self.params[PARAMETERS.index(name)])

    def uncertainty(self, name: str) -> float:
        """Its standard deviation; raises ``ValueError`` when no covariance was given."""
        if self.sigma is None:
            raise ValueError("decompose() was called without a covariance")
        return float(self.sigma[PARAMETERS.index(name)])


def _factors(m: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """(M_Δ, M_R, M_D, D-vector, polarisance, axis, params) of Lu & Chipman 1996."""
    m00 = m[0, 0]
    if m00 <= 0:
        raise PolarimetryInputError("m", f"needs m00 > 0 (transmitted intensity), got {m00}")
    dvec = m[0, 1:] / m00
    d = float(np.linalg.norm(dvec))
    if d >= _D_MAX:
        raise PolarimetryInputError(
            "m", f"has diattenuation D = {d:.6g} ≥ 1: M_D is singular (an ideal polariser or "
            "an unphysical matrix) and the decomposition is undefined; check realizability")
    # eq. 18-19: the diattenuator
    root = math.sqrt(1.0 - d * d)
    dhat = dvec / d if d > 0 else np.zeros(3)
    m_d3 = root * np.eye(3) + (1.0 - root) * np.outer(dhat, dhat)
    md = np.empty((4, 4))
    md[0, 0] = 1.0
    md[0, 1:] = dvec
    md[1:, 0] = dvec
    md[1:, 1:] = m_d3
    md *= m00
    # M' = M M_D^-1 = M_Δ M_R (eq. 31)
    mp = m @ np.linalg.inv(md)
    m_sub = mp[1:, 1:]
    # eq. 35-37: m_Δ = ±(m' m'ᵀ)^½, sign of det m'. Lu & Chipman's closed form in the
    # eigenvalues of m' m'ᵀ is this matrix square root; it is taken here through the SVD
    # m' = U S Vᵀ (m_Δ = ±U S Uᵀ, m_R = ±U Vᵀ), which stays defined when m' is singular
    # (an ideal depolariser, a polariser-like m'), where eq. 36's inverse does not exist.
    u, s_vals, vt = np.linalg.svd(m_sub)
    rot = u @ vt
    sign = -1.0 if np.linalg.det(rot) < 0 else 1.0
    m_delta3 = sign * (u * s_vals) @ u.T
    m_r3 = sign * rot
    # eq. 40: M' = M_Δ M_R and M_R's first column is (1, 0, 0, 0), so M'[1:, 0] is the
    # polarisance P_Δ = (P − m D) / (1 − D²) of the depolariser
    pdelta = mp[1:, 0].copy()
    mdelta = np.eye(4)
    mdelta[1:, 0] = pdelta
    mdelta[1:, 1:] = m_delta3
    mr = np.eye(4)
    mr[1:, 1:] = m_r3
    cos_r = np.clip(0.5 * np.trace(mr) - 1.0, -1.0, 1.0)
    r = math.acos(float(cos_r))
    mr3 = mr[1:, 1:]
    raw_axis = np.array([mr3[1, 2] - mr3[2, 1], mr3[2, 0] - mr3[0, 2], mr3[0, 1] - mr3[1, 0]])
    s = math.sin(r)
    axis = raw_axis / (2.0 * s) if s > 1e-12 else np.zeros(3)
    axis_deg = math.degrees(0.5 * math.atan2(float(raw_axis[1]), float(raw_axis[0])))
    depol = 1.0 - abs(float(np.trace(m_delta3))) / 3.0
    params = np.array([m00, d, r, axis_deg, depol])
    return mdelta, mr, md, dvec, pdelta, axis, params


def _wrap_axis(delta_deg: NDArray[np.float64]) -> NDArray[np.float64]:
    """Axis differences folded into (−90°, 90°] (an axis is defined modulo 180°)."""
    return (delta_deg + 90.0) % 180.0 - 90.0


def decompose(m: ArrayLike, cov: ArrayLike | None = None, *,
              step: float = 1e-6) -> PolarDecomposition:
    """Lu–Chipman decomposition of ``m`` (shape (4, 4)), with uncertainties if ``cov`` given.

    Parameters
    ----------
    m : array_like of shape (4, 4)
        The Mueller matrix (not necessarily normalised).
    cov : array_like of shape (16, 16), optional
        Covariance of row-major ``vec(m)``.
    step : float
        Central-difference step for the Jacobian, relative to ``m00``.

    Raises
    ------
    PolarimetryInputError
        Non-finite or mis-shaped input, ``m00 ≤ 0``, or ``D ≥ 1``.
    """
    mat = check_mueller("m", m)
    mdelta, mr, md, dvec, pdelta, axis, params = _factors(mat)
    sigma = pcov = None
    if cov is not None:
        c = check_covariance("cov", cov)
        h = step * float(mat[0, 0])
        jac = np.empty((len(PARAMETERS), 16))
        flat = mat.ravel()
        for k in range(16):
            up, dn = flat.copy(), flat.copy()
            up[k] += h
            dn[k] -= h
            p_up = _factors(up.reshape(4, 4))[-1]
            p_dn = _factors(dn.reshape(4, 4))[-1]
            diff = p_up - p_dn
            diff[3] = _wrap_axis(np.asarray(diff[3]))
            jac[:, k] = diff / (2.0 * h)
        pcov = jac @ c @ jac.T
        sigma = np.sqrt(np.clip(np.diag(pcov), 0.0, None))
    return PolarDecomposition(m_depolariser=mdelta, m_retarder=mr, m_diattenuator=md,
                              diattenuation_vector=dvec, polarisance_vector=pdelta,
                              retardance_axis=axis, params=params, sigma=sigma,
                              param_cov=pcov)
