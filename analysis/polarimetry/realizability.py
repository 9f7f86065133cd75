"""Physical realizability of a measured Mueller matrix: Cloude's coherency matrix test.

A Mueller matrix is physically realizable (a convex sum of non-depolarising Jones
systems) exactly when its coherency matrix ``H`` is positive semi-definite (Cloude 1986,
Optik 75, 26; Gil, *Polarized Light and the Mueller Matrix Approach*, 2nd ed. 2022,
§5.3 / eq. 5.16 for the Pauli-product form used here):

    H = ¼ Σ_ij m_ij (σ_i ⊗ σ_j*),     m_ij = Re tr((σ_i ⊗ σ_j*)† H)

with the Pauli matrices ordered as the Stokes parameters, σ₀ = 1, σ₁ = diag(1, −1),
σ₂ = [[0, 1], [1, 0]], σ₃ = [[0, −i], [i, 0]]. ``tr H = m00``; a non-depolarising
matrix has one non-zero eigenvalue. ``H`` is linear in ``M``, so every eigenvalue's
first-order standard deviation follows from the 16×16 covariance
(``∂λ_k/∂m_ij = ¼ v_k† (σ_i ⊗ σ_j*) v_k``, non-degenerate perturbation theory).

The test. Noise puts the eigenvalues of a matrix on the boundary (a pure, non-depolarising
element has three zero eigenvalues) below zero about half the time, and first-order σ is
not valid for degenerate eigenvalues, so "λ ≥ −kσ" alone does not hold its nominal level.
:func:`realizability` therefore computes a p-value for the null hypothesis "M is
realizable" by a parametric bootstrap at the nearest realizable matrix (the eigenvalues of
``H`` clipped at zero; Higham 1988, Linear Algebra Appl. 103, 103, Theorem 2.1): draws
``M* ~ N(M_phys, cov)`` give the distribution of the smallest eigenvalue a realizable
matrix would show, and ``p = P(λ*_min ≤ λ_min)``. The null is taken least favourable:
eigenvalues within 3 first-order σ of zero are also put at zero, since clipping only the
negative ones leaves a noisy pure element's small positive eigenvalues in the null and
shifts its λ*_min distribution up (a false-flag rate of 16 % instead of 5 % in the
tests). A matrix is flagged when ``p < alpha``; the false-flag rate is then ≈ alpha at
the boundary and below it inside. The projected matrix is only the null hypothesis of
the test: it is never returned as data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.polarimetry.validation import (
    PolarimetryInputError,
    check_covariance,
    check_mueller,
)

__all__ = ["Realizability", "coherency_matrix", "mueller_from_coherency", "realizability"]

#: Eigenvalues below this many first-order σ are put on the boundary (0) for the null.
_NULL_K = 3.0

_PAULI = (
    np.eye(2, dtype=complex),
    np.array([[1, 0], [0, -1]], dtype=complex),
    np.array([[0, 1], [1, 0]], dtype=complex),
    np.array([[0, -1j], [1j, 0]], dtype=complex),
)
#: The 16 basis matrices σ_i ⊗ σ_j*, indexed like row-major vec(M): shape (16, 4, 4).
_BASIS = np.array([np.kron(_PAULI[i], _PAULI[j].conj()) for i in range(4) for j in range(4)])


def coherency_matrix(m: ArrayLike) -> NDArray[np.complex128]:
    """Cloude's coherency matrix ``H = ¼ Σ m_ij (σ_i ⊗ σ_j*)`` (shape (4, 4), Hermitian)."""
    mat = check_mueller("m", m)
    return np.einsum("k,kab->ab", mat.ravel(), _BASIS) / 4.0


def mueller_from_coherency(h: ArrayLike) -> NDArray[np.float64]:
    """The Mueller matrix (shape (4, 4)) of a coherency matrix: ``m_ij = Re tr(B_ij† H)``."""
    arr = np.asarray(h, dtype=complex)
    if arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
        raise PolarimetryInputError("h", f"must be a finite 4×4 matrix, got shape {arr.shape}")
    return np.einsum("kba,ba->k", _BASIS.conj(), arr).real.reshape(4, 4)


@dataclass(frozen=True)
class Realizability:
    """The result of :func:`realizability`.

    Attributes
    ----------
    eigenvalues : ndarray of shape (4,)
        Eigenvalues of H, ascending (sum ``m00``).
    sigma : ndarray of shape (4,)
        Their first-order standard deviations (indicative; see the module docstring).
    p_value : float
        Bootstrap p-value of "M is realizable" (1 when the smallest eigenvalue is ≥ 0).
    alpha : float
        The level of the test.
    flagged : bool
        ``p_value < alpha``: the matrix is not realizable within its noise. Nothing is
        projected or altered; downstream code decides what to do with a flagged matrix.
    """

    eigenvalues: NDArray[np.float64]
    sigma: NDArray[np.float64]
    p_value: float
    alpha: float
    flagged: bool


def _sqrt_psd(cov: NDArray[np.float64]) -> NDArray[np.float64]:
    """A matrix L with L Lᵀ = cov, for a possibly singular covariance (eigen square root)."""
    vals, vecs = np.linalg.eigh(cov)
    return vecs * np.sqrt(np.clip(vals, 0.0, None))


def realizability(m: ArrayLike, cov: ArrayLike, *, alpha: float = 0.05,
                  n_boot: int = 2000, seed: int = 0) -> Realizability:
    """Test whether ``m`` is physically realizable within its covariance.

    Parameters
    ----------
    m : array_like of shape (4, 4)
        The measured Mueller matrix.
    cov : array_like of shape (16, 16)
        Covariance of row-major ``vec(m)``.
    alpha : float
        Level of the test, in (0, 1): the false-flag rate for a realizable matrix is at
        most ``alpha``.
    n_boot : int
        Bootstrap draws (≥ 100); the p-value's resolution is 1/(n_boot + 1).
    seed : int
        Seed of the bootstrap's generator (results are reproducible).

    Raises
    ------
    PolarimetryInputError
        Non-finite or mis-shaped input, ``alpha`` outside (0, 1), ``n_boot`` < 100.
    """
    mat = check_mueller("m", m)
    c = check_covariance("cov", cov)
    if not 0.0 < float(alpha) < 1.0:
        raise PolarimetryInputError("alpha", f"must be in (0, 1), got {alpha}")
    if int(n_boot) < 100:
        raise PolarimetryInputError("n_boot", f"must be ≥ 100, got {n_boot}")
    h = coherency_matrix(mat)
    lam, vecs = np.linalg.eigh(h)
    # first-order σ: ∂λ_k/∂m_ij = ¼ v_k† B_ij v_k
    grads = np.einsum("ak,nab,bk->kn", vecs.conj(), _BASIS, vecs).real / 4.0
    sig = np.sqrt(np.clip(np.einsum("kn,nm,km->k", grads, c, grads), 0.0, None))
    lam_min = float(lam[0])
    if lam_min >= 0.0:
        p = 1.0
    else:
        # least favourable null: eigenvalues within _NULL_K σ of zero are set to zero
        # (a noisy pure element has three such), negative ones too
        lam_null = np.where(lam < _NULL_K * sig, 0.0, lam)
        h_phys = (vecs * lam_null) @ vecs.conj().T
        m_phys = mueller_from_coherency(h_phys).ravel()
        rng = np.random.default_rng(seed)
        draws = m_phys + rng.standard_normal((int(n_boot), 16)) @ _sqrt_psd(c).T
        h_star = np.einsum("sk,kab->sab", draws, _BASIS) / 4.0
        lam_star = np.linalg.eigvalsh(h_star)[:, 0]
        p = float((1 + np.sum(lam_star <= lam_min)) / (int(n_boot) + 1))
    return Realizability(eigenvalues=lam, sigma=sig, p_value=p, alpha=float(alpha),
                         flagged=p < float(alpha))
