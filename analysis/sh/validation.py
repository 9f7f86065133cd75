"""Input checks shared by every public function of :mod:`analysis.sh`.

A NaN or inf that reaches a least-squares fit, a Γ function or a Wiener gain comes back
as a scipy error about "residuals", as NaN coefficients, or — worst — as a plausible
number (a silently replaced noise level). Each public function therefore checks its
arguments on entry with the helpers here, and a bad one raises :class:`SHInputError`,
which names the argument and says what it must be.

Sphere images are the one deliberate exception: their non-finite pixels mark unusable
data (saturated, outside the HDR range) and are left out by design where documented
(:func:`analysis.sh.sphere_image.image_to_sh`, ``fit_scattered``'s default mask,
``albedo_ratio``); their geometry, weights and every other argument are checked.
"""

from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any

import numpy as np
from numpy.typing import DTypeLike

from analysis.errors import InputError

__all__ = [
    "SHInputError",
    "check_coefficients",
    "check_degree",
    "check_finite",
    "check_scalar",
]


class SHInputError(InputError):
    """An argument of a spherical-harmonic function is NaN, inf or outside its domain
    (``argument`` names it)."""


def check_finite(name: str, value: Any, *, dtype: DTypeLike = float,
                 ndim: int | None = None) -> np.ndarray:
    """``value`` as an array of ``dtype`` whose entries are all finite.

    Raises
    ------
    SHInputError
        Not convertible, wrong number of dimensions, or a NaN/inf entry (the first one's
        index is given).
    """
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as err:
        raise SHInputError(name, f"must be a numeric array ({err})") from None
    if ndim is not None and arr.ndim != ndim:
        raise SHInputError(name, f"must have {ndim} dimension(s), got shape {arr.shape}")
    if arr.size and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        where = tuple(int(i) for i in bad)
        raise SHInputError(
            name, f"must be finite: entry {where} is {arr[where]!r}; remove or mask it first")
    return arr


def check_coefficients(name: str, value: Any, *, dtype: DTypeLike = float,
                       ) -> tuple[np.ndarray, int]:
    """A finite coefficient array of shape ((L+1)², ...) and its band limit L."""
    arr = check_finite(name, value, dtype=dtype)
    if arr.ndim == 0:
        raise SHInputError(name, "must be an array of (L+1)² coefficients, got a scalar")
    size = arr.shape[0]
    lmax = math.isqrt(size) - 1
    if lmax < 0 or (lmax + 1) ** 2 != size:
        raise SHInputError(name, f"must hold (L+1)² coefficients along axis 0, got {size}")
    return arr, lmax


def check_degree(name: str, value: Any, *, minimum: int = 0) -> int:
    """An integer degree (band limit) ≥ ``minimum``; floats, bools and NaN are refused."""
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise SHInputError(name, f"must be an integer ≥ {minimum}, got {value!r}")
    if value < minimum:
        raise SHInputError(name, f"must be ≥ {minimum}, got {value}")
    return int(value)


def check_scalar(
    name: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """A finite real number inside [low, high] (``low_open``/``high_open``: excluded).

    Raises
    ------
    SHInputError
        Not a real number, NaN, ±inf, or outside the interval.
    """
    if isinstance(value, bool) or not isinstance(value, Real | np.floating | np.integer):
        raise SHInputError(name, f"must be a real number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise SHInputError(name, f"must be finite, got {x!r}")
    if low is not None and (x < low or (low_open and x == low)):
        raise SHInputError(name, f"must be {'>' if low_open else '≥'} {low:g}, got {x:g}")
    if high is not None and (x > high or (high_open and x == high)):
        raise SHInputError(name, f"must be {'<' if high_open else '≤'} {high:g}, got {x:g}")
    return x
