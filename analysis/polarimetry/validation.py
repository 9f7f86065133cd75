"""Input checks shared by the public functions of :mod:`analysis.polarimetry`.

A NaN that reaches a least-squares reduction comes back as a NaN Mueller matrix, or worse
as a plausible one; a rank-deficient instrument matrix gives a "solution" whose missing
elements are arbitrary. Each public function checks its arguments on entry, and a bad one
raises :class:`PolarimetryInputError`, which names the argument and says what to do.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from analysis.errors import InputError

__all__ = ["PolarimetryInputError", "check_array", "check_covariance", "check_mueller"]


class PolarimetryInputError(InputError):
    """An argument of a polarimetry function is non-finite, mis-shaped or out of domain
    (``argument`` names it)."""


def check_array(name: str, value: Any, *, ndim: int | None = None,
                shape: tuple[int, ...] | None = None) -> NDArray[np.float64]:
    """``value`` as a finite float array, optionally of a given ``ndim`` or ``shape``.

    Raises
    ------
    PolarimetryInputError
        Not numeric, wrong dimensions/shape, or a NaN/inf entry (its index is given).
    """
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise PolarimetryInputError(name, f"must be a numeric array ({err})") from None
    if ndim is not None and arr.ndim != ndim:
        raise PolarimetryInputError(
            name, f"must have {ndim} dimension(s), got shape {arr.shape}")
    if shape is not None and arr.shape != shape:
        raise PolarimetryInputError(name, f"must have shape {shape}, got {arr.shape}")
    if arr.size and not np.all(np.isfinite(arr)):
        where = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise PolarimetryInputError(
            name, f"must be finite: entry {where} is {arr[where]!r}; mask or remove it first")
    return arr


def check_mueller(name: str, value: Any) -> NDArray[np.float64]:
    """A finite 4×4 Mueller matrix (a 16-vector in row-major order is accepted)."""
    arr = check_array(name, value)
    if arr.shape == (16,):
        arr = arr.reshape(4, 4)
    if arr.shape != (4, 4):
        raise PolarimetryInputError(
            name, f"must be a 4×4 Mueller matrix (or its 16 elements), got shape {arr.shape}")
    return arr


def check_covariance(name: str, value: Any, size: int = 16) -> NDArray[np.float64]:
    """A finite, symmetric ``size``×``size`` covariance with a non-negative diagonal."""
    arr = check_array(name, value, shape=(size, size))
    scale = max(float(np.max(np.abs(arr))), 1e-300)
    if not np.allclose(arr, arr.T, rtol=0.0, atol=1e-10 * scale):
        raise PolarimetryInputError(name, "must be symmetric")
    if np.any(np.diag(arr) < 0):
        raise PolarimetryInputError(name, "must have a non-negative diagonal (variances)")
    return arr
