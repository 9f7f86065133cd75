"""The goniometer drawing as geometry, without Qt: what to draw where, from the positions.

Two pictures, both in millimetres or degrees of the bench's own conventions
(:mod:`instrument.bench.kinematics`, ADR 0012):

* :func:`top_view` — the bench seen from above (lab X, Y; +Z up, azimuths counter-clockwise
  from +X): the incident beam from the source to the sample, the sample surface and its
  normal, the detector arm, the forbidden zones (the minimum bistatic cone around the
  beam, the half-plane behind the sample, the profile's arm-collision zones as wedges of
  the arm's or the normal's azimuth) and the plan's detector positions, done and to do.
  It is the whole truth for an in-plane bench.
* :func:`arms_view` — a type (i) bench (ADR 0099) seen from above, the same projection
  as the hemisphere's: the stationary sample at the centre, each arm's rail (a diameter
  at its azimuth) and head, the zones the guard keeps the detector out of around the
  source head (the arms touching; the beam or the view), and the plan's detector
  directions. :func:`top_view` draws it for a type (i) bench.
* :func:`hemisphere_view` — for out-of-plane benches, the hemisphere above the sample in
  the azimuthal-equidistant projection of the coverage picture (radius ∝ θ, φ from x_s):
  incident and detector directions, the bistatic cone around the incident direction, and
  the plan's scattering directions, done and to do.

Axes a bench lacks are simply not drawn; positions of unhomed axes are not trusted and
the caller passes only homed ones.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from instrument.bench.arms import arm_violations
from instrument.bench.kinematics import Angles, TypeIKinematics, kinematics_of
from instrument.bench.profile import BenchProfile

__all__ = ["Scene", "Shape", "arms_view", "hemisphere_view", "plan_points_xy", "top_view"]


@dataclass(frozen=True)
class Shape:
    """One thing to draw: a polyline, a closed polygon or a set of markers.

    ``xy`` has shape (N, 2); ``role`` names what it is (``beam``, ``arm``, ``normal``,
    ``sample``, ``source``, ``detector``, ``bistatic_cone``, ``behind_sample``,
    ``collision``, ``points_done``, ``points_todo``, ``incident``, ``horizon``; a type (i)
    bench also ``source_rail``, ``detector_rail``, ``stationary_sample``); the view styles
    it by role.
    """

    role: str
    kind: str  # "line" | "polygon" | "markers"
    xy: np.ndarray
    label: str = ""


@dataclass(frozen=True)
class Scene:
    title: str
    shapes: tuple[Shape, ...]
    extent: float                     # half-width of the square that holds the drawing
    notes: tuple[str, ...] = field(default=())

    def by_role(self, role: str) -> list[Shape]:
        return [s for s in self.shapes if s.role == role]


def _unit(azimuth_deg: float) -> np.ndarray:
    a = math.radians(azimuth_deg)
    return np.array([math.cos(a), math.sin(a)])


def _wedge(a0_deg: float, a1_deg: float, r0: float, r1: float, n: int = 48) -> np.ndarray:
    """Polygon of the annular sector between azimuths a0..a1 and radii r0..r1."""
    if a1_deg < a0_deg:
        a0_deg, a1_deg = a1_deg, a0_deg
    a = np.radians(np.linspace(a0_deg, a1_deg, n))
    outer = np.column_stack([r1 * np.cos(a), r1 * np.sin(a)])
    inner = np.column_stack([r0 * np.cos(a[::-1]), r0 * np.sin(a[::-1])])
    return np.vstack([outer, inner, outer[:1]])


def top_view(profile: BenchProfile, positions: Mapping[str, float], *,
             planned: Sequence[Mapping[str, float]] = (), done: Sequence[bool] = ()) -> Scene:
    """The bench from above at ``positions`` (axis units by role, homed axes only).

    ``planned`` are the plan's points' axis targets in execution order and ``done`` says
    which of them are done.
    """
    geo = profile.geometry
    if geo.is_type_i:
        return arms_view(profile, positions,
                         planned_angles=[_angles_of(profile, p) for p in planned], done=done)
    R = geo.detector_distance_mm
    src_az = geo.source_theta_deg + float(positions.get("source_theta", 0.0))
    shapes: list[Shape] = []
    notes: list[str] = []
    has = set(profile.axes)

    # the incident beam: from the source (beyond the arm's reach) to the sample centre
    s = _unit(src_az)
    shapes.append(Shape("bistatic_cone", "polygon",
                        _wedge(src_az - geo.min_bistatic_deg, src_az + geo.min_bistatic_deg,
                               0.08 * R, 1.25 * R),
                        f"detector forbidden within {geo.min_bistatic_deg:g}° of the beam"))
    shapes.append(Shape("beam", "line", np.array([1.3 * R * s, [0.0, 0.0]]),
                        "incident beam"))
    shapes.append(Shape("source", "markers", np.array([1.3 * R * s]), "source"))

    # the sample: its normal's azimuth in the horizontal plane, the surface across it
    if "sample_theta" in has or "sample_tilt" in has or "sample_phi" in has:
        kin = kinematics_of(replace(geo, source_theta_deg=src_az))
        m = kin.sample_to_lab({k: float(v) for k, v in positions.items()})
        n3 = m[:, 2]
        n_az = math.degrees(math.atan2(n3[1], n3[0]))
        n_h = math.hypot(n3[0], n3[1])
        n = _unit(n_az)
        t = np.array([-n[1], n[0]])
        half = 0.12 * R
        shapes.append(Shape("behind_sample", "polygon",
                            _wedge(n_az + 90.0, n_az + 270.0, 0.0, 1.3 * R),
                            "behind the sample (θ ≥ 90°)"))
        shapes.append(Shape("sample", "line", np.array([half * t, -half * t]), "sample"))
        shapes.append(Shape("normal", "line", np.array([[0.0, 0.0], 0.45 * R * n_h * n]),
                            "sample normal"))
        if geo.kind == "out_of_plane":
            notes.append(f"normal tilted {math.degrees(math.asin(max(-1, min(1, n3[2])))):.1f}° "
                         "out of the plane (see the hemisphere)")

    # the detector arm
    if "detector_theta" in has:
        dt = positions.get("detector_theta")
        if dt is not None:
            reach = R + float(positions.get("camera_z", 0.0))
            d = _unit(src_az + float(dt))
            shapes.append(Shape("arm", "line", np.array([[0.0, 0.0], reach * d]),
                                "detector arm"))
            shapes.append(Shape("detector", "markers", np.array([reach * d]), "detector"))
        else:
            notes.append("detector_theta not homed: arm position unknown")

    # the profile's collision zones, as wedges of the arm (or of the normal)
    for zone in geo.collisions:
        offset = 0.0
        if zone.relative_to is not None:
            if zone.relative_to not in positions:
                notes.append(f"zone {zone.describe()}: {zone.relative_to} unknown")
                continue
            offset = float(positions[zone.relative_to])
        if zone.axis == "detector_theta":
            poly = _wedge(src_az + zone.low + offset, src_az + zone.high + offset,
                          0.55 * R, 1.15 * R)
        elif zone.axis in ("sample_theta", "source_theta"):
            poly = _wedge(src_az + zone.low + offset, src_az + zone.high + offset,
                          0.15 * R, 0.4 * R)
        else:
            notes.append(f"zone {zone.describe()} (not an azimuth: not drawn)")
            continue
        shapes.append(Shape("collision", "polygon", poly, zone.reason))

    # the plan's detector positions
    if len(planned) and "detector_theta" in has:
        xy = plan_points_xy(profile, planned, positions)
        flags = np.zeros(len(xy), bool)
        flags[:min(len(done), len(xy))] = np.asarray(done[:len(xy)], bool)
        known = np.isfinite(xy[:, 0])
        for role, sel in (("points_todo", known & ~flags), ("points_done", known & flags)):
            if sel.any():
                shapes.append(Shape(role, "markers", _distinct(xy[sel]),
                                    "points done" if "done" in role else "points to do"))
    return Scene(f"{profile.name}: top view", tuple(shapes), 1.35 * R, tuple(notes))


def _distinct(xy: np.ndarray, resolution: float = 0.1) -> np.ndarray:
    """The distinct markers of ``xy`` at ``resolution`` (a plan visits each detector angle
    once per incidence angle: thousands of points, a few hundred places to draw)."""
    if len(xy) < 2:
        return xy
    keys = np.round(xy / resolution).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return xy[np.sort(first)]


def plan_points_xy(profile: BenchProfile, planned: Sequence[Mapping[str, float]],
                   positions: Mapping[str, float]) -> np.ndarray:
    """Where the detector stands at each planned point in :func:`top_view`, shape (N, 2);
    NaN for points that do not set ``detector_theta``. Vectorised: a plan of 10⁵ points
    costs milliseconds."""
    geo = profile.geometry
    src_az = geo.source_theta_deg + float(positions.get("source_theta", 0.0))
    z_now = float(positions.get("camera_z", 0.0))
    dt = np.array([p.get("detector_theta", np.nan) for p in planned], float)
    z = np.array([p.get("camera_z", z_now) for p in planned], float)
    a = np.radians(src_az + dt)
    r = geo.detector_distance_mm + z
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def _project(theta_deg: np.ndarray, phi_deg: np.ndarray) -> np.ndarray:
    """Azimuthal-equidistant projection: radius = θ (degrees), angle = φ."""
    t, p = np.asarray(theta_deg, float), np.radians(np.asarray(phi_deg, float))
    return np.column_stack([t * np.cos(p), t * np.sin(p)])


def _cone(axis: np.ndarray, half_angle_deg: float) -> np.ndarray:
    """The directions ``half_angle_deg`` from the unit vector ``axis``, projected."""
    e1 = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    b = math.radians(half_angle_deg)
    a = np.linspace(0, 2 * math.pi, 73)[:, None]
    ring = math.cos(b) * axis + math.sin(b) * (np.cos(a) * e1 + np.sin(a) * e2)
    th = np.degrees(np.arctan2(np.hypot(ring[:, 0], ring[:, 1]), ring[:, 2]))
    ph = np.degrees(np.arctan2(ring[:, 1], ring[:, 0]))
    return _project(th, ph)


def _angles_of(profile: BenchProfile, targets: Mapping[str, float]) -> Angles | None:
    kin = kinematics_of(profile.geometry)
    if not all(a in targets for a in kin.axes):
        return None
    return kin.angles(targets)


def _grid(shapes: list[Shape]) -> None:
    rim = np.radians(np.linspace(0, 360, 181))
    for deg in (30.0, 60.0, 90.0):
        shapes.append(Shape("horizon" if deg == 90 else "grid", "line",
                            np.column_stack([deg * np.cos(rim), deg * np.sin(rim)]),
                            f"θ = {deg:g}°"))


def _planned(shapes: list[Shape], planned_angles: Sequence[Angles | None],
             done: Sequence[bool]) -> None:
    """The plan's detector directions, done and to do."""
    flags = list(done) + [False] * (len(planned_angles) - len(done))
    for ok, role in ((False, "points_todo"), (True, "points_done")):
        sel = [a for a, f in zip(planned_angles, flags, strict=False)
               if a is not None and f == ok]
        if sel:
            shapes.append(Shape(role, "markers",
                                _distinct(_project([a.theta_r for a in sel],
                                                   [a.phi_r for a in sel]), 0.01),
                                "points done" if ok else "points to do"))


def arms_view(profile: BenchProfile, positions: Mapping[str, float], *,
              planned_angles: Sequence[Angles | None] = (),
              done: Sequence[bool] = ()) -> Scene:
    """A type (i) bench from above (module docstring): radius θ, azimuth φ from x_s."""
    geo = profile.geometry
    kin = kinematics_of(geo)
    assert isinstance(kin, TypeIKinematics)
    shapes: list[Shape] = []
    _grid(shapes)
    shapes.append(Shape("stationary_sample", "markers", np.zeros((1, 2)),
                        "sample (stationary)"))
    notes: list[str] = []
    pose = {k: float(v) for k, v in positions.items()}
    heads = {}
    for arm in ("source", "detector"):
        arc, az = f"{arm}_arc", f"{arm}_azimuth"
        if arc not in pose or az not in pose:
            notes.append(f"{arm} arm not homed: its position is unknown")
            continue
        ϕ = pose[az] - kin.offsets[az]
        rail = _project([90.0, 90.0], [ϕ, ϕ + 180.0])
        shapes.append(Shape(f"{arm}_rail", "line", rail, f"{arm} arm's rail"))
        t, p = _polar_deg(kin.arm_direction(pose, arm))
        heads[arm] = (t, p)
        shapes.append(Shape("incident" if arm == "source" else "detector", "markers",
                            _project([t], [p]), f"{arm} head θ={t:.1f}° φ={p:.1f}°"))
    if "source" in heads:
        wi = _direction(*heads["source"])
        src, det = geo.source_arm, geo.detector_arm
        if src is not None and det is not None:
            touch = src.half_width_deg + det.half_width_deg
            shapes.append(Shape("collision", "polygon", _cone(wi, touch),
                                f"arms touch within {touch:.2g}° of the source head"))
            # the beam or view rule: the largest separation it refuses, by bisection
            lit = _lit_zone_deg(profile, heads["source"])
            if lit > touch:
                shapes.append(Shape("bistatic_cone", "polygon", _cone(wi, lit),
                                    f"detector forbidden within {lit:.2g}° with the light on"))
    if planned_angles:
        _planned(shapes, planned_angles, done)
    return Scene(f"{profile.name}: type (i) arms from above (radius θ, φ from x)",
                 tuple(shapes), 95.0, tuple(notes))


def _direction(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def _polar_deg(v: np.ndarray) -> tuple[float, float]:
    return (math.degrees(math.atan2(math.hypot(v[0], v[1]), v[2])),
            math.degrees(math.atan2(v[1], v[0])))


def _lit_zone_deg(profile: BenchProfile, source: tuple[float, float]) -> float:
    """How far from the source head the guard's ``beam`` or ``view`` rule reaches (0 when
    neither applies), found by bisection on the guard's own test."""
    geo = profile.geometry
    kin = kinematics_of(geo)
    t, p = source

    def refused(delta: float) -> bool:
        # a detector δ further from the pole than the source, on its azimuth
        pose = kin.positions(Angles(t, p % 360.0, min(t + delta, 89.9), p % 360.0))
        return any(r in ("beam", "view") for r, _ in arm_violations(geo, pose, light=True))

    lo, hi = 0.0, 30.0
    if not refused(1e-3):
        return 0.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if refused(mid) else (lo, mid)
    return lo


def hemisphere_view(profile: BenchProfile, positions: Mapping[str, float], *,
                    planned_angles: Sequence[Angles | None] = (),
                    done: Sequence[bool] = ()) -> Scene:
    """The hemisphere above the sample (θ ≤ 90° within the rim), sample frame."""
    geo = profile.geometry
    kin = kinematics_of(geo)
    shapes: list[Shape] = []
    _grid(shapes)
    notes: list[str] = []
    if all(a in positions for a in kin.axes):
        angles = kin.angles({k: float(v) for k, v in positions.items()})
        # the bistatic cone: directions within min_bistatic of the incident direction
        shapes.append(Shape("bistatic_cone", "polygon",
                            _cone(angles.omega_i, geo.min_bistatic_deg),
                            f"detector forbidden within {geo.min_bistatic_deg:g}° of the beam"))
        shapes.append(Shape("incident", "markers",
                            _project([angles.theta_i], [angles.phi_i]),
                            f"incident θi={angles.theta_i:.1f}° φi={angles.phi_i:.1f}°"))
        shapes.append(Shape("detector", "markers",
                            _project([angles.theta_r], [angles.phi_r]),
                            f"detector θr={angles.theta_r:.1f}° φr={angles.phi_r:.1f}°"))
        if angles.theta_r >= 90 or angles.theta_i >= 90:
            notes.append("a direction is below the sample surface")
    else:
        missing = [a for a in kin.axes if a not in positions]
        notes.append(f"{', '.join(missing)} not homed: directions unknown")
    if planned_angles:
        _planned(shapes, planned_angles, done)
    return Scene(f"{profile.name}: hemisphere above the sample (radius θ, φ from x)",
                 tuple(shapes), 95.0, tuple(notes))

