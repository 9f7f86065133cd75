"""Helmholtz reciprocity of the measured data: f(ωi, ωr) = f(ωr, ωi) where both were measured."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from analysis.brdf.reduction.values import BRDFPoints


@dataclass(frozen=True)
class ReciprocityCheck:
    """Pairs of points measured both ways, (ωi, ωr) and (ωr, ωi).

    Attributes
    ----------
    pairs : ndarray of int, shape (m, 2)
    ratio : ndarray, shape (m,)
        f(a)/f(b).
    z : ndarray, shape (m,)
        (f(a) − f(b)) / √(u_a² + u_b²): Helmholtz reciprocity predicts |z| ≲ 2.
    """

    pairs: NDArray[np.int64]
    ratio: NDArray[np.float64]
    z: NDArray[np.float64]

    @property
    def n_pairs(self) -> int:
        return int(self.pairs.shape[0])

    @property
    def fraction_within_2sigma(self) -> float:
        return float(np.mean(np.abs(self.z) <= 2.0)) if self.z.size else float("nan")


def reciprocity_check(
    points: BRDFPoints, *, tol_rad: float = 1e-3, isotropic: bool = True
) -> ReciprocityCheck:
    """Find points whose source and detector directions are exchanged and compare them.

    Helmholtz reciprocity f(ωi→ωr) = f(ωr→ωi) (Nicodemus et al. 1977) holds for the BRDF f, so
    cosine-corrected values are converted first. With ``isotropic`` (f depends on φr − φi
    only) a pair needs θi(a) = θr(b), θr(a) = θi(b) and equal cos(φr − φi);
    otherwise the direction vectors themselves must be exchanged. Angles match within
    ``tol_rad``.
    """
    f, u = points.plain_brdf()
    if isotropic:
        key_a = np.stack([points.theta_i, points.theta_r,
                          np.cos(points.phi_r - points.phi_i)], -1)
        key_b = np.stack([points.theta_r, points.theta_i,
                          np.cos(points.phi_r - points.phi_i)], -1)
    else:
        def vec(t: NDArray[Any], p: NDArray[Any]) -> NDArray[Any]:
            return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)

        wi = vec(points.theta_i, points.phi_i)
        wr = vec(points.theta_r, points.phi_r)
        key_a = np.concatenate([wi, wr], -1)
        key_b = np.concatenate([wr, wi], -1)
    swapped = np.max(np.abs(key_a[:, None, :] - key_b[None, :, :]), axis=-1) < tol_rad
    same = np.max(np.abs(key_a[:, None, :] - key_a[None, :, :]), axis=-1) < tol_rad
    match = swapped & ~same  # a point on the diagonal θi = θr is its own reciprocal
    a, b = np.nonzero(np.triu(match, k=1))
    pairs = np.stack([a, b], axis=-1).astype(np.int64).reshape(-1, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = f[a] / f[b]
        z = (f[a] - f[b]) / np.hypot(u[a], u[b])
    return ReciprocityCheck(pairs, ratio, z)

