"""The ducc0 backend of the Gauss–Legendre transforms, and the choice of backend.

ducc0 (Reinecke, https://gitlab.mpcdf.mpg.de/mtr/ducc; the SHT library underneath healpy
and pyshtools) computes the same quadrature as :mod:`analysis.sh.transform`'s own
transforms, in compiled SIMD code. Its conventions, matched here at the boundary
(ADR 0040):

* complex harmonics **with** the Condon–Shortley phase, orthonormal on the unit sphere;
  for a real map only m ≥ 0 is stored, the map being
  f = Σ_l a_l0 Y_l0 + 2 Re Σ_{m>0} a_lm Y_lm (Y_lm = (−1)^m λ_l^m e^{imφ});
* m-major layout ("healpy" order): a_lm at index m(2L+1−m)/2 + l;
* ``geometry="GL"`` with L+1 rings and ``phi0=0``: rings at the Gauss–Legendre nodes in
  colatitude from the north pole, 2L+1 equispaced longitudes from φ = 0 — the grid of
  :func:`analysis.sh.transform.gl_grid`, which takes its nodes and weights from ducc0
  (:func:`gl_nodes`) so that both backends use the very same quadrature.

So our real coefficients (no Condon–Shortley phase) map as a_l0 = c_l0 and, for m > 0,
a_lm = (−1)^m (c_lm − i c_l,−m)/√2 (:func:`analysis.sh.convention.convert`); the map needs
no change. Both directions are one gather or scatter by precomputed indices.

The backend (``"ducc0"`` by default, or ``"reference"``: the project's own numpy transform,
kept as the reference the ducc0 path is tested against) and ducc0's thread count (1 by
default: the analysis must not take every core of a shared machine unasked) are module
settings (:func:`set_transform_defaults`) that a keyword of each transform overrides.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Literal, cast

import ducc0
import numpy as np

from analysis.sh.convention import degrees_orders
from analysis.sh.validation import SHInputError

__all__ = [
    "BACKENDS",
    "TransformDefaults",
    "ducc_analysis",
    "ducc_synthesis",
    "gl_nodes",
    "resolve",
    "set_transform_defaults",
    "transform_defaults",
]

Backend = Literal["ducc0", "reference"]
#: The transform backends: ducc0's compiled transform and the project's numpy reference.
BACKENDS: tuple[str, ...] = ("ducc0", "reference")


@dataclass(frozen=True)
class TransformDefaults:
    """Backend and ducc0 thread count used when a transform is not told otherwise.

    Attributes
    ----------
    backend : {"ducc0", "reference"}
    nthreads : int
        ducc0's threads (≥ 1; 0 means every hardware thread, ducc0's own convention).
    """

    backend: Backend = "ducc0"
    nthreads: int = 1


_defaults = TransformDefaults()


def transform_defaults() -> TransformDefaults:
    """The current module-wide backend and thread count."""
    return _defaults


def _check_backend(backend: str) -> Backend:
    if backend not in BACKENDS:
        raise SHInputError("backend", f"must be one of {BACKENDS}, got {backend!r}")
    return cast(Backend, backend)  # one of BACKENDS: checked above


def _check_threads(nthreads: int) -> int:
    if isinstance(nthreads, bool) or not isinstance(nthreads, int | np.integer) or nthreads < 0:
        raise SHInputError("nthreads", f"must be an integer ≥ 0, got {nthreads!r}")
    return int(nthreads)


def set_transform_defaults(*, backend: str | None = None, nthreads: int | None = None
                           ) -> TransformDefaults:
    """Change the module-wide backend and/or ducc0 thread count; returns the previous
    settings (pass their fields back to restore them)."""
    global _defaults
    old = _defaults
    new = old
    if backend is not None:
        new = replace(new, backend=_check_backend(backend))
    if nthreads is not None:
        new = replace(new, nthreads=_check_threads(nthreads))
    _defaults = new
    return old


def resolve(backend: str | None, nthreads: int | None) -> tuple[str, int]:
    """(backend, nthreads) of one call: the keywords, else the module settings."""
    b = _defaults.backend if backend is None else _check_backend(backend)
    n = _defaults.nthreads if nthreads is None else _check_threads(nthreads)
    return b, n


def gl_nodes(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre colatitudes θ_j (ascending from the north pole) and weights in cos θ
    (Σ w_j = 2) of ducc0, the nodes its "GL" geometry uses.

    Both backends run on these nodes so that they compute the same quadrature. ducc0's
    nodes are the roots of P_n to rounding at every n (checked against mpmath at n = 2049);
    :func:`analysis.sh.legendre.gauss_legendre` evaluates P_n in x = cos θ, whose rounding
    moves the polar nodes by up to ε/θ (3.6e-14 rad at the first node for n = 2049).
    """
    theta = np.asarray(ducc0.misc.GL_thetas(n), dtype=np.float64)
    weights = np.asarray(ducc0.misc.GL_weights(n, 1), dtype=np.float64) / (2.0 * np.pi)
    return theta, weights


@functools.lru_cache(maxsize=4)
def _layout(lmax: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Flat real coefficient l² + l + m ↔ float position in ducc0's complex a_lm array.

    Returns (position of each flat coefficient in the float view [Re, Im, Re, Im, …] of
    a_lm, the factor synthesis applies, the factor analysis applies, number of a_lm). The
    cosine part c_lm (m ≥ 0) goes to Re a_l|m|, the sine part c_l,−m to Im a_l|m|; the
    factors hold the 1/√2 of the real harmonics, the Condon–Shortley (−1)^m and the sign
    of the sine part.
    """
    l, m = degrees_orders(lmax)
    am = np.abs(m)
    index = am * (2 * lmax + 1 - am) // 2 + l
    pos = (2 * index + (m < 0)).astype(np.intp)
    cs = np.where(am % 2 == 1, -1.0, 1.0)
    syn = np.where(m == 0, 1.0, cs / np.sqrt(2.0))
    syn = np.where(m < 0, -syn, syn)
    ana = np.where(m == 0, 1.0, cs * np.sqrt(2.0))
    ana = np.where(m < 0, -ana, ana)
    return pos, syn, ana, (lmax + 1) * (lmax + 2) // 2


def ducc_synthesis(coeffs: np.ndarray, lmax: int, nthreads: int) -> np.ndarray:
    """Real coefficients (project convention, flat layout) → map (L+1, 2L+1) on the GL grid."""
    pos, syn, _, nalm = _layout(lmax)
    alm = np.zeros((1, nalm), dtype=np.complex128)
    alm.view(np.float64).reshape(-1)[pos] = coeffs * syn
    out = ducc0.sht.synthesis_2d(alm=alm, spin=0, lmax=lmax, geometry="GL",
                                 ntheta=lmax + 1, nphi=2 * lmax + 1, nthreads=nthreads)
    return out[0]


def ducc_analysis(values: np.ndarray, lmax: int, nthreads: int) -> np.ndarray:
    """Map (L+1, 2L+1) on the GL grid → real coefficients (project convention, flat)."""
    pos, _, ana, _ = _layout(lmax)
    m = np.ascontiguousarray(values, dtype=np.float64)[None]
    alm = ducc0.sht.analysis_2d(map=m, spin=0, lmax=lmax, geometry="GL", nthreads=nthreads)
    return alm.view(np.float64).reshape(-1)[pos] * ana
