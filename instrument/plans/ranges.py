"""The inclusive ranges ``{start, stop, step}`` of plan files, as lazy sequences.

A range of 10⁶ angles is valid in a plan file; as a list it would cost tens of MB before
anything checks what the plan multiplies it with, so validation, counting
(:mod:`instrument.plans.count`) and generation (:mod:`instrument.plans.build`) share this
lazy form and only the generator walks it.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import Any, overload

__all__ = ["FloatRange", "float_range"]


class FloatRange(Sequence[float]):
    """The inclusive range ``{start, stop, step}`` of a plan file, as a lazy sequence:
    ``start + k·step`` for ``k = 0 … n − 1`` with ``n = ⌊(stop − start)/step + 10⁻⁹⌋ + 1``
    (the 10⁻⁹ keeps a stop that the steps reach up to rounding)."""

    def __init__(self, start: float, stop: float, step: float) -> None:
        self.start, self.stop, self.step = float(start), float(stop), float(step)
        self._n = max(0, math.floor((self.stop - self.start) / self.step + 1e-9) + 1)

    def __len__(self) -> int:
        return self._n

    @overload
    def __getitem__(self, k: int) -> float: ...
    @overload
    def __getitem__(self, k: slice) -> list[float]: ...

    def __getitem__(self, k: int | slice) -> float | list[float]:
        if isinstance(k, slice):
            return [self[j] for j in range(*k.indices(self._n))]
        if k < 0:
            k += self._n
        if not 0 <= k < self._n:
            raise IndexError("FloatRange index out of range")
        return self.start + k * self.step

    def __iter__(self) -> Iterator[float]:
        return (self.start + k * self.step for k in range(self._n))


def float_range(x: dict[str, Any]) -> FloatRange:
    """A plan file's range table ``{start, stop, step}`` as a :class:`FloatRange`."""
    return FloatRange(float(x["start"]), float(x["stop"]), float(x["step"]))
