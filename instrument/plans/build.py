"""From a validated plan spec and a bench profile to an ordered, guarded :class:`Plan`.

The plan's points are generated in a natural (raster) order, turned into axis targets by
the bench's kinematics, checked by :mod:`instrument.bench.guard` (nothing moves if any point is
rejected), then ordered for short motion time. :meth:`Plan.commands` is the generator of
typed commands the engine runs; it skips points already done (resume).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Container, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from instrument.bench import guard
from instrument.bench.arms import safe_route
from instrument.bench.dynamics import AxisDynamics, dynamics_of, route_time, step_time
from instrument.bench.kinematics import TYPE_I_AXES, Angles, UnreachableError, kinematics_of
from instrument.bench.profile import BenchProfile, FieldError
from instrument.bench.timing import BenchTiming, bench_timing
from instrument.plans.commands import (
    Acquire,
    AcquisitionPolicy,
    Command,
    Move,
    PointDone,
    ScanPoint,
    SetLight,
)
from instrument.plans.count import check_point_count
from instrument.plans.grid import dedupe_reciprocal, equal_solid_angle_grid, specular_cone
from instrument.plans.order import optimise_order
from instrument.plans.planfile import MAX_POINTS, PlanError, PlanSpec
from instrument.plans.polarimetry import plan_wavelengths, polarimetry_axis
from instrument.plans.polarimetry_pem import pem_axis
from instrument.plans.ranges import float_range
from instrument.plans.route_costs import RouteCosts
from instrument.plans.spin import check_spinner

__all__ = ["EVENTS", "Plan", "PlanEstimate", "build_plan", "dynamics_of", "guarded_points",
           "in_plane_angles"]

#: The events :attr:`PlanEstimate.events` counts: aperture integrals of the emulated power
#: meter and lock-in photodiode with the light on and off (:mod:`instrument.bench.timing`),
#: and the auto-exposure's frames at exposures it did not keep (:meth:`Plan._climb_frames`).
EVENTS = ("power_meter_integrals_lit", "power_meter_integrals_dark", "lockin_integrals_lit",
          "lockin_integrals_dark", "auto_exposure_climb_frames")


@dataclass(frozen=True)
class PlanEstimate:
    """How long a plan takes.

    ``motion_s`` and ``acquisition_s`` are the instrument's own time: moves at the
    profile's velocities and accelerations, exposures plus the policy's readout (what the
    speed/accuracy planner compares). ``bench_motion_s`` and ``bench_acquisition_s`` are
    what *this* bench takes on the wall clock (:mod:`instrument.bench.timing`): emulated
    stages run ``speedup`` times faster, a simulated camera exposes in no time but renders,
    and every point costs its storage; :attr:`total_s` is their sum. ``homing_s`` maps each
    axis of the plan to the wall-clock seconds its homing takes, for a start on axes that
    are not homed yet (not in :attr:`total_s`).
    """

    n_points: int
    travel: dict[str, float]       # total distance per axis, axis units
    motion_s: float
    acquisition_s: float
    bench_motion_s: float | None = None
    bench_acquisition_s: float | None = None
    speedup: float = 1.0
    homing_s: dict[str, float] = field(default_factory=dict)
    #: Costs the profile does not give and the estimate assumed (in words).
    assumed: tuple[str, ...] = ()
    #: What the estimate predicted about the run beyond the plan's points (in words): the
    #: neutral-density turns near a specular peak.
    predicted: tuple[str, ...] = ()
    #: How many of the bench's countable events the acquisition time holds (name →
    #: count, :data:`EVENTS`): the emulated detectors' aperture integrals and the
    #: auto-exposure's extra frames after a neutral-density filter changed the light.
    events: dict[str, float] = field(default_factory=dict)

    @property
    def total_s(self) -> float:
        """Seconds this bench will take (the instrument's own time when not known)."""
        if self.bench_motion_s is None or self.bench_acquisition_s is None:
            return self.real_time_s
        return self.bench_motion_s + self.bench_acquisition_s

    @property
    def real_time_s(self) -> float:
        """Seconds on real stages and a real camera (no emulated speed-up)."""
        return self.motion_s + self.acquisition_s


@dataclass(frozen=True)
class Plan:
    spec: PlanSpec
    profile: BenchProfile
    axes: tuple[str, ...]
    points: tuple[ScanPoint, ...]   # execution order; points[k].index == k
    dropped_in_beam: int = 0        # points left out by ``skip_beam_points``

    @property
    def kind(self) -> str:
        return self.spec.kind

    def targets_array(self) -> np.ndarray:
        """Targets of every point, shape (N, len(axes)); NaN where a point leaves an axis."""
        out = np.full((len(self.points), len(self.axes)), np.nan)
        col = {r: k for k, r in enumerate(self.axes)}
        for p in self.points:
            for r, v in p.targets:
                out[p.index, col[r]] = v
        return out

    def commands(self, done: Container[int] = frozenset()) -> Iterator[Command]:
        """The typed commands of every point not in ``done``, in execution order."""
        light: bool | None = None
        policy = self.spec.acquisition
        for p in self.points:
            if p.index in done:
                continue
            if light is not p.light:
                light = p.light
                yield SetLight(p.light)
            yield Move(p.index, p.targets)
            yield Acquire(p.index, policy, p.label, p.light, p.exposure_us)
            yield PointDone(p.index)

    def estimate(self, *, start: dict[str, float] | None = None) -> PlanEstimate:
        """Points, travel and duration from the axes' dynamics and the exposures, in the
        instrument's own time and on this bench's clocks (:class:`PlanEstimate`)."""
        t = self.targets_array()
        t = _fill_forward(t, start, self.axes)
        dyn = dynamics_of(self.profile, self.axes)
        travel = {r: float(np.abs(np.diff(t[:, k])).sum()) for k, r in enumerate(self.axes)}
        motion, _ = route_time(t, self.axes, dyn)
        motion += self._routes_extra_s(t, dyn)
        pol = self.spec.acquisition
        acq = sum(pol.estimated_seconds(p.exposure_us) for p in self.points)
        timing = bench_timing(self.profile, self.axes)
        fast = {r: _faster(d, timing.axis_speed.get(r, 1.0)) for r, d in dyn.items()}
        bench_motion, _ = route_time(t, self.axes, fast)
        bench_motion += self._routes_extra_s(t, fast)
        speedup = motion / bench_motion if bench_motion > 0 else 1.0
        nd_s, nd_note = self._nd_turns(timing)
        events = dict.fromkeys(EVENTS, 0.0)
        acquisition = self._acquisition_on(timing, events)
        return PlanEstimate(len(self.points), travel, motion, acq, bench_motion,
                            acquisition + nd_s, speedup, dict(timing.home_s),
                            timing.assumed, nd_note + self._events_note(events), events)

    def _routes_extra_s(self, t: np.ndarray, dyn: dict[str, AxisDynamics]) -> float:
        """Seconds a type (i) bench's routes add to the moves between the rows of ``t``
        (targets, axes :attr:`axes`): the legs of a split move one after the other, less
        the one concurrent move :func:`route_time` counted (ADR 0099). 0 on type (ii)."""
        geo = self.profile.geometry
        if not geo.is_type_i or not all(r in self.axes for r in TYPE_I_AXES):
            return 0.0
        col = [self.axes.index(r) for r in TYPE_I_AXES]
        limits = {r: d.limits for r, d in self.profile.axes.items()}
        extra = 0.0
        for a, b in itertools.pairwise(t[:, col]):
            here, there = dict(zip(TYPE_I_AXES, a, strict=True)), dict(
                zip(TYPE_I_AXES, b, strict=True))
            route = safe_route(geo, dyn, here, there, limits=limits)
            if route is not None and route.split:
                extra += route.seconds(here, dyn) - step_time(here, there, dyn)
        return extra

    @staticmethod
    def _events_note(events: dict[str, float]) -> tuple[str, ...]:
        notes = []
        integrals = sum(v for k, v in events.items() if "integrals" in k)
        if integrals:
            notes.append(f"{integrals:.0f} aperture integrals of the emulated detectors")
        if events["auto_exposure_climb_frames"]:
            notes.append(f"{events['auto_exposure_climb_frames']:.0f} auto-exposure frames "
                         "at exposures not kept, after the ND filters changed the light")
        return tuple(notes)

    #: Points within this angle of the mirror direction are taken to clip the camera at
    #: its shortest exposure when the plan does not refine a specular window itself.
    ND_WINDOW_DEG = 5.0

    def _nd_turns(self, timing: BenchTiming) -> tuple[float, tuple[str, ...]]:
        """Seconds of the neutral-density turns the engine will make (ADR 0018), and the
        prediction in words.

        The engine turns to the lightest ND filter when the camera clips at its shortest
        exposure and reads that point again, and turns back once the peak is behind. Which
        points clip depends on the sample; the estimate takes those within the plan's
        specular window (``[scan] specular.half_width_deg``, else :data:`ND_WINDOW_DEG`)
        of the mirror direction as clipping: per run of such points, a turn to the first
        ND slot, the point read again (its frames and the scene change) and a turn back.
        A matt sample makes none of them (an upper estimate there); never zero where a
        glossy one would."""
        pol = self.spec.acquisition
        nd = sorted(nd_slots_of(self.profile))
        if not (nd and timing.wheel_slots and pol.uses_camera and self.spec.spectral is None):
            return 0.0, ()
        open_slot = next((k for k in range(1, timing.wheel_slots + 1) if k not in nd), 1)
        specular = self.spec.scan.get("specular") if isinstance(self.spec.scan, dict) else None
        window = float(specular.get("half_width_deg", self.ND_WINDOW_DEG)
                       if isinstance(specular, dict) else self.ND_WINDOW_DEG)
        turn = timing.wheel_move_s(open_slot, nd[0])
        per_frame = (pol.min_exposure_us * 1e-6 * timing.exposure_factor
                     + max(timing.frame_overhead_s, pol.readout_s))
        reread = pol.frames * per_frame * (2 if pol.mode == "auto" and pol.hdr else 1)
        runs, inside = 0, False
        for p in self.points:
            near = (p.light and p.label == "sample" and p.angles is not None
                    and _from_mirror_deg(p.angles) <= window)
            if near and not inside:
                runs += 1
            inside = near
        if not runs:
            return 0.0, ()
        seconds = runs * (2 * turn + reread + timing.scene_change_s)
        return seconds, (f"ND filters: {runs} peak(s) within {window:g}° of specular taken "
                         f"to clip, {2 * runs} wheel turns of {turn:.2g} s and {runs} "
                         f"point(s) read again: {seconds:.3g} s (none on a matt sample)",)

    def _acquisition_on(self, timing: BenchTiming, events: dict[str, float]) -> float:
        """Wall-clock seconds of every point's acquisition and storage on a bench; counts
        the :data:`EVENTS` into ``events``.

        Per point: the light brackets (1; with auto-exposure and HDR, half of
        ``max_brackets`` and one more, the middle of what a scene needs) and as many dark
        frames with ``dark = "per_point"``, each of ``frames`` averaged frames costing the
        exposure (when the camera exposes in wall time) and the camera's per-frame time;
        the auto-exposure's frames climbing to the new light after a neutral-density
        filter (:meth:`_climb_frames`); the camera's scene-change time (and a simulated
        scene's render time) for a lit point after a move or after the light came on; the
        emulated detectors' aperture integrals at a new world state (a move, the light
        switched, a filter turned; :mod:`instrument.bench.timing`); the lock-in's
        settling for its readings (twice with per-point darks); the filter wheel's turn
        where the slot changes; the engine's and storage's time per point.
        """
        pol = self.spec.acquisition
        total = 0.0
        lit: bool | None = None
        where: tuple[Any, ...] | None = None
        slot: int | None = None
        climb = _ExposureClimb(pol, self.profile)
        dark_seen: set[Any] = set()
        if pol.uses_lockin and timing.lockin_integral_s != (0.0, 0.0):
            # the emulated lock-in computes its input once as the bench opens (light off)
            events["lockin_integrals_dark"] += 1
            total += timing.lockin_integral_s[1]
        for p in self.points:
            moved = bool(p.targets) and p.targets != where
            if p.targets:
                where = p.targets
            want = dict(p.meta).get("filter")
            turned = want is not None and int(want) != slot
            if want is not None:
                # the first filter: the wheel may stand anywhere; count a turn from slot 1
                total += timing.wheel_move_s(1 if slot is None else slot, int(want))
                slot = int(want)
            total += self._integrals_s(timing, p.light, moved or turned or lit is not p.light,
                                       where, dark_seen, events)
            pem = self.spec.polarimetry if "pem_setting" in dict(p.meta) else None
            if pem is not None:
                # a PEM setting: 1f and 2f each settled for the plan's time constants
                total += timing.pem_reading_s(pem["time_constants"], pem["reads"])
            elif pol.uses_lockin and timing.lockin_settle_s > 0:
                reads = 2 if (pol.dark == "per_point" and p.light
                              and pol.reads_dark("lockin")) else 1
                total += reads * timing.lockin_reading_s(pol.frames)
            if not pol.uses_camera:
                total += timing.point_overhead_s / 4  # a journal line, no frames
                lit = p.light
                continue
            exposure_s = (p.exposure_us if p.exposure_us is not None
                          else pol.exposure_us) * 1e-6
            brackets = 1.0
            if p.exposure_us is None and pol.mode == "auto" and pol.hdr:
                brackets = (max(pol.max_brackets, 1) + 1) / 2
            darks = brackets if pol.dark == "per_point" and p.light else 0.0
            per_frame = (exposure_s * timing.exposure_factor
                         + max(timing.frame_overhead_s, pol.readout_s))
            total += (brackets + darks) * pol.frames * per_frame
            if p.light and p.exposure_us is None and pol.mode == "auto":
                extra = climb.frames(slot)
                events["auto_exposure_climb_frames"] += extra
                total += extra * pol.frames * (climb.exposure_s * timing.exposure_factor
                                               + max(timing.frame_overhead_s, pol.readout_s))
            if p.light and (moved or lit is not True):
                total += timing.scene_change_s + timing.render_s
            lit = p.light
            total += timing.point_overhead_s
        return total

    def _integrals_s(self, timing: BenchTiming, light: bool, new_state: bool,
                     where: tuple[Any, ...] | None, dark_seen: set[Any],
                     events: dict[str, float]) -> float:
        """Seconds of the emulated detectors' aperture integrals at one point, counted into
        ``events``. With the light on, at a new world state (the emulators cache the last
        ones): the power meter one, the lock-in's photodiode two (the light, and its
        ambient part with the source off). With the light off (a dark point, or the
        per-point dark phase) one per detector at a pose not read dark before: dark, the
        filter in the beam does not change the world, so the emulators' caches hold it."""
        pol = self.spec.acquisition
        dark_phase = pol.dark == "per_point" and light
        seconds = 0.0
        for name, used, cost, ambient in (
                ("power_meter", pol.uses_power_meter, timing.power_meter_integral_s, 1),
                ("lockin", pol.uses_lockin, timing.lockin_integral_s, 2)):
            if not used or cost == (0.0, 0.0):
                continue
            n_lit = n_dark = 0
            if light and new_state:
                n_lit, n_dark = 1, ambient - 1
            if (not light or (dark_phase and pol.reads_dark(name))) \
                    and (name, where) not in dark_seen:
                dark_seen.add((name, where))
                n_dark += 1
            events[f"{name}_integrals_lit"] += n_lit
            events[f"{name}_integrals_dark"] += n_dark
            seconds += n_lit * cost[0] + n_dark * cost[1]
        return seconds


class _ExposureClimb:
    """The auto-exposure's frames at exposures it does not keep, after a neutral-density
    filter of the plan's filters changed the light.

    The engine's auto-exposure (``instrument.run.engine.RunEngine._brackets``) starts
    at the exposure it kept last and multiplies it by ``hdr_factor`` f per frame while
    the peak is below ``target_fraction``/f of full scale (divides it while the frame
    clips), one frame per step. Light dimmed by a factor R = 10^ΔOD therefore costs
    about log R / log f frames: rounded, the count for a peak anywhere within the
    accepted range of one factor f, and none beyond the exposure limits. The first
    point's exposure is taken as the plan's (the scene's brightness is not known to the
    plan); the filters' densities are the profile's nominal ones (``od``)."""

    def __init__(self, policy: AcquisitionPolicy, profile: BenchProfile) -> None:
        self.factor = float(policy.hdr_factor)
        self.lo = float(policy.min_exposure_us)
        self.hi = float(policy.max_exposure_us)
        self.exposure_us = min(max(float(policy.exposure_us), self.lo), self.hi)
        self.od = nd_densities(profile)
        self.current: float | None = None

    @property
    def exposure_s(self) -> float:
        return self.exposure_us * 1e-6

    def frames(self, slot: int | None) -> int:
        """Frames not kept at a lit point through ``slot`` (None: no filter)."""
        od = self.od.get(slot, 0.0) if slot is not None else 0.0
        before, self.current = self.current, od
        if before is None or od == before:
            return 0
        want = min(max(self.exposure_us * 10.0 ** (od - before), self.lo), self.hi)
        steps = round(abs(math.log(want / self.exposure_us)) / math.log(self.factor))
        grown = self.exposure_us * self.factor ** (steps if want > self.exposure_us
                                                   else -steps)
        self.exposure_us = min(max(grown, self.lo), self.hi)
        return steps


def _from_mirror_deg(a: Angles) -> float:
    """Angle (degrees) between the receiver direction and the mirror direction of the
    incidence (the specular peak), conventions of :mod:`analysis.brdf.geometry`."""
    ti, pi_, tr, pr = (math.radians(x) for x in (a.theta_i, a.phi_i, a.theta_r, a.phi_r))
    mirror = (-math.sin(ti) * math.cos(pi_), -math.sin(ti) * math.sin(pi_), math.cos(ti))
    recv = (math.sin(tr) * math.cos(pr), math.sin(tr) * math.sin(pr), math.cos(tr))
    dot = sum(x * y for x, y in zip(mirror, recv, strict=True))
    return math.degrees(math.acos(max(-1.0, min(1.0, dot))))


def _fill_forward(t: np.ndarray, start: dict[str, float] | None, axes: Sequence[str]
                  ) -> np.ndarray:
    """Axes a point does not move keep their previous target (or start, or 0)."""
    t = t.copy()
    for k, r in enumerate(axes):
        prev = (start or {}).get(r, 0.0)
        for i in range(len(t)):
            if math.isnan(t[i, k]):
                t[i, k] = prev
            prev = t[i, k]
    return t


def _faster(d: AxisDynamics, speed: float) -> AxisDynamics:
    """The dynamics of an axis whose clock runs ``speed`` times faster: every move takes
    1/speed of the time (velocity × s, acceleration × s², settle / s)."""
    return AxisDynamics(d.velocity * speed, d.acceleration * speed * speed,
                        d.settle_s / speed)


# --------------------------------------------------------------------------- generation


def _raw_points(spec: PlanSpec, profile: BenchProfile) -> list[ScanPoint]:
    check_point_count(spec)  # from the axes, before a single point is made
    s = spec.scan
    kind = spec.kind
    kin = kinematics_of(profile.geometry)
    limits = {r: d.limits for r, d in profile.axes.items() if d.limits is not None}
    label = {"reference": "reference", "signature": "signature"}.get(kind, "sample")
    if kind == "brdf_hemisphere" and not profile.geometry.reaches_hemisphere:
        # One cause, one message: an in-plane goniometer has no sample azimuth or tilt, so
        # every off-plane direction would otherwise be listed as its own error.
        raise PlanError(f"plan {spec.name!r}", [FieldError(
            "plan.kind", f"'brdf_hemisphere' needs an out-of-plane bench (geometry.kind = "
            f"'out_of_plane'); bench {profile.name!r} is {profile.geometry.kind!r}: "
            "choose one with --bench (e.g. sim-out-of-plane)")])
    errors: list[FieldError] = []

    def geo_point(a: Angles, lab: str = label) -> ScanPoint | None:
        try:
            pos = kin.positions(a, limits=limits)
        except UnreachableError as err:
            errors.append(FieldError("scan", f"{err} (bench geometry "
                                             f"{profile.geometry.kind!r})"))
            return None
        return ScanPoint(0, tuple((r, float(pos[r])) for r in kin.axes), a, lab)

    pts: list[ScanPoint] = []
    angles: list[Angles] = []
    if kind in ("brdf_in_plane", "reference", "signature") and "points" in s:
        angles.extend(in_plane_angles(float(ti), float(tr)) for ti, tr in s["points"])
    elif kind in ("brdf_in_plane", "reference", "signature"):
        theta_r = _expand(s["theta_r"])
        # a two-pass lobe plan builds its first pass: the θr grid and a search around the
        # mirror direction (instrument.plans.lobe)
        search = s.get("specular")
        if "lobe" in s:
            lb = s["lobe"]
            search = {"half_width_deg": float(lb.get("search_half_width_deg", 5.0)),
                      "step_deg": float(lb.get("search_step_deg", 1.0))}
        for ti in _expand(s["theta_i"]):
            rs = list(theta_r)
            if search is not None:
                hw, step = search["half_width_deg"], search["step_deg"]
                n = math.floor(hw / step + 1e-9)
                rs += [ti_abs + k * step for k in range(-n, n + 1)
                       for ti_abs in (abs(ti),) if abs(ti_abs + k * step) < 90]
                rs = sorted(set(round(r, 9) for r in rs))
            for tr in rs:
                angles.append(in_plane_angles(ti, tr))
    elif kind == "brdf_hemisphere":
        grid, _ = equal_solid_angle_grid(int(s["n_directions"]),
                                         float(s.get("theta_max_deg", 85.0)))
        for ti in _expand(s["theta_i"]):
            for pi in _expand(s.get("phi_i", [0.0])):
                dirs = [tuple(d) for d in grid]
                if "specular" in s:
                    sp = s["specular"]
                    dirs += specular_cone(ti, pi, half_width_deg=sp["half_width_deg"],
                                          rings=int(sp.get("rings", 2)),
                                          per_ring=int(sp.get("per_ring", 8)))
                angles += [Angles(float(ti), float(pi) % 360.0 if ti > 0 else 0.0,
                                  float(th), float(ph)) for th, ph in dirs]
    if angles:
        if s.get("reciprocity", False):
            keep = dedupe_reciprocal(angles, isotropic=bool(s.get("isotropic", True)))
            angles = [angles[i] for i in keep]
        for a in angles:
            p = geo_point(a)
            if p is not None:
                pts.append(p)
    elif kind == "lightfield":
        fixed = [(r, float(s[r])) for r in ("sample_theta", "detector_theta") if r in s]
        for z in _expand(s["camera_z"]):
            pts.append(ScanPoint(0, (*fixed, ("camera_z", float(z))), None, "lightfield"))
    elif kind == "sphere_capture":
        # Objects × lightings: the lighting axis moves least often (its moves are the long
        # ones on a real goniometer); the changer steps through the objects at each.
        sel = str(s.get("selector", "sample_phi"))
        lrole = str(s.get("lighting_role", "source_theta"))
        for k, theta in enumerate(_expand(s["lighting_deg"])):
            for o in s["objects"]:
                pts.append(ScanPoint(0, ((lrole, float(theta)),
                                         (sel, float(o["station_deg"]))), None, "sphere",
                                     meta=(("object", str(o["name"])), ("lighting", k))))
    elif kind in ("dark", "flat_field"):
        fixed = tuple((r, float(v)) for r, v in s.get("positions", {}).items())
        lab, light = ("dark", False) if kind == "dark" else ("flat", True)
        for e in _expand(s["exposures_us"]):
            for k in range(int(s.get("frames", 1))):
                pts.append(ScanPoint(0, fixed, None, lab, light, float(e), (("repeat", k),)))
    elif kind == "photon_transfer":
        fixed = tuple((r, float(v)) for r, v in s.get("positions", {}).items())
        for e in _ptc_exposures(s["exposures_us"]):
            for k in range(int(s.get("pairs", 2))):
                for frame in (0, 1):  # a pair: the difference frame cancels fixed pattern
                    pts.append(ScanPoint(0, fixed, None, "ptc", True, e,
                                         (("pair", k), ("frame", frame))))
            if s.get("dark", True):
                for frame in (0, 1):
                    pts.append(ScanPoint(0, fixed, None, "dark", False, e, (("frame", frame),)))
    if errors:
        raise PlanError(f"plan {spec.name!r}", errors[:20])
    if spec.acquisition.dark == "start" and kind not in ("dark", "photon_transfer"):
        darks = [ScanPoint(0, (), None, "dark", False, None)]
        pts = darks + pts
    return pts


def in_plane_angles(theta_i: float, theta_r_signed: float) -> Angles:
    """Plan-file signed angles → sample-frame angles.

    θi ≥ 0 puts the source at φi = 0 (θi < 0 at φi = 180°); θr > 0 is on the specular
    side (φr opposite to φi), θr < 0 on the source side.
    """
    phi_i = 0.0 if theta_i >= 0 else 180.0
    phi_r = (phi_i + 180.0) % 360.0 if theta_r_signed >= 0 else phi_i
    return Angles(abs(theta_i), phi_i, abs(theta_r_signed), phi_r)


def _expand(x: Any) -> Sequence[float]:
    if isinstance(x, dict):
        return float_range(x)
    return [float(e) for e in x]


def _ptc_exposures(x: Any) -> Sequence[float]:
    if isinstance(x, dict) and "n" in x:
        n = int(x["n"])
        if x.get("log", True):
            return list(np.geomspace(float(x["start"]), float(x["stop"]), n))
        return list(np.linspace(float(x["start"]), float(x["stop"]), n))
    return _expand(x)


def guarded_points(spec: PlanSpec, profile: BenchProfile) -> list[ScanPoint]:
    """The points ``spec`` expands to on ``profile``, in generation order, less every point
    the guard rejects (a candidate list for planning, e.g. :mod:`instrument.plans.lobe`;
    :func:`build_plan` refuses such points instead)."""
    raw = [replace(p, index=i) for i, p in enumerate(_raw_points(spec, profile))]
    bad = {v.index for v in guard.check(raw, profile)}
    return [p for p in raw if p.index not in bad]


def build_plan(spec: PlanSpec, profile: BenchProfile, *,
               start: dict[str, float] | None = None) -> Plan:
    """Expand, guard and order ``spec`` for ``profile``.

    Raises
    ------
    PlanError
        The plan does not fit this bench (unreachable angles, too many points).
    GuardError
        Some points violate limits, the beam or collision zones (nothing has moved).
    """
    raw = _raw_points(spec, profile)
    if not raw:
        raise PlanError(f"plan {spec.name!r}", [FieldError("scan", "expands to no points")])
    if len(raw) > MAX_POINTS:
        raise PlanError(f"plan {spec.name!r}", [FieldError(
            "scan", f"expands to {len(raw)} points; at most {MAX_POINTS}")])
    raw = [replace(p, index=i) for i, p in enumerate(raw)]
    dropped = 0
    if spec.scan.get("skip_beam_points", False):
        beam = {v.index for v in guard.check(raw, profile) if v.reason in guard.NEAR_SOURCE}
        dropped = len(beam)
        raw = [replace(p, index=i)
               for i, p in enumerate(p for p in raw if p.index not in beam)]
    guard.enforce(raw, profile)
    axes = tuple(dict.fromkeys(r for p in raw for r, _ in p.targets))
    # Points that move nothing (dark frames taken at the start) stay first, in order.
    head = [p for p in raw if not p.targets]
    body = [p for p in raw if p.targets]
    if (spec.order == "optimised" and axes and len(body) > 2
            and all(len(p.targets) == len(axes) for p in body)):
        t = np.array([[dict(p.targets)[r] for r in axes] for p in body])
        st = None if start is None else np.array([start.get(r, 0.0) for r in axes])
        dyn = dynamics_of(profile, axes)
        costs = RouteCosts.of(profile, t, axes, dyn, start=st)  # None on type (ii)
        order = optimise_order(t, axes, dyn, start=st, costs=costs)
        body = _routable(profile, body, [body[int(j)] for j in order], start)
    elif profile.geometry.is_type_i:
        _routable(profile, body, body, start)
    _check_power_meter_wavelength(spec, profile)
    check_spinner(spec, profile)
    if spec.spectral is not None:
        body = _wavelength_axis(spec, profile, body)
        if len(head) + len(body) > MAX_POINTS:
            raise PlanError(f"plan {spec.name!r}", [FieldError(
                "spectral.filters", f"expands to {len(head) + len(body)} points; at most "
                f"{MAX_POINTS}")])
    if spec.polarimetry is not None:
        body = _polarimetry(spec, profile, body)
        axes = tuple(dict.fromkeys(r for p in head + body for r, _ in p.targets))
    if spec.acquisition.dark == "per_row":
        body = _dark_per_row(body)
    points = tuple(replace(p, index=k) for k, p in enumerate(head + body))
    return Plan(spec, profile, axes, points, dropped)


def _routable(profile: BenchProfile, generated: list[ScanPoint], ordered: list[ScanPoint],
              start: dict[str, float] | None) -> list[ScanPoint]:
    """``ordered``, if the arms of a type (i) bench can run it without touching between
    points (:func:`instrument.bench.guard.check_route`); else the generated order if they
    can run that; else :class:`~instrument.bench.guard.GuardError` (nothing has moved)."""
    if not profile.geometry.is_type_i:
        return ordered
    dyn = dynamics_of(profile, profile.axes)
    bad = guard.check_route(ordered, profile, dyn, start=start)
    if bad and ordered is not generated and not guard.check_route(generated, profile, dyn,
                                                                   start=start):
        return generated
    if bad:
        raise guard.GuardError(bad, len(ordered))
    return ordered


def plan_filter_wavelengths(spec: PlanSpec, profile: BenchProfile) -> list[float]:
    """The centre wavelengths (nm) of the plan's ``[spectral]`` filters that the profile
    gives a band for; empty without a wavelength axis."""
    bands = filter_bands(profile) or {}
    return [bands[f][0] for f in (spec.spectral or {}).get("filters", ()) if f in bands]


def _polarimetry(spec: PlanSpec, profile: BenchProfile, body: list[ScanPoint]
                 ) -> list[ScanPoint]:
    """``body`` with the dual-rotating-retarder steps (:mod:`instrument.plans.polarimetry`)
    or the PEM settings (:mod:`instrument.plans.polarimetry_pem`) at every lit point,
    within the point limit."""
    assert spec.polarimetry is not None
    wavelengths = plan_wavelengths(profile, plan_filter_wavelengths(spec, profile))
    pem = spec.polarimetry["mode"] == "pem"
    out = (pem_axis(spec.polarimetry, profile, body, spec.acquisition, wavelengths) if pem
           else polarimetry_axis(spec.polarimetry, profile, body, wavelengths))
    if len(out) > MAX_POINTS:
        raise PlanError(f"plan {spec.name!r}", [FieldError(
            "polarimetry.analyser_deg" if pem else "polarimetry.steps",
            f"expands to {len(out)} points; at most {MAX_POINTS}")])
    return out


def _dark_per_row(body: list[ScanPoint]) -> list[ScanPoint]:
    """A dark point (light off, no move) before every row: each run of points at one θi
    and one filter, in execution order."""
    out: list[ScanPoint] = []
    row: tuple[Any, ...] | None = None
    for p in body:
        key = (None if p.angles is None else round(p.angles.theta_i, 6),
               dict(p.meta).get("filter"))
        if p.light and key != row:
            out.append(ScanPoint(0, (), None, "dark", False, None))
            row = key
        out.append(p)
    return out


def filter_bands(profile: BenchProfile) -> dict[int, tuple[float, float]] | None:
    """Slot → (centre, FWHM) in nm of the bench's filter wheel (``options.filters`` of
    its ``fw102c`` device); None when the bench has no filter wheel."""
    wheels = [d for d in profile.devices.values() if d.driver == "fw102c"]
    if not wheels:
        return None
    out = {}
    for key, spec in dict(wheels[0].options.get("filters", {})).items():
        if isinstance(spec, dict) and "center_nm" in spec and "bandwidth_nm" in spec:
            out[int(key)] = (float(spec["center_nm"]), float(spec["bandwidth_nm"]))
    return out


def nd_slots_of(profile: BenchProfile) -> set[int]:
    """The slots of the bench's filter wheel that hold a neutral-density filter (``od``
    in its ``options.filters``)."""
    return set(nd_densities(profile))


def nd_densities(profile: BenchProfile) -> dict[int, float]:
    """Slot → optical density of the bench's neutral-density filters (``od`` in its
    filter wheel's ``options.filters``); empty without any."""
    wheels = [d for d in profile.devices.values() if d.driver == "fw102c"]
    if not wheels:
        return {}
    return {int(k): float(v["od"]) for k, v in dict(wheels[0].options.get("filters",
                                                                           {})).items()
            if isinstance(v, dict) and "od" in v}


def _check_power_meter_wavelength(spec: PlanSpec, profile: BenchProfile) -> None:
    """A power meter set to another wavelength than the light it reads corrects it with the
    wrong responsivity: refused before the run where the profile states both (a simulated
    source's wavelength; with a wavelength axis the engine sets the meter per filter)."""
    if not spec.acquisition.uses_power_meter or spec.spectral is not None:
        return
    src = dict((profile.simulation or {}).get("source", {}))
    meters = [(role, d) for role, d in profile.devices.items() if d.kind == "power_meter"]
    if "wavelength_nm" not in src or not meters:
        return
    lam, width = float(src["wavelength_nm"]), float(src.get("bandwidth_nm", 0.0))
    role, meter = meters[0]
    set_nm = meter.settings.get("wavelength_nm")
    if set_nm is not None and abs(float(set_nm) - lam) > max(1.0, 0.5 * width):
        raise PlanError(f"plan {spec.name!r} on bench {profile.name!r}", [FieldError(
            f"devices.{role}.settings.wavelength_nm", f"the power meter is set to "
            f"{float(set_nm):g} nm but the source emits at {lam:g} nm: set the meter to the "
            "source's wavelength (its responsivity correction depends on it)")])


def _wavelength_axis(spec: PlanSpec, profile: BenchProfile, body: list[ScanPoint]
                     ) -> list[ScanPoint]:
    """``body`` once per filter of ``[spectral]`` (meta ``filter``), in its order.

    Refuses, naming the field, a bench without a filter wheel, a slot whose band the
    profile does not give, and (on a simulated bench, whose source spectrum is known) a
    filter outside the source's band: its points would be dark. A list that names a
    neutral-density filter is an ND calibration (``examples/calibration_nd.toml``): its
    slots are ND filters and open slots (the reference reading), all of one wavelength.
    """
    sp = spec.spectral or {}
    bands = filter_bands(profile)
    nd = nd_slots_of(profile)
    if nd & set(sp["filters"]):
        both = sorted(set(sp["filters"]) & set(bands or {}))
        if both:
            raise PlanError(f"plan {spec.name!r}", [FieldError(
                "spectral.filters", f"mixes neutral-density filters with band-pass slot(s) "
                f"{both}: an ND calibration reads ND filters against an open slot")])
        return [replace(p, meta=(*p.meta, ("filter", f)))
                for f in sp["filters"] for p in body]
    errors = []
    if bands is None:
        errors.append(FieldError("spectral", f"bench {profile.name!r} has no filter wheel "
                                 "(a device with driver 'fw102c')"))
        bands = {}
    missing = [f for f in sp["filters"] if f not in bands]
    if missing and not errors:
        errors.append(FieldError("spectral.filters", f"slot(s) {missing} have no band in the "
                                 "bench profile: give center_nm and bandwidth_nm in the "
                                 "filter wheel's options.filters"))
    src = dict((profile.simulation or {}).get("source", {}))
    if "wavelength_nm" in src and not errors:
        lam, width = float(src["wavelength_nm"]), float(src.get("bandwidth_nm", 0.0))
        for f in sp["filters"]:
            centre, fwhm = bands[f]
            if abs(centre - lam) > 0.5 * (width + fwhm):
                errors.append(FieldError("spectral.filters", f"slot {f} ({centre:g} nm) is "
                                         f"outside the source's band ({lam:g} ± "
                                         f"{width / 2:g} nm): its points would be dark"))
    if errors:
        raise PlanError(f"plan {spec.name!r}", errors)
    out = []
    for k, f in enumerate(sp["filters"]):
        block = body[::-1] if sp["order"] == "motion" and k % 2 else body
        out += [replace(p, meta=(*p.meta, ("filter", f))) for p in block]
    return out
