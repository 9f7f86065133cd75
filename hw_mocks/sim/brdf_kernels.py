"""Fused evaluation of the simulated sample's BRDF for one incident direction and many
outgoing ones: the simulated camera's pupil integral asks for f(ω_i, ω_r) along millions
of rays a view with ω_i fixed (the beam is collimated).

The registry's models (:mod:`analysis.brdf`) evaluate on a :class:`~analysis.brdf.geometry.
Geometry`, which builds the half vector, cos θ_h and the Smith terms as separate arrays —
about forty passes over the rays, several of them over ω_i's constant terms broadcast to
every ray. For the parts the sim benches use, the same formulas are written here with ω_i's
terms computed once and the rest in place (about twenty passes):

* ``lambert``: f = ρ/π;
* ``ggx`` (Cook–Torrance with the GGX distribution, height-correlated Smith visibility and
  F ≡ 1: :func:`analysis.brdf.specular.cook_torrance`): f = k_s D(h) V with
  D = α²/(π t²), t = cos²θ_h (α² − 1) + 1 (Walter et al., EGSR 2007, eq. 33) and
  V = ½ / (μ_r S_i + μ_i S_r), S = √(α² + (1 − α²) μ²) (Heitz, JCGT 3(2) 2014, eq. 99).
  With the unnormalised half vector v = ω_i + ω_r, cos²θ_h = v_z²/|v|², so
  D = (α²/π) (|v|² / (|v|² + (α² − 1) v_z²))² — no square root, no division by |v|.

Both parts depend on ω_i and ω_r only through μ_i, μ_r and ω_i · ω_r: the kernels are
the same in any frame turned about the sample normal (the scene passes beam-aligned
components). Nothing is approximated: the values equal the registry's to rounding
(tests/hw_mocks/test_brdf_kernels.py, against ``evaluate_geometry``: within 64 ε/α²
relative, the rounding of either form where D's denominator cancels near the peak —
3·10⁻¹³ at α = 0.2, far inside the pupil rule's 10⁻⁶), and :func:`fixed_incidence`
checks each kernel against the model it stands for before it is used.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

__all__ = ["SUPPORTED_PARTS", "fixed_incidence", "rounding_rtol"]

#: Registry parts with a fused kernel (base model name → number of parameters).
SUPPORTED_PARTS = {"lambert": 1, "ggx": 2}

Kernel = Callable[[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
                  NDArray[np.float64]]

#: The rounding error of either form, relative, in units of the float64 epsilon times the
#: cancellation's amplification: t = 1 − cos²θ_h (1 − α²) falls to α² at the peak, so
#: the ~10 roundings of each form grow by up to 1/α² in D ∝ 1/t² (2 × 32: a margin).
_ROUNDING_ULPS = 64.0


def rounding_rtol(alphas: Sequence[float]) -> float:
    """How far (relative) the kernels and the model may differ by rounding alone, for GGX
    widths ``alphas``: 64 ε / min(1, α²)."""
    smallest = min([1.0, *(a * a for a in alphas)])
    return _ROUNDING_ULPS * float(np.finfo(float).eps) / smallest


def _ggx_kernel(ks: float, alpha: float, omega_i: NDArray[np.float64]) -> Kernel:
    """k_s D V of the module docstring for ω_i (unit, μ_i floored as the model does)."""
    from analysis.brdf.geometry import MU_FLOOR

    xi, yi = float(omega_i[0]), float(omega_i[1])
    mi = max(float(omega_i[2]), MU_FLOOR)
    a2 = alpha * alpha
    s_i = math.sqrt(a2 + (1.0 - a2) * mi * mi)
    scale = ks * a2 / math.pi * 0.5  # k_s · α²/π · ½ (the ½ of V)

    def kernel(xr: NDArray, yr: NDArray, zr: NDArray) -> NDArray[np.float64]:
        mr = np.maximum(zr, MU_FLOOR)
        vz2 = mr + mi
        vz2 *= vz2
        n2 = xr + xi
        n2 *= n2
        tmp = yr + yi
        tmp *= tmp
        n2 += tmp
        n2 += vz2  # |v|²
        vz2 *= a2 - 1.0
        vz2 += n2  # |v|² t
        np.divide(n2, vz2, out=n2)
        n2 *= n2  # (1/t)² = π D / α²
        np.multiply(mr, mr, out=tmp)
        tmp *= 1.0 - a2
        tmp += a2
        np.sqrt(tmp, out=tmp)  # S_r
        tmp *= mi
        mr *= s_i
        tmp += mr  # μ_r S_i + μ_i S_r (≥ μ_r S_i > 0: the model's 10⁻³⁰⁰ floor never acts)
        np.divide(n2, tmp, out=n2)
        n2 *= scale
        return n2

    return kernel


def _sum_kernel(omega_i: NDArray[np.float64], parts: Sequence[tuple[str, NDArray]]
                ) -> Kernel:
    constant = sum(float(p[0]) / math.pi for name, p in parts if name == "lambert")
    lobes = [_ggx_kernel(float(p[0]), float(p[1]), omega_i)
             for name, p in parts if name == "ggx"]

    def kernel(xr: NDArray, yr: NDArray, zr: NDArray) -> NDArray[np.float64]:
        if not lobes:
            return np.full(np.shape(zr), constant)
        out = lobes[0](xr, yr, zr)
        for lobe in lobes[1:]:
            out += lobe(xr, yr, zr)
        if constant:
            out += constant
        return out

    return kernel


def _probe_directions() -> NDArray[np.float64]:
    """Outgoing unit directions over the upper hemisphere (grazing included), fixed."""
    rng = np.random.default_rng(0x6B1)
    z = np.concatenate([rng.uniform(0.0, 1.0, 60), [1.0, 1e-13, 1e-3, 0.5]])
    phi = rng.uniform(0.0, 2.0 * math.pi, z.size)
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def fixed_incidence(model, params: NDArray[np.float64]
                    ) -> Callable[[NDArray[np.float64]], Kernel] | None:
    """For a registry model (``analysis.brdf`` :class:`BRDFModel`) and its parameter
    vector: a function ω_i ↦ kernel(x_r, y_r, z_r) giving f with ω_r by its components
    (unit, in a frame whose z is the sample normal), or None when some part has no
    kernel here (the caller evaluates the model). Each kernel is checked against the
    model at 64 fixed directions when it is first made for an ω_i (kept for the
    16 latest)."""
    from analysis.brdf.geometry import geometry_from_vectors

    parts = getattr(model, "parts", None) or (model,)
    if any(SUPPORTED_PARTS.get(m.name) != m.n_params for m in parts):
        return None
    vector = np.asarray(params, dtype=float)
    split, i = [], 0
    for m in parts:
        split.append((m.name, vector[i:i + m.n_params]))
        i += m.n_params
    probe = _probe_directions()
    rtol = rounding_rtol([float(p[1]) for name, p in split if name == "ggx"])

    @lru_cache(maxsize=16)
    def checked(wi_components: tuple[float, float, float]) -> Kernel:
        wi = np.array(wi_components)
        kernel = _sum_kernel(wi, split)
        want = model.evaluate_geometry(vector, geometry_from_vectors(wi, probe))
        got = kernel(probe[:, 0].copy(), probe[:, 1].copy(), probe[:, 2].copy())
        if not np.allclose(got, want, rtol=rtol, atol=0.0):
            raise AssertionError(f"the fused {model.name} kernel departs from the model "
                                 f"(max rel. {np.max(np.abs(got / want - 1.0)):.2e})")
        return kernel

    def at(omega_i: NDArray[np.float64]) -> Kernel:
        x, y, z = (float(c) for c in omega_i)
        norm = math.sqrt(x * x + y * y + z * z)
        return checked((x / norm, y / norm, z / norm))

    return at
