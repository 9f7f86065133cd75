"""The guard: every point of a plan is checked before anything moves.

A point is rejected when

* an axis target lies outside the profile's soft limits (or the bench lacks the axis);
* the detector would sit in, or shadow, the incident beam: the bistatic angle
  |detector_theta| (the angle between source and detector directions, see
  :mod:`instrument.bench.kinematics`) is below the geometry's ``min_bistatic_deg``
  (a detector cannot sit in the incident beam: no exact backscatter);
* a direction leaves the upper hemisphere (θi or θr ≥ 90°: the beam or the detector would
  look at the sample from behind);
* an axis (or a difference of two axes) lies in one of the profile's arm-collision zones;
* on a type (i) goniometer (``geometry.goniometer = "type_i"``), the rules of
  :mod:`instrument.bench.arms`: the arms' heads touch (``arms``), the detector arm shadows
  the incident beam (``beam``) or the source arm stands in the detector's field of view
  (``view``); the last two only with the light on. A move between two allowed poses that
  would make the arms touch on the way is refused as ``path`` (:func:`check_route`).

:func:`check` returns every violation; :func:`enforce` raises :class:`GuardError` whose
message lists each offending point and why.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

from instrument.bench import arms
from instrument.bench.dynamics import AxisDynamics
from instrument.bench.kinematics import TYPE_I_AXES, Angles, wrap180
from instrument.bench.profile import BenchProfile

__all__ = ["NEAR_SOURCE", "GuardError", "GuardedPoint", "Violation", "check", "check_route",
           "enforce"]

#: Reasons that mean "the detector is too near the source direction": what a plan's
#: ``skip_beam_points`` drops (type ii: ``beam``; type i: also the arms' rules).
NEAR_SOURCE = ("beam", *arms.ARM_RULES)


class GuardedPoint(Protocol):
    """What the guard reads of a point: a plan's :class:`instrument.plans.commands.ScanPoint`
    or an operator's manual move (both frozen: the guard only reads them, so the members
    are read-only properties here)."""

    @property
    def index(self) -> int: ...

    @property
    def angles(self) -> Angles | None: ...

    @property
    def light(self) -> bool: ...

    def target_dict(self) -> dict[str, float]: ...

    def describe(self) -> str: ...

#: How many violations the error message spells out before summarising the rest.
MAX_LISTED = 40


@dataclass(frozen=True)
class Violation:
    index: int
    # "limits" | "missing_axis" | "beam" | "hemisphere" | "collision"; type (i) also
    # "arms" | "view" | "path"
    reason: str
    detail: str
    point: str = ""  # the point's own description (angles, targets)

    def __str__(self) -> str:
        where = f" ({self.point})" if self.point else ""
        return f"point {self.index}{where}: {self.detail}"


class GuardError(ValueError):
    """Points of a plan that must not be run; ``violations`` lists them all."""

    def __init__(self, violations: list[Violation], n_points: int) -> None:
        self.violations = list(violations)
        bad = sorted({v.index for v in violations})
        lines = [f"  - {v}" for v in violations[:MAX_LISTED]]
        if len(violations) > MAX_LISTED:
            lines.append(f"  ... and {len(violations) - MAX_LISTED} more")
        if n_points > 1 and len(bad) == n_points:
            lines.append("  every point is rejected: is the bench (--bench) the one this "
                         "plan is written for?")
        super().__init__(
            f"{len(bad)} of {n_points} point(s) rejected before any motion:\n"
            + "\n".join(lines)
        )


def check(points: Iterable[GuardedPoint], profile: BenchProfile) -> list[Violation]:
    """All violations of ``points`` on the bench ``profile``, in point order."""
    geometry = profile.geometry
    out: list[Violation] = []
    for p in points:
        first = len(out)
        targets = p.target_dict()
        for role, value in targets.items():
            spec = profile.devices.get(role)
            if spec is None or not spec.is_axis:
                out.append(Violation(p.index, "missing_axis",
                                     f"bench {profile.name!r} has no axis {role!r}"))
                continue
            if not math.isfinite(value):
                out.append(Violation(p.index, "limits", f"{role} target {value} not finite"))
            elif spec.limits is not None and not spec.limits[0] <= value <= spec.limits[1]:
                out.append(Violation(
                    p.index, "limits", f"{role} = {value:.4g} outside the soft limits "
                    f"[{spec.limits[0]:g}, {spec.limits[1]:g}]"))
        if p.angles is not None and "detector_theta" in targets and p.light:
            bistatic = abs(wrap180(targets["detector_theta"]))
            if bistatic < geometry.min_bistatic_deg:
                out.append(Violation(
                    p.index, "beam", f"detector in or shadowing the incident beam: bistatic "
                    f"angle {bistatic:.3g} deg < {geometry.min_bistatic_deg:g} deg"))
        if p.angles is not None:
            for name, theta in (("theta_i", p.angles.theta_i), ("theta_r", p.angles.theta_r)):
                if not theta < 90.0:
                    out.append(Violation(
                        p.index, "hemisphere",
                        f"{name} = {theta:.4g} deg is not above the sample surface (< 90)"))
        if geometry.is_type_i and all(r in targets for r in TYPE_I_AXES):
            for reason, detail in arms.arm_violations(geometry, targets, light=p.light):
                out.append(Violation(p.index, reason, detail))
        for zone in geometry.collisions:
            if zone.hit(targets):
                out.append(Violation(p.index, "collision",
                                     f"arm-collision zone: {zone.describe()}"))
        if len(out) > first:
            desc = p.describe()
            out[first:] = [Violation(v.index, v.reason, v.detail, desc) for v in out[first:]]
    return out


def check_route(points: Sequence[GuardedPoint], profile: BenchProfile,
                dynamics: dict[str, AxisDynamics], *,
                start: dict[str, float] | None = None) -> list[Violation]:
    """``path`` violations of running ``points`` in this order on a type (i) bench: a move
    into a point (from ``start``, or from the previous point) for which
    :func:`instrument.bench.arms.safe_route` finds no collision-free route. Empty for a
    type (ii) bench."""
    if not profile.geometry.is_type_i:
        return []
    limits = {r: d.limits for r, d in profile.axes.items()}
    out = []
    here = dict(start) if start and all(r in start for r in TYPE_I_AXES) else None
    for p in points:
        there = p.target_dict()
        if not all(r in there for r in TYPE_I_AXES):
            continue
        if here is not None and arms.safe_route(profile.geometry, dynamics, here, there,
                                                limits=limits) is None:
            out.append(Violation(p.index, "path", "no collision-free route for the arms from "
                                 + ", ".join(f"{r}={here[r]:.4g}" for r in TYPE_I_AXES)
                                 + ": every tried order and detour makes them touch",
                                 p.describe()))
        here = there
    return out


def enforce(points: Sequence[GuardedPoint], profile: BenchProfile) -> None:
    """Raise :class:`GuardError` if any point of ``points`` violates the bench."""
    violations = check(points, profile)
    if violations:
        raise GuardError(violations, len(points))
