"""The guard's rules for a type (i) goniometer, and collision-free paths between poses.

Geometry (ADR 0099): each arm's head (the source, or the detector with its aperture, on
its carriage) sits at its radius r from the sample centre, ``width_mm`` w wide across the
arc, so seen from the sample it is a disc of angular half-width α = atan(w/2 / r). With δ
the angle between the two heads' directions (the bistatic angle 2β) a pose is refused by

``arms``
    the heads touch: δ < α_s + α_d. Conservative: a head on the outer arc that could pass
    behind the inner one is still refused, since its carriage would meet the inner rail.
``beam`` (light on, detector arm inside the source arm, r_d < r_s)
    the detector head shadows the incident beam: it lies in front of the sample
    (cos δ > 0) at a distance r_d·sin δ from the beam axis smaller than w_d/2 + b, with b
    the beam's radius (``geometry.beam_radius_mm``, 0 if not declared).
``view`` (light on, source arm inside the detector arm, r_s < r_d)
    the source head is in the detector's field of view: its distance r_s·sin δ from the
    line of sight is smaller than w_s/2 + h, h = (a/2)·r_s/r_d + (r_d − r_s)·tan(γ/2) the
    half-width of the detector's view cone at r_s (aperture a, view angle γ =
    ``field_of_view_deg``; γ = 0: the cone from the aperture to the sample centre).

Paths. The engine starts a move's axes together and each runs its own trapezoidal
profile (:mod:`instrument.bench.dynamics`), so the path of a move is the timed one, not a
straight line in joint space. :func:`path_clear` samples it at steps short enough that
the heads move by at most ε between samples (the sum of the axes' top speeds × the
step), and asks for δ ≥ α_s + α_d + ε/2 at every sample: in between, every pose is within
ε/2 of a sample, so the heads cannot touch there. :func:`safe_route` finds a sequence of
such moves when the direct one is not clear: the arms one after the other (either
first), then detours that turn one arm's azimuth aside, move its arc, and turn it back,
or move its arc aside (over or under the other head), turn its azimuth, and move the arc
back.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from instrument.bench.dynamics import (
    AxisDynamics,
    move_progress,
    move_time,
    move_times,
    moves_progress,
    step_time,
)
from instrument.bench.kinematics import TYPE_I_AXES, TypeIKinematics, kinematics_of
from instrument.bench.profile import ArmSpec, GeometrySpec

__all__ = ["ARM_RULES", "BOUND_SEGMENTS", "PathCheck", "Route", "arm_violations", "path_bounds",
           "path_clear", "safe_route", "sample_step_deg", "separation_deg"]

#: The rules a type (i) pose can break near the source direction (a plan's
#: ``skip_beam_points`` drops such points, as it drops the type (ii) beam cone).
ARM_RULES = ("arms", "beam", "view")
#: Largest head movement (degrees) between two samples of a path; smaller when the arms
#: are narrow (a quarter of the narrower head's half-width).
MAX_STEP_DEG = 0.5
#: Stretches of a path :func:`path_bounds` bounds before :func:`path_clear` samples it.
BOUND_SEGMENTS = 64
#: Azimuth detours :func:`safe_route` tries (degrees aside, either way).
DETOURS_DEG = (20.0, 45.0, 90.0)

_SOURCE = ("source_arc", "source_azimuth")
_DETECTOR = ("detector_arc", "detector_azimuth")


def _arms(geometry: GeometrySpec) -> tuple[ArmSpec, ArmSpec]:
    if geometry.source_arm is None or geometry.detector_arm is None:
        raise ValueError("a type (i) geometry needs geometry.source_arm and "
                         "geometry.detector_arm")
    return geometry.source_arm, geometry.detector_arm


def separation_deg(kin: TypeIKinematics, poses: Mapping[str, np.ndarray]) -> np.ndarray:
    """δ (degrees) between the heads at each of the poses (arrays by role, same shape)."""
    def dirs(arm: str) -> np.ndarray:
        a = np.radians(np.asarray(poses[f"{arm}_arc"], float) - kin.offsets[f"{arm}_arc"])
        p = np.radians(np.asarray(poses[f"{arm}_azimuth"], float)
                       - kin.offsets[f"{arm}_azimuth"])
        return np.stack([np.sin(a) * np.cos(p), np.sin(a) * np.sin(p), np.cos(a)], axis=-1)

    s, d = dirs("source"), dirs("detector")
    cross = np.linalg.norm(np.cross(s, d), axis=-1)
    delta: np.ndarray = np.degrees(np.arctan2(cross, np.sum(s * d, axis=-1)))
    return delta


def arm_violations(geometry: GeometrySpec, pose: Mapping[str, float], *, light: bool
                   ) -> list[tuple[str, str]]:
    """(rule, why) of every rule of the module docstring the pose breaks."""
    src, det = _arms(geometry)
    kin = kinematics_of(geometry)
    assert isinstance(kin, TypeIKinematics)
    delta = float(separation_deg(kin, {r: np.asarray(pose[r]) for r in TYPE_I_AXES}))
    out = []
    touch = src.half_width_deg + det.half_width_deg
    if delta < touch:
        out.append(("arms", f"source and detector arms collide: {delta:.3g} deg apart < "
                            f"{touch:.3g} deg (heads {src.width_mm:g} mm at {src.radius_mm:g} "
                            f"mm and {det.width_mm:g} mm at {det.radius_mm:g} mm)"))
    if not light or math.cos(math.radians(delta)) <= 0:
        return out
    off = math.sin(math.radians(delta))
    if det.radius_mm < src.radius_mm:
        clear = det.width_mm / 2 + (geometry.beam_radius_mm or 0.0)
        if det.radius_mm * off < clear:
            out.append(("beam", f"detector arm shadows the incident beam: its head is "
                                f"{det.radius_mm * off:.3g} mm from the beam axis < {clear:.3g}"
                                " mm (half its width and the beam radius)"))
    elif src.radius_mm < det.radius_mm:
        half = (geometry.detector_aperture_mm / 2 * src.radius_mm / det.radius_mm
                + (det.radius_mm - src.radius_mm)
                * math.tan(math.radians(det.field_of_view_deg / 2)))
        clear = src.width_mm / 2 + half
        if src.radius_mm * off < clear:
            out.append(("view", f"source arm in the detector's field of view: its head is "
                                f"{src.radius_mm * off:.3g} mm from the line of sight < "
                                f"{clear:.3g} mm"))
    return out


def sample_step_deg(geometry: GeometrySpec) -> float:
    """ε of the module docstring: the largest head movement between two samples of a
    path (:data:`MAX_STEP_DEG`, or a quarter of the narrower head's half-width)."""
    src, det = _arms(geometry)
    return min(MAX_STEP_DEG, min(src.half_width_deg, det.half_width_deg) / 4)


def path_bounds(geometry: GeometrySpec, here: np.ndarray, there: np.ndarray,
                dynamics: Mapping[str, AxisDynamics] | None = None, *,
                segments: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Which moves ``here[k]`` → ``there[k]`` (arm axes in ``TYPE_I_AXES`` order,
    shape (K, 4)) :func:`path_clear` would find clear, and which it would find blocked,
    each proven without its fine sampling (neither: sample the path).

    δ is 1-Lipschitz in each head's direction, and a head whose arc turns by Δa and
    azimuth by Δϕ (each monotonic) travels at most |Δa| + |Δϕ| on the sphere (its speed²
    is ȧ² + sin²a ϕ̇²). Over a stretch of the path from pose A to pose B, with L the two
    heads' bound and s the part travelled, δ ≥ max(δ_A − s, δ_B − (L − s)) ≥
    (δ_A + δ_B − L)/2. The timed path (``dynamics``) is cut into ``segments`` stretches
    of equal time (without ``dynamics``: one, the whole move); at or above the sampled
    check's threshold α_s + α_d + ε/2 on every stretch, every sample passes it. Blocked:
    a pose of the path with δ below the threshold less ε/2; the fine sampling has a
    sample within ε/2 of head travel of it, below the threshold."""
    src, det = _arms(geometry)
    kin = kinematics_of(geometry)
    assert isinstance(kin, TypeIKinematics)
    a, b = np.asarray(here, float), np.asarray(there, float)
    if dynamics is None or segments <= 1:
        poses = np.stack([a, b], axis=1)                        # (K, 2, 4)
    else:
        dist = b - a
        ends = np.stack([move_times(dist[:, k], dynamics[r])
                         - np.where(dist[:, k] != 0, dynamics[r].settle_s, 0.0)
                         for k, r in enumerate(TYPE_I_AXES)], axis=1).max(axis=1)
        t = ends[:, None] * np.linspace(0.0, 1.0, segments + 1)[None, :]
        poses = np.stack([a[:, None, k] + moves_progress(dist[:, None, k], dynamics[r], t)
                          for k, r in enumerate(TYPE_I_AXES)], axis=-1)
    delta = separation_deg(kin, {r: poses[..., k] for k, r in enumerate(TYPE_I_AXES)})
    travel = np.abs(np.diff(poses, axis=1)).sum(axis=2)        # (K, segments)
    need = src.half_width_deg + det.half_width_deg + sample_step_deg(geometry) / 2
    clear: np.ndarray = np.all((delta[:, :-1] + delta[:, 1:] - travel) / 2 >= need, axis=1)
    blocked: np.ndarray = np.any(delta < need - sample_step_deg(geometry) / 2, axis=1)
    return clear, blocked


@dataclass(frozen=True)
class PathCheck:
    """A move's timed path: whether it keeps the heads apart, and its closest approach."""

    clear: bool
    closest_deg: float
    seconds: float


def path_clear(geometry: GeometrySpec, dynamics: Mapping[str, AxisDynamics],
               here: Mapping[str, float], there: Mapping[str, float]) -> PathCheck:
    """Whether the move ``here`` → ``there`` (the arm axes, started together) keeps the
    heads apart all the way (module docstring: sampling with the ε/2 margin)."""
    src, det = _arms(geometry)
    kin = kinematics_of(geometry)
    assert isinstance(kin, TypeIKinematics)
    dist = {r: float(there[r]) - float(here[r]) for r in TYPE_I_AXES}
    seconds = max(move_time(d, dynamics[r]) - dynamics[r].settle_s if d else 0.0
                  for r, d in dist.items())
    eps = sample_step_deg(geometry)
    speed = sum(dynamics[r].velocity for r, d in dist.items() if d)
    n = max(2, math.ceil(seconds * speed / eps) + 1) if seconds > 0 else 1
    t = np.linspace(0.0, seconds, n)
    poses = {r: float(here[r]) + move_progress(dist[r], dynamics[r], t) for r in TYPE_I_AXES}
    delta = separation_deg(kin, poses)
    closest = float(delta.min())
    need = src.half_width_deg + det.half_width_deg + (eps / 2 if n > 1 else 0.0)
    return PathCheck(closest >= need, closest, seconds)


@dataclass(frozen=True)
class Route:
    """The moves that take the arms from one pose to another without touching: each a full
    set of arm-axis targets, run one after the other (the last is the destination)."""

    moves: tuple[dict[str, float], ...]
    how: str

    @property
    def split(self) -> bool:
        return len(self.moves) > 1

    def seconds(self, here: Mapping[str, float],
                dynamics: Mapping[str, AxisDynamics]) -> float:
        """Motion time from ``here``: each leg's slowest axis, the legs one after the
        other (:func:`instrument.bench.dynamics.step_time`)."""
        total, at = 0.0, dict(here)
        for leg in self.moves:
            total += step_time(at, leg, dynamics)
            at = leg
        return total


def _within(pose: Mapping[str, float],
            limits: Mapping[str, tuple[float, float] | None]) -> bool:
    for r, v in pose.items():
        lim = limits.get(r)
        if lim is not None and not lim[0] - 1e-9 <= v <= lim[1] + 1e-9:
            return False
    return True


def _candidates(here: dict[str, float], there: dict[str, float]
                ) -> list[tuple[str, list[dict[str, float]]]]:
    """Sequences of waypoints to try, simplest first (module docstring)."""
    def with_(base: dict[str, float], **roles: float) -> dict[str, float]:
        return {**base, **roles}

    def arm_at(base: dict[str, float], axes: Sequence[str], src: dict[str, float]
               ) -> dict[str, float]:
        return {**base, **{r: src[r] for r in axes}}

    out: list[tuple[str, list[dict[str, float]]]] = [("both arms together", [there])]
    for first, axes in (("source", _SOURCE), ("detector", _DETECTOR)):
        out.append((f"{first} arm first", [arm_at(here, axes, there), there]))
    for mover, (arc, az), other in (("detector", _DETECTOR, _SOURCE),
                                    ("source", _SOURCE, _DETECTOR)):
        # (the axis set aside, where to, the other axis of the arm, in words)
        asides = [(az, base + sign * d, arc, f"{mover} arm around: azimuth {{:+.4g}} (aside "
                   f"of {name}), arc, azimuth back")
                  for name, base in (("here", here[az]), ("there", there[az]))
                  for d in DETOURS_DEG for sign in (1.0, -1.0)]
        asides += [(arc, here[arc] + sign * d, az, f"{mover} arm over the other: arc "
                    "{:+.4g}, azimuth, arc back")
                   for d in DETOURS_DEG for sign in (1.0, -1.0)]
        for aside_axis, value, then_axis, words in asides:
            for other_first in (True, False):
                start = arm_at(here, other, there) if other_first else dict(here)
                w1 = with_(start, **{aside_axis: value})
                w2 = with_(w1, **{then_axis: there[then_axis]})
                w3 = with_(w2, **{aside_axis: there[aside_axis]})
                how = words.format(value) + ("; other arm first" if other_first
                                             else "; other arm last")
                out.append((how, [w1, w2, w3, there]))
    return out


def safe_route(geometry: GeometrySpec, dynamics: Mapping[str, AxisDynamics],
               here: Mapping[str, float], there: Mapping[str, float], *,
               limits: Mapping[str, tuple[float, float] | None] | None = None
               ) -> Route | None:
    """The first collision-free :class:`Route` ``here`` → ``there`` (arm axes by role;
    every waypoint inside ``limits``), or None when none of the tried routes is clear."""
    h = {r: float(here[r]) for r in TYPE_I_AXES}
    t = {r: float(there[r]) for r in TYPE_I_AXES}
    checked: dict[tuple[float, ...], bool] = {}  # candidates share legs

    def clear(a: dict[str, float], b: dict[str, float]) -> bool:
        key = tuple(a[r] for r in TYPE_I_AXES) + tuple(b[r] for r in TYPE_I_AXES)
        if key not in checked:
            # the bound proves most legs clear without sampling their path
            clear_, blocked = path_bounds(geometry, np.array([key[:4]]),
                                          np.array([key[4:]]), dynamics,
                                          segments=BOUND_SEGMENTS)
            checked[key] = bool(clear_[0] or (not blocked[0]
                                              and path_clear(geometry, dynamics, a, b).clear))
        return checked[key]

    for how, waypoints in _candidates(h, t):
        if limits is not None and not all(_within(w, limits) for w in waypoints):
            continue
        moves: list[dict[str, float]] = []
        at = h
        ok = True
        for w in waypoints:
            if w == at:
                continue
            if not clear(at, w):
                ok = False
                break
            moves.append(w)
            at = w
        if ok:
            return Route(tuple(moves) or (t,), how)
    return None
