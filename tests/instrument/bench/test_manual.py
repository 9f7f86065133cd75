"""Manual moves through the guard: the pose after the move is judged like a plan point."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from instrument.bench import guard
from instrument.bench.manual import (
    MoveRefused,
    check_light_on,
    manual_move,
    plan_home,
    plan_manual_move,
)
from instrument.bench.profile import parse_profile
from instrument.plans.commands import ScanPoint
from tests.instrument.helpers import IDEAL_PROFILE

COLLISION = """
[[geometry.collision]]
axis = "detector_theta"
relative_to = "sample_theta"
range = [95.0, 200.0]
reason = "arm passes behind the sample holder"
"""

PROFILE = parse_profile(IDEAL_PROFILE + COLLISION)
HERE = {"sample_theta": 20.0, "detector_theta": 40.0, "camera_z": 0.0}


def test_a_move_inside_everything_is_allowed_and_keeps_the_rest_of_the_pose():
    move = plan_manual_move(PROFILE, HERE, {"detector_theta": 60.0}, light=True)
    assert move.moved_targets() == {"detector_theta": 60.0}
    assert move.target_dict() == {"sample_theta": 20.0, "detector_theta": 60.0,
                                  "camera_z": 0.0}
    # θi = sample_theta, θr = |sample_theta − detector_theta| in plane (ADR 0012)
    assert move.angles.theta_i == pytest.approx(20.0)
    assert move.angles.theta_r == pytest.approx(40.0)


def test_outside_the_soft_limits_is_refused_with_the_limit():
    with pytest.raises(MoveRefused) as exc:
        plan_manual_move(PROFILE, HERE, {"sample_theta": 95.0}, light=False)
    reasons = {v.reason for v in exc.value.violations}
    assert "limits" in reasons
    assert "outside the soft limits [-90, 90]" in str(exc.value)


def test_into_the_beam_is_refused_only_with_the_light_on():
    with pytest.raises(MoveRefused) as exc:
        plan_manual_move(PROFILE, HERE, {"detector_theta": 2.0}, light=True)
    assert [v.reason for v in exc.value.violations] == ["beam"]
    assert "incident beam" in str(exc.value)
    # dark, the arm may stand there (dark frames are taken anywhere), as for a plan
    plan_manual_move(PROFILE, HERE, {"detector_theta": 2.0}, light=False)


def test_a_collision_zone_relative_to_another_axis_uses_its_present_position():
    with pytest.raises(MoveRefused) as exc:
        plan_manual_move(PROFILE, {"sample_theta": -10.0, "detector_theta": 40.0},
                         {"detector_theta": 100.0}, light=False)
    assert "collision" in {v.reason for v in exc.value.violations}
    assert "behind the sample holder" in str(exc.value)


def test_unhomed_axes_left_out_of_the_pose_give_no_angles_and_no_beam_check():
    move = plan_manual_move(PROFILE, {}, {"detector_theta": 1.0}, light=True)
    assert move.angles is None


def test_home_is_a_move_to_the_reference():
    with pytest.raises(MoveRefused):  # the arm would swing into the lit beam
        plan_home(PROFILE, HERE, "detector_theta", light=True)
    assert plan_home(PROFILE, HERE, "detector_theta", light=False).what == "home"


def test_light_on_with_the_arm_in_the_beam_is_refused():
    assert check_light_on(PROFILE, HERE) == []
    bad = check_light_on(PROFILE, {"sample_theta": 20.0, "detector_theta": 1.0})
    assert [v.reason for v in bad] == ["beam"]
    assert check_light_on(PROFILE, {}) == []


def test_non_finite_targets_are_bad_arguments():
    with pytest.raises(ValueError, match="finite"):
        manual_move(PROFILE, HERE, {"sample_theta": float("nan")}, light=False)
    with pytest.raises(ValueError, match="at least one"):
        manual_move(PROFILE, HERE, {}, light=False)


@given(st.floats(-120, 120), st.floats(-200, 200), st.booleans())
def test_the_verdict_is_the_guards_verdict_on_the_same_point(sample, detector, light):
    """A manual move is refused exactly when the plan guard refuses the same point."""
    from instrument.bench.kinematics import InPlaneKinematics

    pose = {"sample_theta": sample, "detector_theta": detector}
    plan_point = ScanPoint(0, tuple(pose.items()), InPlaneKinematics().angles(pose),
                           light=light)
    expected = guard.check([plan_point], PROFILE)
    try:
        plan_manual_move(PROFILE, {}, pose, light=light)
        got = []
    except MoveRefused as err:
        got = err.violations
    assert [(v.reason, v.detail) for v in got] == [(v.reason, v.detail) for v in expected]
