"""Type (i) goniometer (ADR 0099): profile keys, kinematics, the guard's arm rules, routes
between poses, manual moves and the cost of concurrent arm moves."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from instrument.bench import arms, guard
from instrument.bench.dynamics import AxisDynamics, dynamics_of, move_progress, move_time
from instrument.bench.kinematics import (
    TYPE_I_AXES,
    Angles,
    OutOfPlaneKinematics,
    TypeIKinematics,
    kinematics_of,
    positions_close,
)
from instrument.bench.manual import MoveRefused, plan_manual_move
from instrument.bench.profile import ProfileError, builtin_profiles, load_profile, parse_profile
from instrument.plans.commands import ScanPoint
from instrument.plans.order import optimise_order

PROFILE = load_profile("sim-type-i")
GEO = PROFILE.geometry
LIMITS = {r: d.limits for r, d in PROFILE.axes.items()}
DYN = dynamics_of(PROFILE, TYPE_I_AXES)
KIN = kinematics_of(GEO)

#: A type (i) bench written by hand: arms of declared widths, one table per rule's test.
HAND = '[bench]\nname = "hand-type-i"\n' + "".join(
    f'[devices.{role}]\ndriver = "thorlabs_apt"\nurl = "simapt://{role}?model=K10CR1"\n'
    f"limits = {lim}\n"
    for role, lim in (("source_arc", "[-90.0, 90.0]"), ("source_azimuth", "[-180.0, 180.0]"),
                      ("detector_arc", "[-90.0, 90.0]"),
                      ("detector_azimuth", "[-180.0, 180.0]"))) + """
[geometry]
goniometer = "type_i"
detector_distance_mm = {r_d}
detector_aperture_mm = 5.0
beam_radius_mm = 2.0
[geometry.source_arm]
radius_mm = {r_s}
width_mm = {w_s}
[geometry.detector_arm]
width_mm = {w_d}
"""


def hand(r_s: float = 400.0, w_s: float = 40.0, r_d: float = 300.0, w_d: float = 14.0):
    return parse_profile(HAND.format(r_s=r_s, w_s=w_s, r_d=r_d, w_d=w_d))


def point(pose: dict[str, float], *, light: bool = True, index: int = 0) -> ScanPoint:
    return ScanPoint(index, tuple(pose.items()), KIN.angles(pose), "sample", light)


# ------------------------------------------------------------------ profile


def test_every_other_builtin_profile_stays_type_ii():
    for name in builtin_profiles():
        geo = load_profile(name).geometry
        assert geo.is_type_i == (name == "sim-type-i"), name
        if name != "sim-type-i":
            assert geo.goniometer == "type_ii" and geo.source_arm is None


def test_the_builtin_type_i_bench_has_both_arms_on_emulated_stages():
    assert GEO.kind == "out_of_plane" and GEO.reaches_hemisphere
    assert set(TYPE_I_AXES) <= set(PROFILE.axes)
    assert {PROFILE.devices[r].driver for r in TYPE_I_AXES} == {
        "thorlabs_apt", "zaber", "newport_smc100"}
    assert GEO.detector_arm is not None and GEO.detector_arm.radius_mm == 300.0


@pytest.mark.parametrize("change, path", [
    (('goniometer = "type_i"', 'goniometer = "type_3"'), "geometry.goniometer"),
    (("width_mm = 40.0", "width_mm = -1.0"), "geometry.source_arm.width_mm"),
    (("radius_mm = 400.0\n", ""), "geometry.source_arm.radius_mm"),
    (("[geometry.detector_arm]\nwidth_mm = 14.0", ""), "geometry.detector_arm"),
    (('goniometer = "type_i"', 'goniometer = "type_i"\nkind = "in_plane"'), "geometry.kind"),
    (("width_mm = 14.0", "width_mm = 14.0\nradius_mm = 3.0"), "geometry.detector_arm.radius_mm"),
])
def test_bad_type_i_keys_name_their_field(change, path):
    text = HAND.format(r_s=400.0, w_s=40.0, r_d=300.0, w_d=14.0).replace(*change)
    with pytest.raises(ProfileError) as err:
        parse_profile(text)
    assert path in [e.path for e in err.value.errors]


def test_arms_on_a_type_ii_bench_are_refused():
    text = HAND.format(r_s=400.0, w_s=40.0, r_d=300.0, w_d=14.0).replace(
        'goniometer = "type_i"', 'goniometer = "type_ii"')
    with pytest.raises(ProfileError) as err:
        parse_profile(text)
    assert {"geometry.source_arm", "geometry.detector_arm"} <= {e.path for e in err.value.errors}


values = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6),
                   st.text(max_size=3), st.booleans())


@settings(max_examples=150, deadline=None)
@given(st.dictionaries(st.sampled_from(["radius_mm", "width_mm", "arc_offset_deg",
                                        "azimuth_offset_deg", "field_of_view_deg", "colour"]),
                       values, max_size=6))
def test_the_arm_validator_accepts_exactly_the_documented_values(table):
    """Any source_arm table: either a valid arm with every value in its range, or errors
    that all name a field of geometry.source_arm."""
    def toml(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + re.sub(r'[\\"\x00-\x1f\x7f]', "", v) + '"'
        if isinstance(v, float) and not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        return repr(v)

    body = "".join(f"{k} = {toml(v)}\n" for k, v in table.items())
    text = re.sub(r"\[geometry.source_arm\]\nradius_mm = 400.0\nwidth_mm = 40.0\n",
                  "[geometry.source_arm]\n" + body,
                  HAND.format(r_s=400.0, w_s=40.0, r_d=300.0, w_d=14.0))
    try:
        arm = parse_profile(text).geometry.source_arm
    except ProfileError as err:
        assert all(e.path.startswith("geometry.source_arm") for e in err.errors), err
        return
    assert arm is not None
    assert 1.0 <= arm.radius_mm <= 1e5 and 0 < arm.width_mm < 2 * arm.radius_mm
    assert "colour" not in table and "field_of_view_deg" not in table


# ------------------------------------------------------------------ kinematics


arc = st.floats(-89.0, 89.0, allow_nan=False)
azimuth = st.floats(-179.0, 179.0, allow_nan=False)
offset = st.floats(-90.0, 90.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(arc, azimuth, arc, azimuth, offset, offset)
def test_positions_to_angles_and_back_reach_the_same_directions(a_s, p_s, a_d, p_d, o1, o2):
    kin = TypeIKinematics(offsets={"source_arc": o1, "detector_azimuth": o2})
    pos = {"source_arc": a_s + o1, "source_azimuth": p_s, "detector_arc": a_d,
           "detector_azimuth": p_d + o2}
    angles = kin.angles(pos)
    for sol in kin.solutions(angles):
        for arm in ("source", "detector"):
            assert np.allclose(kin.arm_direction(sol, arm), kin.arm_direction(pos, arm),
                               atol=1e-9)
    # the positive-arc solution is the pose itself when its arcs are positive
    if a_s > 1e-6 and a_d > 1e-6:
        assert positions_close(kin.solutions(angles)[0], pos, TYPE_I_AXES, tol=1e-7)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 89.0), st.floats(0.0, 359.9), st.floats(0.0, 89.0), st.floats(0.0, 359.9))
def test_angles_to_positions_and_back(ti, pi, tr, pr):
    a = Angles(ti, pi, tr, pr)
    for sol in KIN.solutions(a):
        back = KIN.angles(sol)
        assert np.allclose(back.omega_i, a.omega_i, atol=1e-9)
        assert np.allclose(back.omega_r, a.omega_r, atol=1e-9)


def test_arm_readings_follow_the_documented_convention():
    # source_arc reads θ + arc_offset (−60): a head at 30° from the pole on azimuth 0
    a = KIN.angles({"source_arc": -30.0, "source_azimuth": 0.0, "detector_arc": 100.0,
                    "detector_azimuth": 180.0})
    assert a.as_tuple() == pytest.approx((30.0, 0.0, 40.0, 180.0))
    # a negative arc reaches the far side of the rail: φ + 180°
    a = KIN.angles({"source_arc": -90.0, "source_azimuth": 10.0, "detector_arc": 60.0,
                    "detector_azimuth": 0.0})
    assert (a.theta_i, a.phi_i) == pytest.approx((30.0, 190.0))
    assert a.theta_r == pytest.approx(0.0, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(st.floats(1.0, 80.0), st.floats(0.0, 359.0), st.floats(1.0, 80.0), st.floats(0.0, 359.0))
def test_the_same_angles_mean_the_same_directions_on_both_types(ti, pi, tr, pr):
    """Type (ii) out-of-plane and type (i) realise (θi, φi, θr, φr) as the same pair of
    sample-frame directions, and so the same lab bistatic angle."""
    a = Angles(ti, pi, tr, pr)
    assume(2.0 < a.bistatic_deg < 178.0)
    ii = OutOfPlaneKinematics()
    assume(ii.solutions(a))
    pos_ii = ii.solutions(a)[0]
    pos_i = KIN.positions(a)
    on_ii, on_i = ii.angles(pos_ii), KIN.angles(pos_i)
    for got in (on_ii, on_i):
        assert np.allclose(got.omega_i, a.omega_i, atol=1e-7)
        assert np.allclose(got.omega_r, a.omega_r, atol=1e-7)
    # lab frame: the angle between the source and the detector is the same
    assert abs(pos_ii["detector_theta"]) == pytest.approx(
        float(arms.separation_deg(KIN, {r: np.asarray(v) for r, v in pos_i.items()})),
        abs=1e-6)


# ------------------------------------------------------------------ guard


def test_arms_closer_than_their_widths_are_refused_light_or_not():
    pose = KIN.positions(Angles(30.0, 0.0, 32.0, 3.0))
    for light in (True, False):
        reasons = {v.reason for v in guard.check([point(pose, light=light)], PROFILE)}
        assert "arms" in reasons
    assert not guard.check([point(KIN.positions(Angles(30.0, 0.0, 30.0, 180.0)))], PROFILE)


def test_an_inner_detector_arm_shadowing_the_beam_is_refused_only_with_light():
    # narrow detector head (4 mm) inside the source arm: its own width keeps it 0.8° from
    # the source head, the beam (2 mm radius) needs r_d·sinδ ≥ 2 + 2 mm: δ ≥ 0.76°...
    prof = hand(r_s=400.0, w_s=4.0, r_d=150.0, w_d=4.0)
    kin = kinematics_of(prof.geometry)
    touch = prof.geometry.source_arm.half_width_deg + prof.geometry.detector_arm.half_width_deg
    delta = touch + 0.2  # the heads clear, the detector still in the beam (< 1.53°)
    assert 150.0 * math.sin(math.radians(delta)) < 4.0
    pose = kin.positions(Angles(40.0, 0.0, 40.0 + delta, 0.0))
    lit = guard.check([ScanPoint(0, tuple(pose.items()), kin.angles(pose), "sample", True)], prof)
    assert [v.reason for v in lit] == ["beam"]
    assert "shadows the incident beam" in lit[0].detail
    dark = guard.check([ScanPoint(0, tuple(pose.items()), kin.angles(pose), "dark", False)],
                       prof)
    assert dark == []


def test_a_source_arm_inside_the_detectors_view_is_refused():
    # the view cone of 2° beyond the 5 mm aperture is 2.5·150/400 + 250·tan 1° = 5.3 mm
    # wide at the source head's radius: with its 2 mm, δ < asin(7.3/150) = 2.8° is in view
    text = HAND.format(r_s=150.0, w_s=4.0, r_d=400.0, w_d=4.0).replace(
        "[geometry.detector_arm]", "[geometry.detector_arm]\nfield_of_view_deg = 2.0")
    prof = parse_profile(text)
    kin = kinematics_of(prof.geometry)
    pose = kin.positions(Angles(40.0, 0.0, 42.0, 0.0))
    got = guard.check([ScanPoint(0, tuple(pose.items()), kin.angles(pose), "sample", True)],
                      prof)
    assert [v.reason for v in got] == ["view"]
    assert "field of view" in got[0].detail


def test_type_i_limits_are_the_axes_limits():
    pose = {"source_arc": 30.0, "source_azimuth": 0.0, "detector_arc": 100.0,
            "detector_azimuth": 0.0}  # source_arc limit 25
    got = guard.check([point(pose)], PROFILE)
    assert any(v.reason == "limits" and "source_arc" in v.detail for v in got)


# ------------------------------------------------------------------ paths


def test_move_progress_is_the_trapezoid_of_move_time():
    dyn = AxisDynamics(10.0, 10.0)
    for d in (0.5, 40.0, -40.0):
        t_end = move_time(d, dyn)
        t = np.linspace(0.0, t_end, 2001)
        x = move_progress(d, dyn, t)
        assert x[0] == 0.0 and x[-1] == pytest.approx(d)
        assert np.all(np.diff(x) * math.copysign(1, d) >= -1e-12)
        assert np.max(np.abs(np.diff(x))) / (t[1] - t[0]) <= dyn.velocity * (1 + 1e-9)


def test_a_move_whose_ends_are_allowed_but_which_crosses_the_other_arm_is_split():
    here = KIN.positions(Angles(20.0, 0.0, 70.0, 0.0), limits=LIMITS)
    there = KIN.positions(Angles(20.0, 0.0, 10.0, 0.0), limits=LIMITS)
    assert not guard.check([point(here), point(there)], PROFILE)
    assert not arms.path_clear(GEO, DYN, here, there).clear
    route = arms.safe_route(GEO, DYN, here, there, limits=LIMITS)
    assert route is not None and route.split and route.moves[-1] == there
    at = here
    for leg in route.moves:
        assert dense_min_separation(at, leg) > touch_deg()
        at = leg


def touch_deg() -> float:
    return GEO.source_arm.half_width_deg + GEO.detector_arm.half_width_deg


def dense_min_separation(here, there, n: int = 20000) -> float:
    """The closest approach of a timed move, sampled far finer than path_clear does."""
    dist = {r: there[r] - here[r] for r in TYPE_I_AXES}
    total = max(move_time(d, DYN[r]) for r, d in dist.items())
    t = np.linspace(0.0, total, n)
    poses = {r: here[r] + move_progress(dist[r], DYN[r], t) for r in TYPE_I_AXES}
    return float(arms.separation_deg(KIN, poses).min())


upper = st.tuples(st.floats(5.0, 80.0), st.floats(0.0, 359.0))


@settings(max_examples=60, deadline=None)
@given(upper, upper, upper, upper)
def test_every_route_found_keeps_the_arms_apart_on_a_dense_check(s1, d1, s2, d2):
    here = KIN.positions(Angles(*s1, *d1), limits=LIMITS)
    there = KIN.positions(Angles(*s2, *d2), limits=LIMITS)
    assume(not guard.check([point(here), point(there)], PROFILE))
    route = arms.safe_route(GEO, DYN, here, there, limits=LIMITS)
    if route is None:
        return
    at = here
    for leg in route.moves:
        assert dense_min_separation(at, leg, 4000) >= touch_deg() - 1e-9
        assert all(LIMITS[r][0] - 1e-9 <= v <= LIMITS[r][1] + 1e-9 for r, v in leg.items())
        at = leg


def test_arms_swapped_on_a_ring_go_over_each_other_and_without_room_are_refused():
    """Both heads on one ring (θ 30°), each where the other must go: no azimuth turn gets
    one past the other, so the route lifts one arm's arc over the other head. With the
    arcs held on that ring by their soft limits there is no route: ``path``."""
    here = KIN.positions(Angles(30.0, 0.0, 30.0, 180.0))
    there = KIN.positions(Angles(30.0, 180.0, 30.0, 0.0))
    there = {**there, "source_arc": here["source_arc"], "detector_arc": here["detector_arc"]}
    route = arms.safe_route(GEO, DYN, here, there, limits=LIMITS)
    assert route is not None and "over the other" in route.how
    at = here
    for leg in route.moves:
        assert dense_min_separation(at, leg) > touch_deg()
        at = leg
    held = {**LIMITS, "source_arc": (here["source_arc"] - 0.01, here["source_arc"] + 0.01),
            "detector_arc": (here["detector_arc"] - 0.01, here["detector_arc"] + 0.01)}
    assert arms.safe_route(GEO, DYN, here, there, limits=held) is None


# ------------------------------------------------------------------ manual moves


def test_a_jog_into_the_other_arm_is_refused_before_anything_moves():
    here = KIN.positions(Angles(30.0, 0.0, 40.0, 180.0))
    with pytest.raises(MoveRefused) as err:
        # the detector arc (azimuth 180°) at −30° + its offset 60°: onto the source head
        plan_manual_move(PROFILE, here, {"detector_arc": 30.0}, light=False)
    assert "arms" in {v.reason for v in err.value.violations}


def test_a_manual_move_through_the_other_arm_is_refused_as_path():
    here = KIN.positions(Angles(20.0, 0.0, 70.0, 0.0), limits=LIMITS)
    there = KIN.positions(Angles(20.0, 0.0, 10.0, 0.0), limits=LIMITS)
    with pytest.raises(MoveRefused) as err:
        plan_manual_move(PROFILE, here, {"detector_arc": there["detector_arc"]}, light=False)
    assert [v.reason for v in err.value.violations] == ["path"]
    assert "move one arm first" in str(err.value)
    # around it is allowed: azimuth aside, then the arc
    aside = plan_manual_move(PROFILE, here, {"detector_azimuth": 30.0}, light=False)
    plan_manual_move(PROFILE, aside.target_dict(), {"detector_arc": there["detector_arc"]},
                     light=False)


# ------------------------------------------------------------------ order


def test_a_step_costs_the_slower_arm_not_the_sum_of_the_arms():
    """Both arms move at once: the travel-optimised order prices a step as its slowest arm."""
    from instrument.bench.dynamics import route_time

    axes = TYPE_I_AXES
    a = [0.0, 0.0, 0.0, 0.0]
    b = [40.0, 0.0, 0.0, 0.0]      # the source arm alone
    c = [40.0, 0.0, 20.0, 0.0]     # both arms
    t_src = move_time(40.0, DYN["source_arc"])
    t_det = move_time(20.0, DYN["detector_arc"])
    _total, steps = route_time(np.array([a, c]), axes, DYN)
    assert steps[1] == pytest.approx(max(t_src, t_det))
    assert steps[1] < t_src + t_det
    assert route_time(np.array([a, b]), axes, DYN)[1][1] == pytest.approx(t_src)
    # the optimiser, on a line of points, orders them monotonically (least total time)
    pts = np.array([[x, 0.0, 2 * x, 0.0] for x in (0.0, 30.0, 10.0, 20.0, 40.0)])
    order = optimise_order(pts, axes, DYN)
    assert list(pts[order, 0]) in ([0.0, 10.0, 20.0, 30.0, 40.0],
                                   [40.0, 30.0, 20.0, 10.0, 0.0])
