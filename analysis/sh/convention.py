"""The spherical-harmonic convention used throughout ``analysis.sh``, written down once.

Conventions (the project's canonical one is :data:`PROJECT_CONVENTION`):

* Angles: θ is the **colatitude** measured from +z (0 ≤ θ ≤ π), φ the azimuth from +x
  towards +y (0 ≤ φ < 2π). Unit vectors are (sin θ cos φ, sin θ sin φ, cos θ).
* Normalisation: **orthonormal** on the unit sphere, ∫ Y_lm Y_l'm' dΩ = δ_ll' δ_mm'.
* Real harmonics (the graphics convention of Ramamoorthi & Hanrahan, SIGGRAPH 2001, and of
  Mahajan, Ramamoorthi & Curless 2006, where Y_1,1 = +0.488603 x):

      Y_l0      = λ_l^0(cos θ)
      Y_lm      = √2 λ_l^m(cos θ) cos(mφ)      (m > 0)
      Y_l,−m    = √2 λ_l^m(cos θ) sin(mφ)      (m > 0)

  with λ_l^m = √((2l+1)/(4π) (l−m)!/(l+m)!) P_l^m and P_l^m **without** the Condon–Shortley
  phase. With ``condon_shortley=True`` every order m ≠ 0 carries the extra factor (−1)^m.
* Complex harmonics: Y_l^m = λ_l^m e^{imφ} (× (−1)^m with the Condon–Shortley phase), and
  Y_l^{−m} = (−1)^m conj(Y_l^m) for the Condon–Shortley version (the convention of ducc0 and
  most physics texts).
* Coefficient layout: a flat vector of length (L+1)², index ``l*l + l + m`` for
  −l ≤ m ≤ l (see :func:`lm_index`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from analysis.sh.validation import SHInputError, check_coefficients, check_degree

__all__ = [
    "PROJECT_CONVENTION",
    "SHConvention",
    "band_slice",
    "convert",
    "degrees_orders",
    "lm_index",
    "lmax_from_size",
    "n_coeffs",
]


@dataclass(frozen=True)
class SHConvention:
    """An explicit spherical-harmonic convention.

    Attributes
    ----------
    kind : {"real", "complex"}
        Real (cos/sin) or complex (e^{imφ}) harmonics.
    normalization : {"orthonormal"}
        Only the orthonormal normalisation is used in the project; other normalisations
        (e.g. the geodesy "4π" one of SHTOOLS) are converted at the boundary.
    condon_shortley : bool
        Whether the factor (−1)^m is included in the harmonics.
    colatitude : bool
        θ is the colatitude from +z (always True here; kept explicit for readers).
    """

    kind: Literal["real", "complex"] = "real"
    normalization: Literal["orthonormal"] = "orthonormal"
    condon_shortley: bool = False
    colatitude: bool = True

    def __post_init__(self) -> None:
        if self.kind not in ("real", "complex"):
            raise ValueError(f"kind must be 'real' or 'complex', got {self.kind!r}")
        if self.normalization != "orthonormal":
            raise ValueError("only the orthonormal normalisation is supported")
        if not self.colatitude:
            raise ValueError("θ must be the colatitude (angle from +z)")


#: Real, orthonormal, no Condon–Shortley phase, θ colatitude (Ramamoorthi–Hanrahan graphics).
PROJECT_CONVENTION = SHConvention()


def n_coeffs(lmax: int) -> int:
    """Number of coefficients (L+1)² up to degree ``lmax``."""
    return (check_degree("lmax", lmax) + 1) ** 2


def lmax_from_size(size: int) -> int:
    """Inverse of :func:`n_coeffs`; raises if ``size`` is not a perfect square."""
    size = check_degree("size", size, minimum=1)
    lmax = math.isqrt(size) - 1
    if (lmax + 1) ** 2 != size:
        raise SHInputError("size", f"must be (L+1)² for some L, got {size} coefficients")
    return lmax


def lm_index(l: int | np.ndarray, m: int | np.ndarray) -> int | np.ndarray:
    """Flat index ``l*l + l + m`` of coefficient (l, m), −l ≤ m ≤ l."""
    return l * l + l + m


def band_slice(l: int | np.integer[Any]) -> slice:
    """Slice of the flat vector holding the 2l+1 coefficients of degree l (m = −l … l)."""
    l = check_degree("l", l)
    return slice(l * l, (l + 1) * (l + 1))


def degrees_orders(lmax: int) -> tuple[np.ndarray, np.ndarray]:
    """Arrays (l, m) of shape ((L+1)²,) giving the degree and order of each flat index."""
    lmax = check_degree("lmax", lmax)
    l = np.repeat(np.arange(lmax + 1), 2 * np.arange(lmax + 1) + 1)
    m = np.arange(l.size) - l * l - l
    return l, m


def convert(
    coeffs: np.ndarray,
    *,
    source: SHConvention,
    target: SHConvention,
) -> np.ndarray:
    """Convert coefficients of a real-valued function between conventions.

    Parameters
    ----------
    coeffs : ndarray of shape ((L+1)², ...)
        Coefficients in ``source`` convention, flat layout along axis 0.
    source, target : SHConvention

    Returns
    -------
    ndarray of shape ((L+1)², ...)
        Real dtype for a real target, complex for a complex target.

    Notes
    -----
    For a real function f with real coefficients c (no CS phase), the complex coefficients
    (no CS phase) are a_l0 = c_l0, a_lm = (c_lm − i c_l,−m)/√2 and
    a_l,−m = (c_lm + i c_l,−m)/√2 for m > 0. The Condon–Shortley phase multiplies the real
    harmonics of odd |m| by −1, and the complex ones of odd m > 0 only (since then
    Y^{−m} = (−1)^m conj(Y^m) is unchanged).
    """
    c, lmax = check_coefficients("coeffs", coeffs,
                                 dtype=complex if np.iscomplexobj(coeffs) else float)
    for name, conv in (("source", source), ("target", target)):
        if not isinstance(conv, SHConvention):
            raise SHInputError(name, f"must be an SHConvention, got {type(conv).__name__}")
    _, m = degrees_orders(lmax)
    shape = (-1,) + (1,) * (c.ndim - 1)
    m_b = m.reshape(shape)
    odd = np.abs(m_b) % 2 == 1
    # Complex CS harmonics: Y^{-m} = (-1)^m conj(Y^m) leaves negative orders unsigned.
    odd_pos = odd & (m_b > 0)
    # Step 1: to the real, no-CS form.
    if source.kind == "real":
        real = c.astype(float, copy=True)
        if source.condon_shortley:
            real = np.where(odd, -real, real)
    else:
        a = c.astype(complex, copy=True)
        if source.condon_shortley:
            a = np.where(odd_pos, -a, a)
        real = np.empty(c.shape, dtype=float)
        l_all, _ = degrees_orders(lmax)
        pos = m > 0
        zero = m == 0
        real[zero] = a[zero].real
        idx_p = np.nonzero(pos)[0]
        idx_n = lm_index(l_all[pos], -m[pos])
        real[idx_p] = np.sqrt(2.0) * a[idx_p].real
        real[idx_n] = -np.sqrt(2.0) * a[idx_p].imag
    # Step 2: from the real, no-CS form to the target.
    if target.kind == "real":
        out = real
        if target.condon_shortley:
            out = np.where(odd, -out, out)
        return out
    l_all, _ = degrees_orders(lmax)
    out_c = np.empty(c.shape, dtype=complex)
    zero = m == 0
    out_c[zero] = real[zero]
    pos = np.nonzero(m > 0)[0]
    neg = lm_index(l_all[pos], -m[pos])
    out_c[pos] = (real[pos] - 1j * real[neg]) / np.sqrt(2.0)
    out_c[neg] = (real[pos] + 1j * real[neg]) / np.sqrt(2.0)
    if target.condon_shortley:
        out_c = np.where(odd_pos, -out_c, out_c)
    return out_c
