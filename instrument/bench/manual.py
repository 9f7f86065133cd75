"""Manual moves (an operator's jog, an absolute target, a home) through the plan's guard.

A manual move is judged like a plan point: :func:`instrument.bench.guard.check` sees the
*pose the bench will have after the move* — the moved axes at their targets, every other
homed axis where it stands now — with the scattering angles the kinematics give for that
pose, so the soft limits, the minimum bistatic cone (detector in the beam), the upper
hemisphere and the arm-collision zones of the profile apply exactly as they do to a
scan. An unhomed axis is left out of the pose: its counter is not a physical position.

A home is judged as a move to the axis's reference (0): homing the detector arm swings
it into the beam, so with the light on it is refused like any move there. Turning the
light on is judged as a point at the present pose with the light on (the detector
parked in the beam is refused before the beam reaches it).

Only end poses are judged, as for a plan, except on a type (i) goniometer, where the arms
can meet on the way: there the move's own path (its axes started together, as the bench
runs them) must keep the arms apart too (:func:`instrument.bench.arms.path_clear`), else
the move is refused as ``path`` before anything moves; the remedy is to move one arm
first, or around the other.

:func:`plan_manual_move` returns the :class:`ManualMove` or raises :class:`MoveRefused`,
whose message lists every reason, in the guard's words. Nothing here talks to a device:
the caller reads the positions, asks, and only then moves.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from instrument.bench import guard
from instrument.bench.arms import path_clear
from instrument.bench.dynamics import dynamics_of
from instrument.bench.kinematics import TYPE_I_AXES, Angles, kinematics_of
from instrument.bench.profile import BenchProfile

__all__ = [
    "HOME_POSITION",
    "ManualMove",
    "MoveRefused",
    "check_light_on",
    "manual_move",
    "plan_home",
    "plan_manual_move",
]

#: Where a homed axis stands right after homing (its reference), in axis units.
HOME_POSITION = 0.0


@dataclass(frozen=True)
class ManualMove:
    """The bench pose after an operator's move, in the form the guard reads
    (:class:`instrument.bench.guard.GuardedPoint`).

    ``targets`` is the whole known pose after the move (axis units, by role); ``moved``
    names the axes the operator commands.
    """

    targets: tuple[tuple[str, float], ...]
    moved: tuple[str, ...]
    angles: Angles | None
    light: bool
    index: int = 0
    what: str = "move"

    def target_dict(self) -> dict[str, float]:
        return dict(self.targets)

    def moved_targets(self) -> dict[str, float]:
        """The commanded axes and their targets."""
        pose = self.target_dict()
        return {r: pose[r] for r in self.moved}

    def describe(self) -> str:
        shown = self.moved_targets() if self.moved else self.target_dict()
        parts = [f"{r}={v:.4g}" for r, v in shown.items()]
        if self.angles is not None:
            a = self.angles
            parts.append(f"(θi={a.theta_i:.4g} φi={a.phi_i:.4g} θr={a.theta_r:.4g} "
                         f"φr={a.phi_r:.4g})")
        return f"{self.what} " + " ".join(parts)


class MoveRefused(ValueError):
    """The guard refused a manual move; ``violations`` says why, nothing has moved."""

    def __init__(self, move: ManualMove, violations: list[guard.Violation]) -> None:
        self.move = move
        self.violations = list(violations)
        reasons = "; ".join(dict.fromkeys(v.detail for v in self.violations))
        super().__init__(f"{move.describe()} refused: {reasons}")


def manual_move(profile: BenchProfile, current: Mapping[str, float],
                targets: Mapping[str, float], *, light: bool, what: str = "move"
                ) -> ManualMove:
    """The pose after moving ``targets`` from ``current`` (positions of homed axes).

    Parameters
    ----------
    current
        Present positions, axis units, of the axes whose position is physical (homed).
    targets
        Commanded axes and their absolute targets, axis units.
    light
        Whether light reaches the sample (the beam check applies only then, as for a
        plan's dark points).
    """
    if not targets:
        raise ValueError("a manual move needs at least one axis target")
    pose = {r: float(v) for r, v in current.items()}
    for role, value in targets.items():
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f"{role}: target must be finite, got {value}")
        pose[role] = value
    geo = profile.geometry
    kin = kinematics_of(geo)
    angles = kin.angles(pose) if all(a in pose for a in kin.axes) else None
    return ManualMove(tuple(pose.items()), tuple(targets), angles, bool(light), what=what)


def plan_manual_move(profile: BenchProfile, current: Mapping[str, float],
                     targets: Mapping[str, float], *, light: bool) -> ManualMove:
    """:func:`manual_move`, guarded: returns it, or raises :class:`MoveRefused`."""
    move = manual_move(profile, current, targets, light=light)
    violations = guard.check([move], profile) + _path(profile, current, move)
    if violations:
        raise MoveRefused(move, violations)
    return move


def plan_home(profile: BenchProfile, current: Mapping[str, float], role: str, *,
              light: bool) -> ManualMove:
    """A home of ``role``, judged as a move to :data:`HOME_POSITION`; raises
    :class:`MoveRefused` when the bench may not stand there."""
    move = manual_move(profile, current, {role: HOME_POSITION}, light=light, what="home")
    violations = [v for v in guard.check([move], profile) + _path(profile, current, move)
                  if not (v.reason == "limits" and v.detail.startswith(f"{role} "))]
    # A reference outside the soft limits is the stage's business, not a reason to refuse
    # finding it: the limits apply to moves after homing.
    if violations:
        raise MoveRefused(move, violations)
    return move


def _path(profile: BenchProfile, current: Mapping[str, float], move: ManualMove
          ) -> list[guard.Violation]:
    """A type (i) move whose own path brings the arms together (module docstring)."""
    pose = move.target_dict()
    if not (profile.geometry.is_type_i and all(r in current for r in TYPE_I_AXES)
            and all(r in pose for r in TYPE_I_AXES)):
        return []
    check = path_clear(profile.geometry, dynamics_of(profile, TYPE_I_AXES), current, pose)
    if check.clear:
        return []
    return [guard.Violation(move.index, "path", "the arms would touch on the way (closest "
                            f"{check.closest_deg:.3g} deg apart): move one arm first, or "
                            "around the other", move.describe())]


def check_light_on(profile: BenchProfile, current: Mapping[str, float]) -> list[guard.Violation]:
    """Why light may not be turned on at the present pose (empty list: it may).

    Only the beam rule depends on the light: limits and collision zones are the business
    of the moves that led here.
    """
    if not current:
        return []
    geo = profile.geometry
    kin = kinematics_of(geo)
    angles = kin.angles(current) if all(a in current for a in kin.axes) else None
    point = ManualMove(tuple((r, float(v)) for r, v in current.items()), (), angles, True,
                       what="light on at")
    return [v for v in guard.check([point], profile) if v.reason == "beam"]
