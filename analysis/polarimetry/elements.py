"""Mueller matrices of the elements of a polarimeter, with the conventions stated once.

Conventions (ADR 0102)
----------------------
* Stokes vector ``S = (I, Q, U, V)``: ``Q = I(0°) − I(90°)``, ``U = I(45°) − I(135°)``,
  ``V = I(R) − I(L)``, intensities behind ideal analysers.
* Angles are measured from the +x axis of the beam's transverse frame, counter-clockwise
  as seen by an observer looking into the beam (facing the source). In radians inside
  numerical code; the functions here take degrees where the name says ``_deg``.
* Rotation: an element whose axis is at θ has ``M(θ) = R(−θ) · M(0) · R(θ)`` with
  ``R(θ) = [[1,0,0,0],[0,cos2θ,sin2θ,0],[0,−sin2θ,cos2θ,0],[0,0,0,1]]``
  (Goldstein, *Polarized Light*, 3rd ed. 2011, §5.4–5.5, the rotator and rotated
  polarising components).
* Retarder with its fast axis at 0 and retardance δ (radians, phase lead of the fast
  component): ``[[1,0,0,0],[0,1,0,0],[0,0,cosδ,sinδ],[0,0,−sinδ,cosδ]]`` (Goldstein §5.3).
  Handedness follows from it: a quarter-wave plate with its fast axis at +45° turns
  +x linear light ``(1,1,0,0)`` into ``(1,0,0,+1)``; ``V > 0`` is what Goldstein calls
  right-circular. Chipman, Lam & Young (2018, §6.3) use the same matrix for a fast axis
  at 0; a lab whose handedness is opposite flips the sign of row 3 and column 3.
* Mueller matrices are indexed ``M[i, j]`` with ``i, j ∈ {0,1,2,3}`` = (I, Q, U, V);
  where a matrix is flattened, ``vec(M)`` is row-major: element ``(i, j)`` at ``4i + j``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.polarimetry.validation import PolarimetryInputError, check_array

__all__ = [
    "depolariser",
    "diattenuator",
    "linear_polariser",
    "linear_retarder",
    "rotated",
    "rotation",
    "stokes_dop",
]


def _finite_scalar(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise PolarimetryInputError(name, f"must be finite, got {value!r}")
    return v


def rotation(theta_rad: float) -> NDArray[np.float64]:
    """The Mueller rotation matrix ``R(θ)`` (Goldstein 2011, §5.4).

    ``R(θ)`` expresses a Stokes vector in a frame rotated by θ (counter-clockwise, looking
    into the beam); an element with its axis at θ is ``R(−θ) M(0) R(θ)``.

    Returns
    -------
    ndarray of shape (4, 4)
    """
    t = _finite_scalar("theta_rad", theta_rad)
    c, s = math.cos(2 * t), math.sin(2 * t)
    return np.array([[1.0, 0, 0, 0], [0, c, s, 0], [0, -s, c, 0], [0, 0, 0, 1.0]])


def rotated(m: ArrayLike, theta_rad: float) -> NDArray[np.float64]:
    """``R(−θ) · M · R(θ)``: element ``m`` (given at axis 0) turned to axis θ."""
    mat = check_array("m", m, shape=(4, 4))
    return rotation(-theta_rad) @ mat @ rotation(theta_rad)


def diattenuator(theta_rad: float, q: float, r: float) -> NDArray[np.float64]:
    """Linear diattenuator with intensity transmittances ``q`` (axis θ) and ``r`` (⊥ axis).

    ``M(0) = ½ [[q+r, q−r, 0, 0], [q−r, q+r, 0, 0], [0, 0, 2√(qr), 0], [0, 0, 0, 2√(qr)]]``
    (Goldstein 2011, §5.2, with ``q = p_x²``, ``r = p_y²``), rotated to θ.

    Raises
    ------
    PolarimetryInputError
        ``q`` or ``r`` outside [0, 1].
    """
    q = _finite_scalar("q", q)
    r = _finite_scalar("r", r)
    for name, val in (("q", q), ("r", r)):
        if not 0.0 <= val <= 1.0:
            raise PolarimetryInputError(
                name, f"must be an intensity transmittance in [0, 1], got {val}")
    g = math.sqrt(q * r)
    m0 = 0.5 * np.array([[q + r, q - r, 0, 0], [q - r, q + r, 0, 0],
                         [0, 0, 2 * g, 0], [0, 0, 0, 2 * g]])
    return rotated(m0, theta_rad)


def linear_polariser(theta_rad: float, transmittance: float = 1.0) -> NDArray[np.float64]:
    """Ideal linear polariser with its transmission axis at θ (Goldstein 2011, §5.2)."""
    return diattenuator(theta_rad, transmittance, 0.0)


def linear_retarder(theta_rad: float, retardance_rad: float) -> NDArray[np.float64]:
    """Linear retarder, fast axis at θ, retardance δ in radians (Goldstein 2011, §5.3, §5.5).

    ``M(0) = [[1,0,0,0],[0,1,0,0],[0,0,cosδ,sinδ],[0,0,−sinδ,cosδ]]`` rotated to θ; see the
    module docstring for the handedness this fixes.
    """
    d = _finite_scalar("retardance_rad", retardance_rad)
    c, s = math.cos(d), math.sin(d)
    m0 = np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, c, s], [0, 0, -s, c]])
    return rotated(m0, theta_rad)


def depolariser(transmittance: float = 1.0, retained: float = 0.0) -> NDArray[np.float64]:
    """Isotropic depolariser ``t · diag(1, a, a, a)``; ``a = 0`` is the ideal depolariser.

    ``retained`` (``a`` in [0, 1]) is the fraction of the degree of polarisation kept
    (Chipman, Lam & Young 2018, §7.4: the ideal depolariser has only ``m00 ≠ 0``).
    """
    t = _finite_scalar("transmittance", transmittance)
    a = _finite_scalar("retained", retained)
    if t < 0:
        raise PolarimetryInputError("transmittance", f"must be ≥ 0, got {t}")
    if not 0.0 <= a <= 1.0:
        raise PolarimetryInputError("retained", f"must be in [0, 1], got {a}")
    return t * np.diag([1.0, a, a, a])


def stokes_dop(stokes: ArrayLike) -> NDArray[np.float64]:
    """Degree of polarisation ``√(Q² + U² + V²) / I`` (Goldstein 2011, §4.3).

    Parameters
    ----------
    stokes : array_like of shape (..., 4)
        Stokes vectors along the last axis.

    Returns
    -------
    ndarray of shape (...)
        The degree of polarisation; 0 where ``I = 0`` (no light, nothing polarised).

    Raises
    ------
    PolarimetryInputError
        Non-finite entries, a last axis not of length 4, or ``I < 0``.
    """
    s = check_array("stokes", stokes)
    if s.ndim == 0 or s.shape[-1] != 4:
        raise PolarimetryInputError("stokes", f"must have a last axis of length 4, got {s.shape}")
    intensity = s[..., 0]
    if np.any(intensity < 0):
        raise PolarimetryInputError("stokes", "must have I = S[..., 0] ≥ 0")
    pol = np.sqrt(np.sum(s[..., 1:] ** 2, axis=-1))
    safe = np.where(intensity > 0, intensity, 1.0)
    return np.where(intensity > 0, pol / safe, 0.0)
