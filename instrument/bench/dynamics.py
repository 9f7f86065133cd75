"""Move-time model for planning: trapezoidal velocity profiles, simultaneous axes.

A point-to-point move of distance d with maximum velocity v and acceleration a (symmetric
acceleration and deceleration, starting and ending at rest) takes

    t = d/v + v/a          if d ≥ v²/a   (reaches v: accelerate, cruise, decelerate)
    t = 2·sqrt(d/a)        otherwise    (triangular profile, peak velocity sqrt(a·d))

(any motion-control text; it is the profile the APT and SMC100 controllers run). Axes of a
step start together, so a step lasts as long as its slowest axis. This module is the
planner's own model and deliberately independent of the emulators in ``hw_mocks``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from instrument.bench.profile import BenchProfile

__all__ = ["DEFAULT_DYNAMICS", "AxisDynamics", "dynamics_of", "move_progress", "move_time",
           "move_times", "moves_progress", "route_time", "step_time"]


@dataclass(frozen=True)
class AxisDynamics:
    """Velocity (units/s), acceleration (units/s²) and a per-move settle/overhead time (s)."""

    velocity: float
    acceleration: float
    settle_s: float = 0.0

    def __post_init__(self) -> None:
        if not (self.velocity > 0 and self.acceleration > 0 and self.settle_s >= 0):
            raise ValueError(f"need velocity, acceleration > 0 and settle_s >= 0: {self}")


#: Used for planning when a profile gives no velocity/acceleration for an axis.
DEFAULT_DYNAMICS = AxisDynamics(velocity=10.0, acceleration=10.0)


def dynamics_of(profile: BenchProfile, axes: Iterable[str]) -> dict[str, AxisDynamics]:
    """Each axis's dynamics from its profile entry (:data:`DEFAULT_DYNAMICS` where the
    profile gives no velocity or acceleration)."""
    out = {}
    for r in axes:
        spec = profile.devices.get(r)
        if spec is None or spec.velocity is None or spec.acceleration is None:
            out[r] = DEFAULT_DYNAMICS
        else:
            out[r] = AxisDynamics(spec.velocity, spec.acceleration, spec.settle_s)
    return out


def move_progress(distance: float, dyn: AxisDynamics, t: np.ndarray) -> np.ndarray:
    """Signed distance covered ``t`` seconds (array) after the start of one trapezoidal
    move of ``distance`` (the profile of the module docstring; the settle time comes after
    arrival and moves nothing)."""
    t = np.asarray(t, dtype=float)
    return moves_progress(np.full(t.shape, float(distance)), dyn, t)


def moves_progress(distance: np.ndarray, dyn: AxisDynamics, t: np.ndarray) -> np.ndarray:
    """:func:`move_progress` of many moves at once: ``distance`` and ``t`` broadcast
    together (each element the distance covered by its move at its time)."""
    dist = np.asarray(distance, dtype=float)
    t = np.asarray(t, dtype=float)
    d = np.abs(dist)
    v0, a = dyn.velocity, dyn.acceleration
    full = d >= v0 * v0 / a                       # reaches its top speed
    ta = np.where(full, v0 / a, np.sqrt(d / a))
    total = np.where(full, d / v0 + v0 / a, 2.0 * ta)
    v = np.where(full, v0, a * ta)
    rise = 0.5 * a * np.minimum(t, ta) ** 2
    cruise = v * np.clip(t - ta, 0.0, np.maximum(total - 2.0 * ta, 0.0))
    fall_t = np.clip(t - (total - ta), 0.0, ta)
    fall = v * fall_t - 0.5 * a * fall_t ** 2
    covered: np.ndarray = np.sign(dist) * np.minimum(rise + cruise + fall, d)
    return covered


def move_time(distance: float, dyn: AxisDynamics) -> float:
    """Seconds for one trapezoidal move of ``|distance|``; 0 for no move."""
    d = abs(float(distance))
    if d == 0.0:
        return 0.0
    v, a = dyn.velocity, dyn.acceleration
    if d >= v * v / a:
        return d / v + v / a + dyn.settle_s
    return 2.0 * math.sqrt(d / a) + dyn.settle_s


def move_times(distance: np.ndarray, dyn: AxisDynamics) -> np.ndarray:
    """Vectorised :func:`move_time` for an array of distances (any shape)."""
    d = np.abs(np.asarray(distance, dtype=float))
    v, a = dyn.velocity, dyn.acceleration
    t = np.where(d >= v * v / a, d / v + v / a, 2.0 * np.sqrt(d / a))
    return np.where(d > 0, t + dyn.settle_s, 0.0)


def step_time(a: Mapping[str, float], b: Mapping[str, float],
              dynamics: Mapping[str, AxisDynamics]) -> float:
    """Seconds from positions ``a`` to ``b`` with all axes started together."""
    times = [move_time(b[r] - a.get(r, b[r]), dynamics[r]) for r in b if r in dynamics]
    return max(times, default=0.0)


def route_time(targets: np.ndarray, axes: Sequence[str], dynamics: Mapping[str, AxisDynamics],
               *, start: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """Total motion time of visiting the rows of ``targets`` (shape (N, A)) in order.

    Returns the total seconds and the per-step times, shape (N,) (step k ends at point k;
    step 0 starts at ``start`` or costs nothing without one).
    """
    t = np.asarray(targets, dtype=float)
    if t.size == 0:
        return 0.0, np.zeros(0)
    prev = np.vstack([t[:1] if start is None else np.asarray(start, float)[None, :], t[:-1]])
    per_axis = np.stack([move_times(t[:, k] - prev[:, k], dynamics[r])
                         for k, r in enumerate(axes)], axis=1)
    steps = per_axis.max(axis=1)
    return float(steps.sum()), steps
