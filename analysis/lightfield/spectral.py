"""Fourier basis on an angle domain and the BRDF matrices B and B̃ (Sasaki 2020,
ch. 2).

Basis (eq. 2-13): ``φ_p(θ) = exp(i p ω (θ − θ_c))``, ``ω = 2π/(b − a)``, ``θ_c = (a + b)/2``,
orthonormal under ``⟨f, g⟩ = (1/(b − a)) ∫_a^b f g* dθ``.  On the cell-centred grid
``θ_j = a + (j + ½)Δθ`` the coefficients ``X_p = ⟨x, φ_p⟩`` are computed exactly (for
band-limited x) by one FFT: ``X_p = e^{iπp(1 − 1/N)} FFT(x)_p / N``; orders are kept in
numpy ``fftfreq`` order, ``p = −N/2 … N/2 − 1``.

Matrices (M_p = Σ_q B_pq O_q):

* plain basis  ``B_pq  = (1/(b−a)) ∬ f(θ_o, θ_m) cos θ_o φ_q(θ_o) φ_p*(θ_m) dθ_o dθ_m`` (eq. 2-13);
* weighted basis (eq. 2-18) — the unknown is ``G(θ_o) = cos θ_o · O(θ_o)`` — so that
  ``B̃_pq = (1/(b−a)) ∬ f φ_q(θ_o) φ_p*(θ_m)``, the plain 2-D Fourier coefficient of f;
* separable model (eq. 2-14…25): ``B̃_pq = S_pp W_{p−q} + D_p D_q*`` with
  ``S_pp = ∫_{−(b−a)/2}^{(b−a)/2} f_spec(ζ) e^{−ipωζ} dζ`` (one period: the specular
  convolution is treated as periodic on the domain), ``W_k = ⟨f_wind, φ_k⟩`` and
  ``D_p = (1/√(b−a)) ∫_a^b f_diff φ_p* dθ``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .brdf import FlatlandBRDF, SpatiallyVaryingBRDF
from .field import theta_grid
from .scatter import BRDFCallable

__all__ = [
    "SeparableSpectra",
    "brdf_fourier_matrix",
    "coefficients",
    "fourier_orders",
    "separable_spectra",
    "synthesize",
]


def fourier_orders(n: int) -> NDArray[np.int64]:
    """Orders p of an N-point grid in fftfreq order (−N/2 … N/2 − 1)."""
    return np.rint(np.fft.fftfreq(n) * n).astype(np.int64)


def _phase(n: int) -> NDArray[np.complex128]:
    p = fourier_orders(n)
    return np.exp(1j * np.pi * p * (1.0 - 1.0 / n))


def coefficients(samples: ArrayLike, *, axis: int = -1) -> NDArray[np.complex128]:
    """Coefficients ``X_p = ⟨x, φ_p⟩`` of cell-centred samples along ``axis`` (eq. 2-13)."""
    x = np.asarray(samples)
    n = x.shape[axis]
    shape = [1] * x.ndim
    shape[axis] = n
    return np.fft.fft(x, axis=axis) * _phase(n).reshape(shape) / n


def synthesize(coeffs: ArrayLike, *, axis: int = -1) -> NDArray[np.complex128]:
    """Inverse of :func:`coefficients`: ``x(θ_j) = Σ_p X_p φ_p(θ_j)``."""
    c = np.asarray(coeffs)
    n = c.shape[axis]
    shape = [1] * c.ndim
    shape[axis] = n
    return np.fft.ifft(c * np.conj(_phase(n)).reshape(shape), axis=axis) * n


def _fine_n(n: int, width: float, lobe_rad: float | None, oversample: int) -> int:
    k = oversample * n
    if lobe_rad is not None:
        k = max(k, int(np.ceil(16 * width / lobe_rad)))
    return int(2 ** np.ceil(np.log2(k)))


def _resample_orders(c_fine: NDArray[Any], n: int) -> NDArray[Any]:
    """Pick the orders of an N-grid from coefficients computed on a finer grid."""
    k = c_fine.shape[-1]
    p = fourier_orders(n)
    return c_fine[..., np.mod(p, k)]


@dataclass(frozen=True)
class SeparableSpectra:
    """Spectra of the separable BRDF model per scattering point (eq. 2-20…25).

    Attributes
    ----------
    orders : ndarray (N,) — the Fourier orders p (fftfreq order)
    s : ndarray (R or 1, N) complex — S_pp, the approximate eigenvalues
    d : ndarray (R or 1, N) complex — D_p, the diffuse coefficients
    w : ndarray (N,) complex — W_k of the window (δ_k0 for a flat window)
    flat_window : bool — True when W_k = δ_k0 and the closed form eq. 2-32/33 is exact
    """

    orders: NDArray[np.int64]
    s: NDArray[np.complex128]
    d: NDArray[np.complex128]
    w: NDArray[np.complex128]
    flat_window: bool

    def matrix(self, r: int = 0) -> NDArray[np.complex128]:
        """The dense B̃ of point r: ``S_pp W_{p−q} + D_p D_q*``, shape (N, N)."""
        p = self.orders
        n = p.size
        s = self.s[min(r, self.s.shape[0] - 1)]
        d = self.d[min(r, self.d.shape[0] - 1)]
        wk = self.w[np.mod(p[:, None] - p[None, :], n)]
        return s[:, None] * wk + np.outer(d, d.conj())


def separable_spectra(
    brdf: FlatlandBRDF | SpatiallyVaryingBRDF,
    domain_rad: tuple[float, float],
    n: int,
    *,
    points_mm: ArrayLike | None = None,
    normal_angle_rad: ArrayLike = 0.0,
    oversample: int = 8,
) -> SeparableSpectra:
    """S_pp, D_p and W_k of the separable model by fine midpoint quadrature.

    Per-point quantities (shape (R, N)) appear for a spatially varying BRDF (scaled by its
    maps at ``points_mm``) or per-point normal angles Θ_r (D_p of ``f_diff(θ − Θ_r)``); the
    specular lobe depends on θ_m − θ_o only, so S_pp does not depend on Θ_r.
    """
    a, b = domain_rad
    width = b - a
    base = brdf.base if isinstance(brdf, SpatiallyVaryingBRDF) else brdf
    k = _fine_n(n, width, base.specular_width_rad, oversample)
    zeta = theta_grid((-width / 2, width / 2), k)  # one period centred on 0
    # on a centred grid ⟨f, φ_p⟩ uses θ − θ_c = ζ, so S_p = width · coefficient_p
    s = width * _resample_orders(coefficients(base.f_spec(zeta)), n)
    th = theta_grid(domain_rad, k)
    tn = np.atleast_1d(np.asarray(normal_angle_rad, dtype=float))
    fd = base.f_diff(th[None, :] - tn[:, None])  # (R_t, k)
    d = np.sqrt(width) * _resample_orders(coefficients(fd, axis=-1), n)
    w = _resample_orders(coefficients(base.f_wind(th)), n)
    s = s[None, :]
    if isinstance(brdf, SpatiallyVaryingBRDF):
        if points_mm is None:
            raise ValueError("a spatially varying BRDF needs points_mm")
        c = np.atleast_1d(np.asarray(points_mm, dtype=float))
        s = s * np.asarray(brdf.specular_scale(c), dtype=float)[:, None]
        d = d * np.sqrt(np.asarray(brdf.diffuse_scale(c), dtype=float))[:, None]
    # s is complex (Fourier coefficients); numpy's stubs lose the dtype through the scalings
    return SeparableSpectra(fourier_orders(n), s, d, w, base.window_exponent == 0)  # type: ignore[arg-type]


def brdf_fourier_matrix(
    brdf: BRDFCallable,
    domain_rad: tuple[float, float],
    n: int,
    *,
    weighted: bool = True,
    normal_angle_rad: float = 0.0,
    y_mm: float | None = None,
    oversample: int = 4,
    lobe_width_rad: float | None = None,
) -> NDArray[np.complex128]:
    """Dense B̃ (``weighted=True``, eq. 2-18) or B (eq. 2-13) of any BRDF, shape (N, N).

    The double integral over ``[a, b]²`` is the midpoint rule on a fine grid of
    ``K ≥ oversample·N`` points per axis (and ≥ 16 points per ``lobe_width_rad``), via one
    2-D FFT.  Indices are fftfreq orders: ``B[p_index, q_index]``.  No periodic
    approximation is made: the specular lobe is cut at the domain edges as in the scene.
    """
    a, b = domain_rad
    width = b - a
    k = _fine_n(n, width, lobe_width_rad, oversample)
    th = theta_grid(domain_rad, k)
    t_o = th[None, :] - normal_angle_rad  # axis 1: θ_o
    t_m = th[:, None] - normal_angle_rad  # axis 0: θ_m
    f = brdf(t_o, t_m, y_mm=y_mm) if y_mm is not None else brdf(t_o, t_m)
    f = np.broadcast_to(f, (k, k)).astype(float)
    if not weighted:
        f = f * np.clip(np.cos(t_o), 0.0, None)
    # C[p, q'] = ⟨⟨f, φ_p(θ_m) φ_q'(θ_o)⟩⟩ ; B̃_pq = width · C[p, −q]
    c = coefficients(coefficients(f, axis=0), axis=1)
    p = fourier_orders(n)
    return width * c[np.mod(p, k)[:, None], np.mod(-p, k)[None, :]]
