"""Dual-rotating-retarder (and PEM) polarimetry: instrument matrix and data reduction.

The dual rotating retarder (DRR; Azzam 1978, Opt. Lett. 2, 148; Goldstein 1992, Appl.
Opt. 31, 6676) is a fixed polariser and a rotating retarder in the source arm (the
polarisation-state generator, PSG) and a rotating retarder and a fixed polariser in the
detector arm (the analyser, PSA). Step k sets the retarders to (θ_k, r·θ_k), r = 5 by
default, and the detector reads

    I_k = a_kᵀ · M · g_k = w_k · vec(M),   w_k = vec(a_k g_kᵀ)

(Goldstein 1992, eq. 3 onwards, written in matrix form), with ``g_k`` the Stokes vector
the PSG sends (unit unpolarised source), ``a_k`` the first row of the PSA's Mueller
matrix and ``vec`` row-major (element (i, j) at 4i + j; conventions in
:mod:`analysis.polarimetry.elements`). Stacking the K rows gives the instrument matrix
W (K×16); the Mueller matrix is the weighted least-squares solution of ``W vec(M) = I``
with its full 16×16 covariance (:func:`reduce`).

Retardances are in radians, retarder and polariser angles in degrees (as the stage
reports them).

The fixed polarisers are partial (non-ideal) linear polarisers: diattenuators with
principal intensity transmittances ``q = 1`` along the axis and ``r = ε`` across it, ε the
power extinction ratio of the datasheet (about 10⁻⁵ for a Glan–Taylor prism, 10⁻³ for a
film polariser; 0 is the ideal polariser). Their Mueller matrix at axis 0 is
``½ [[1+ε, 1−ε, 0, 0], [1−ε, 1+ε, 0, 0], [0, 0, 2√ε, 0], [0, 0, 0, 2√ε]]`` (Chipman,
Lam & Young, *Polarized Light and Optical Systems*, 2018, ch. 6, the linear diattenuator
with q = 1, r = ε; Goldstein 2011, §5.2 with ``p_x² = 1``, ``p_y² = ε``). Only its first
row and first column enter W: the generator acts on an unpolarised source and the
detector reads intensity, so ``g ∝ Ret · ½(1+ε, (1−ε) cos 2p, (1−ε) sin 2p, 0)`` and
likewise for the analyser row. A source already polarised along the generator's axis
(a laser) leaks less through it: :func:`generator_extinction` gives the extinction the
generator row takes then.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special

from analysis.polarimetry.elements import diattenuator, linear_polariser, linear_retarder
from analysis.polarimetry.validation import PolarimetryInputError, check_array

__all__ = [
    "MuellerEstimate",
    "analyser_row",
    "check_extinction",
    "condition_number",
    "drr_angles",
    "estimate",
    "generator_extinction",
    "generator_stokes",
    "instrument_matrix",
    "normalise",
    "pem_instrument_rows",
    "reduce",
]

#: Relative singular-value threshold below which W is treated as rank-deficient.
_RANK_RTOL = 1e-10

_UNPOLARISED = np.array([1.0, 0.0, 0.0, 0.0])


def _scalar(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise PolarimetryInputError(name, f"must be finite, got {value!r}")
    return v


def check_extinction(name: str, value: float) -> float:
    """A polariser's power extinction ratio ε, validated: finite and ``0 ≤ ε < 1``.

    Raises
    ------
    PolarimetryInputError
        Naming ``name``, where ε is outside [0, 1) (1 would pass both polarisations
        equally: no polariser).
    """
    e = _scalar(name, value)
    if not 0.0 <= e < 1.0:
        raise PolarimetryInputError(
            name, f"must be a power extinction ratio in [0, 1) (the crossed/parallel "
            f"transmittance from the polariser's datasheet, 0 for an ideal one), got {value!r}")
    return e


def generator_extinction(extinction: float, source_dop: float = 0.0) -> float:
    """Effective extinction of the generator's polariser for a partly polarised source.

    A source of degree of linear polarisation s along the polariser's axis, Stokes
    ``(1, s, 0, 0)`` in its frame, leaves the partial polariser (q = 1, r = ε) as
    ``½(1+ε + (1−ε)s, 1−ε + (1+ε)s, 0, 0)``: the state an unpolarised source leaves a
    polariser of extinction ``ε' = ε (1 − s)/(1 + s)`` in, up to the intensity (equate the
    degrees of polarisation; the matrix of the module docstring). ``s = 0`` (unpolarised)
    gives ε; a laser polarised 0.98 along the axis 0.01 ε. A source polarised slightly
    off the axis also turns the generated state by ~√ε of its misalignment (10⁻³° here);
    the calibration's azimuth 0 is the generated state's, so that is absorbed.

    Raises
    ------
    PolarimetryInputError
        ε outside [0, 1) or s outside [0, 1].
    """
    e = check_extinction("extinction", extinction)
    s = _scalar("source_dop", source_dop)
    if not 0.0 <= s <= 1.0:
        raise PolarimetryInputError(
            "source_dop", f"must be a degree of polarisation in [0, 1], got {source_dop!r}")
    return e * (1.0 - s) / (1.0 + s)


def _polariser_row(p_rad: float, extinction: float) -> NDArray[np.float64]:
    """First row of a partial polariser at axis p: ½(1+ε, (1−ε) cos 2p, (1−ε) sin 2p, 0).

    Also its first column (the matrix is symmetric): the Stokes vector it passes from a
    unit unpolarised source. Module docstring for the source of the matrix.
    """
    e = extinction
    return 0.5 * np.array([1.0 + e, (1.0 - e) * math.cos(2 * p_rad),
                           (1.0 - e) * math.sin(2 * p_rad), 0.0])


def _polariser(p_rad: float, extinction: float) -> NDArray[np.float64]:
    return linear_polariser(p_rad) if extinction == 0.0 else diattenuator(p_rad, 1.0,
                                                                          extinction)


def generator_stokes(retarder_deg: float, retardance: float,
                     polariser_deg: float = 0.0, extinction: float = 0.0
                     ) -> NDArray[np.float64]:
    """Stokes vector (shape (4,)) of a PSG: polariser (extinction ε), then retarder, unit
    unpolarised source."""
    p = math.radians(_scalar("polariser_deg", polariser_deg))
    t = math.radians(_scalar("retarder_deg", retarder_deg))
    e = check_extinction("extinction", extinction)
    return linear_retarder(t, retardance) @ _polariser(p, e) @ _UNPOLARISED


def analyser_row(retarder_deg: float, retardance: float,
                 polariser_deg: float = 0.0, extinction: float = 0.0) -> NDArray[np.float64]:
    """First row (shape (4,)) of a PSA's Mueller matrix: retarder, then polariser
    (extinction ε), detector."""
    p = math.radians(_scalar("polariser_deg", polariser_deg))
    t = math.radians(_scalar("retarder_deg", retarder_deg))
    e = check_extinction("extinction", extinction)
    return (_polariser(p, e) @ linear_retarder(t, retardance))[0].copy()


def instrument_matrix(psg_retarder_deg: ArrayLike, psa_retarder_deg: ArrayLike, *,
                      psg_retardance: float, psa_retardance: float,
                      psg_polariser_deg: float = 0.0,
                      psa_polariser_deg: float = 0.0,
                      psg_extinction: float = 0.0,
                      psa_extinction: float = 0.0) -> NDArray[np.float64]:
    """The DRR instrument matrix W: row k is ``w_k = vec(a_k g_kᵀ)`` (Goldstein 1992).

    Parameters
    ----------
    psg_retarder_deg, psa_retarder_deg : array_like of shape (K,)
        Fast-axis angles of the two retarders at each step, degrees.
    psg_retardance, psa_retardance : float
        Retardances, radians (π/2 for a quarter-wave plate).
    psg_polariser_deg, psa_polariser_deg : float
        Transmission axes of the fixed polarisers, degrees.
    psg_extinction, psa_extinction : float
        The polarisers' power extinction ratios ε in [0, 1) (datasheet values; 0 is an
        ideal polariser and gives W exactly as for ``linear_polariser``).

    Returns
    -------
    ndarray of shape (K, 16)
        ``I_k = W[k] · vec(M)`` with row-major ``vec`` and a unit unpolarised source.
    """
    g_ang = check_array("psg_retarder_deg", psg_retarder_deg, ndim=1)
    a_ang = check_array("psa_retarder_deg", psa_retarder_deg, ndim=1)
    if g_ang.shape != a_ang.shape:
        raise PolarimetryInputError(
            "psa_retarder_deg", f"must have the shape of psg_retarder_deg {g_ang.shape}, "
            f"got {a_ang.shape}")
    d_g = _scalar("psg_retardance", psg_retardance)
    d_a = _scalar("psa_retardance", psa_retardance)
    p_g = math.radians(_scalar("psg_polariser_deg", psg_polariser_deg))
    p_a = math.radians(_scalar("psa_polariser_deg", psa_polariser_deg))
    # vectorised over the steps: g_k = Ret(θ_k) · Pol_ε(p_g) · (1,0,0,0),
    # a_k = [Pol(p_a) · Ret(θ'_k)] row 0; the same matrices as elements.py (tested equal)
    pol_g = _polariser_row(p_g, check_extinction("psg_extinction", psg_extinction))
    pol_a = _polariser_row(p_a, check_extinction("psa_extinction", psa_extinction))
    gen = np.einsum("kij,j->ki", _retarders(np.radians(g_ang), d_g), pol_g)
    ana = np.einsum("i,kij->kj", pol_a, _retarders(np.radians(a_ang), d_a))
    return (ana[:, :, None] * gen[:, None, :]).reshape(g_ang.size, 16)


def _retarders(theta_rad: NDArray[np.float64], delta: float) -> NDArray[np.float64]:
    """Linear-retarder Mueller matrices, shape (K, 4, 4), fast axes θ_k, retardance δ.

    The closed form of ``R(−θ) M(0) R(θ)`` (Goldstein 2011, §5.5) for the matrix of
    :func:`analysis.polarimetry.elements.linear_retarder`.
    """
    c, s = np.cos(2 * theta_rad), np.sin(2 * theta_rad)
    cd, sd = math.cos(delta), math.sin(delta)
    out = np.zeros((theta_rad.size, 4, 4))
    out[:, 0, 0] = 1.0
    out[:, 1, 1] = c * c + s * s * cd
    out[:, 1, 2] = out[:, 2, 1] = c * s * (1.0 - cd)
    out[:, 1, 3] = -s * sd
    out[:, 2, 2] = s * s + c * c * cd
    out[:, 2, 3] = c * sd
    out[:, 3, 1] = s * sd
    out[:, 3, 2] = -c * sd
    out[:, 3, 3] = cd
    return out


def drr_angles(steps: int, ratio: float = 5.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Retarder angles of a DRR scan: ``θ_k = 180°·k/steps`` and ``ratio·θ_k`` (degrees).

    The 1:5 ratio is Azzam's (1978); 16 steps is the minimum for 16 unknowns, but with
    equal steps over 180° the intensity's harmonics (up to 24θ for the 1:5 ratio) alias
    onto each other below 25 steps: W is then rank-deficient for every step count from
    16 to 24 except 23 (:func:`condition_number` returns ``inf``, :func:`reduce` raises).
    Use ≥ 25 steps (36 by default in the plans), for which the condition number no longer
    depends on the step count, or pass other angles to :func:`instrument_matrix`.

    Raises
    ------
    PolarimetryInputError
        ``steps`` not an integer ≥ 16, or ``ratio`` non-finite or zero.
    """
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)):
        raise PolarimetryInputError("steps", f"must be an integer, got {steps!r}")
    if steps < 16:
        raise PolarimetryInputError(
            "steps", f"must be ≥ 16 (16 unknown Mueller elements), got {steps}")
    r = _scalar("ratio", ratio)
    if r == 0:
        raise PolarimetryInputError("ratio", "must be non-zero")
    theta = 180.0 * np.arange(int(steps)) / int(steps)
    return theta, r * theta


def condition_number(w: ArrayLike) -> float:
    """2-norm condition number ``σ_max/σ_min`` of an instrument matrix (shape (K, 16)).

    It bounds how much relative noise in the intensities is amplified in ``vec(M)``
    (Smith 2002, Appl. Opt. 41, 2488, §2, uses this figure of merit for the DRR).
    ``inf`` when W is rank-deficient.
    """
    mat = check_array("w", w, ndim=2)
    if mat.shape[1] != 16:
        raise PolarimetryInputError("w", f"must have 16 columns, got shape {mat.shape}")
    s = np.linalg.svd(mat, compute_uv=False)
    if s.size < 16 or s[-1] <= _RANK_RTOL * s[0]:
        return math.inf
    return float(s[0] / s[-1])


@dataclass(frozen=True)
class MuellerEstimate:
    """A reduced Mueller matrix with its covariance.

    Attributes
    ----------
    m : ndarray of shape (4, 4)
        The Mueller matrix in the units of the intensities (unit-source normalisation).
    cov : ndarray of shape (16, 16)
        Covariance of ``vec(m)`` (row-major).
    sigma : ndarray of shape (4, 4)
        Standard deviations of the elements, ``√diag(cov)`` reshaped.
    chi2 : float
        Weighted residual sum of squares of the fit.
    dof : int
        Degrees of freedom, K − 16 (0 for an exactly determined set).
    m_normalised, cov_normalised, sigma_normalised : ndarray
        ``m / m00`` with its covariance propagated to first order (:func:`normalise`);
        ``m_normalised[0, 0] = 1`` with zero variance. All zero when ``m00 ≤ 0``.
    normalised_valid : bool
        Whether ``m00 > 0``, i.e. whether the normalised matrix exists.
    """

    m: NDArray[np.float64]
    cov: NDArray[np.float64]
    sigma: NDArray[np.float64]
    chi2: float
    dof: int
    m_normalised: NDArray[np.float64]
    cov_normalised: NDArray[np.float64]
    sigma_normalised: NDArray[np.float64]
    normalised_valid: bool = True


def normalise(m: ArrayLike, cov: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``M / m00`` and its covariance by first-order propagation.

    ``n_ij = m_ij / m00``; ``∂n_ij/∂m_kl = δ_(ij),(kl) / m00 − m_ij / m00² · δ_(kl),(00)``;
    ``cov_n = J cov Jᵀ``.

    Raises
    ------
    PolarimetryInputError
        ``m00 ≤ 0`` (no transmitted intensity: the normalised matrix is undefined).
    """
    mat = check_array("m", m, shape=(4, 4))
    c = check_array("cov", cov, shape=(16, 16))
    m00 = float(mat[0, 0])
    if m00 <= 0:
        raise PolarimetryInputError("m", f"needs m00 > 0 to normalise, got {m00}")
    v = mat.ravel()
    jac = np.eye(16) / m00
    jac[:, 0] -= v / m00**2
    # n00 = m00/m00 is 1 identically: its row is zero, not 1/m00 − m00/m00², which rounds
    # to ±1 ulp for some m00 (a variance of 1e-18 where there is none).
    jac[0, :] = 0.0
    return (mat / m00), jac @ c @ jac.T


def reduce(intensities: ArrayLike, sigmas: ArrayLike, w: ArrayLike) -> MuellerEstimate:
    """Weighted least-squares Mueller matrix from DRR or PEM data.

    Solves ``min Σ_k ((w_k · vec(M) − I_k) / σ_k)²``: with ``A = diag(1/σ) W``,
    ``vec(M) = (AᵀA)⁻¹ Aᵀ (I/σ)`` and ``cov = (AᵀA)⁻¹`` (the data-reduction matrix of
    Goldstein 1992, §3, with weights; any least-squares text, e.g. Press et al.,
    *Numerical Recipes* 3rd ed., §15.4, eq. 15.4.8 for the covariance).

    Parameters
    ----------
    intensities : array_like of shape (K,)
        Detector readings, one per row of ``w``.
    sigmas : array_like of shape (K,) or scalar
        Their standard deviations (> 0).
    w : array_like of shape (K, 16)
        Instrument matrix (:func:`instrument_matrix`, :func:`pem_instrument_rows`).

    Raises
    ------
    PolarimetryInputError
        Non-finite or mis-shaped input, a σ ≤ 0, or W of rank < 16 (fewer than 16
        independent settings: some Mueller elements are not determined).
    """
    mat = check_array("w", w, ndim=2)
    if mat.shape[1] != 16:
        raise PolarimetryInputError("w", f"must have 16 columns, got shape {mat.shape}")
    k = mat.shape[0]
    y = check_array("intensities", intensities, shape=(k,))
    s = check_array("sigmas", sigmas)
    if s.ndim == 0:
        s = np.full(k, float(s))
    elif s.shape != (k,):
        raise PolarimetryInputError(
            "sigmas", f"must be a scalar or have shape ({k},), got {s.shape}")
    if np.any(s <= 0):
        raise PolarimetryInputError("sigmas", "must all be > 0")
    a = mat / s[:, None]
    u, sv, vt = np.linalg.svd(a, full_matrices=False)
    rank = int(np.sum(sv > _RANK_RTOL * sv[0])) if sv.size and sv[0] > 0 else 0
    if k < 16 or rank < 16:
        raise PolarimetryInputError(
            "w", f"has rank {rank} < 16 ({k} rows): these settings determine only {rank} of "
            "the 16 Mueller elements; use at least 16 distinct steps (drr_angles(steps ≥ 16)) "
            "or add generator/analyser states")
    b = y / s
    vec = vt.T @ ((u.T @ b) / sv)
    cov = (vt.T / sv**2) @ vt
    cov = 0.5 * (cov + cov.T)
    resid = a @ vec - b
    m = vec.reshape(4, 4)
    return estimate(m, cov, chi2=float(resid @ resid), dof=k - 16)


def estimate(m: ArrayLike, cov: ArrayLike, *, chi2: float, dof: int) -> MuellerEstimate:
    """A :class:`MuellerEstimate` from a matrix and its covariance (σ, normalised parts).

    Used by :func:`reduce` and by reductions that add terms to the covariance (e.g. the
    calibration's, :func:`analysis.polarimetry.calibration.reduce_calibrated`).
    """
    mat = check_array("m", m, shape=(4, 4))
    c = check_array("cov", cov, shape=(16, 16))
    sigma = np.sqrt(np.clip(np.diag(c), 0.0, None)).reshape(4, 4)
    valid = bool(mat[0, 0] > 0)
    if valid:
        mn, cn = normalise(mat, c)
    else:  # nothing transmitted: M/m00 is not observable; zeros and the flag, not NaN
        mn, cn = np.zeros((4, 4)), np.zeros((16, 16))
    sn = np.sqrt(np.clip(np.diag(cn), 0.0, None)).reshape(4, 4)
    return MuellerEstimate(m=mat, cov=c, sigma=sigma, chi2=float(chi2), dof=int(dof),
                           m_normalised=mn, cov_normalised=cn, sigma_normalised=sn,
                           normalised_valid=valid)


def pem_instrument_rows(analysers: ArrayLike, *, amplitude_rad: float,
                        pem_axis_deg: float = 45.0,
                        polariser_deg: float = 0.0,
                        polariser_extinction: float = 0.0) -> NDArray[np.float64]:
    """Rows of the instrument matrix for a PEM generator read at DC, 1f and 2f.

    The generator is a polariser at ``polariser_deg`` followed by a photoelastic modulator
    with its axis at ``pem_axis_deg`` and retardation ``δ(t) = A sin ωt``. Every element of
    a retarder's Mueller matrix is affine in (cos δ, sin δ), so the generated Stokes vector
    is ``g(t) = g₀ + g_c cos δ(t) + g_s sin δ(t)``. The Jacobi–Anger expansions
    ``cos(A sin ωt) = J₀(A) + 2 Σ J₂ₙ(A) cos 2nωt`` and
    ``sin(A sin ωt) = 2 Σ J₂ₙ₊₁(A) sin (2n+1)ωt`` (Abramowitz & Stegun 9.1.42–43) give

    * DC:  ``g₀ + J₀(A) g_c``
    * 1f:  ``√2 J₁(A) g_s`` — the RMS amplitude of the ``sin ωt`` component
    * 2f:  ``√2 J₂(A) g_c`` — the RMS amplitude of the ``cos 2ωt`` component

    Lock-in convention: the 1f and 2f channels are the signed in-phase outputs of a
    lock-in that reports RMS amplitudes (as the SR830 does), phased so that the PEM's
    ``sin ωt`` (at 1f) and ``cos 2ωt`` (at 2f) read positive; the DC channel is the mean
    intensity. For a PEM at 45° after a polariser at 0°, ``g = (1, cos δ, 0, sin δ)``: the
    1f channel senses V, the 2f channel Q; U is not generated, so a full Mueller matrix
    needs a second generator setting (e.g. polariser at 45°, PEM at 0°), stacked.

    Parameters
    ----------
    analysers : array_like of shape (N, 4)
        First rows of the analyser Mueller matrices (:func:`analyser_row`), one per fixed
        analyser setting.
    amplitude_rad : float
        Peak retardation A of the PEM, radians (2.405 rad zeroes J₀).
    polariser_extinction : float
        The source polariser's power extinction ratio ε (a partial polariser, as in
        :func:`instrument_matrix`; 0 is ideal).

    Returns
    -------
    ndarray of shape (3N, 16)
        For analyser n, rows 3n, 3n+1, 3n+2 are the DC, 1f and 2f channels.
    """
    an = check_array("analysers", analysers, ndim=2)
    if an.shape[1] != 4:
        raise PolarimetryInputError("analysers", f"must have shape (N, 4), got {an.shape}")
    amp = _scalar("amplitude_rad", amplitude_rad)
    pem_axis_deg = _scalar("pem_axis_deg", pem_axis_deg)
    polariser_deg = _scalar("polariser_deg", polariser_deg)
    e = polariser_extinction
    g_plus = generator_stokes(pem_axis_deg, 0.0, polariser_deg, e)       # g0 + gc
    g_minus = generator_stokes(pem_axis_deg, math.pi, polariser_deg, e)  # g0 − gc
    g_quarter = generator_stokes(pem_axis_deg, math.pi / 2, polariser_deg, e)  # g0 + gs
    g0 = 0.5 * (g_plus + g_minus)
    gc = 0.5 * (g_plus - g_minus)
    gs = g_quarter - g0
    j0, j1, j2 = (float(special.jv(n, amp)) for n in (0, 1, 2))
    channels: Sequence[NDArray[np.float64]] = (
        g0 + j0 * gc, math.sqrt(2.0) * j1 * gs, math.sqrt(2.0) * j2 * gc)
    rows = [np.outer(a, g).ravel() for a in an for g in channels]
    return np.array(rows).reshape(len(rows), 16)
