"""Guard (limits, beam, hemisphere, collisions) and the trapezoidal move-time model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from instrument.bench.dynamics import AxisDynamics, move_time, move_times, route_time
from instrument.bench.guard import GuardError, check, enforce
from instrument.bench.kinematics import Angles, InPlaneKinematics
from instrument.bench.profile import parse_profile
from instrument.plans.commands import ScanPoint
from tests.instrument.helpers import IDEAL_PROFILE

COLLISION = """
[[geometry.collision]]
axis = "detector_theta"
range = [150.0, 170.0]
reason = "arm hits the source housing"
[[geometry.collision]]
axis = "detector_theta"
relative_to = "sample_theta"
range = [95.0, 200.0]
reason = "arm passes behind the sample holder"
"""


def _point(i, st, dt):
    kin = InPlaneKinematics()
    pos = {"sample_theta": st, "detector_theta": dt}
    return ScanPoint(i, tuple(pos.items()), kin.angles(pos))


def test_guard_accepts_good_points():
    prof = parse_profile(IDEAL_PROFILE)
    assert check([_point(0, 20.0, 40.0), _point(1, -30.0, -80.0)], prof) == []


def test_guard_lists_every_offending_point_and_why():
    prof = parse_profile(IDEAL_PROFILE + COLLISION)
    pts = [
        _point(0, 20.0, 40.0),     # fine
        _point(1, 95.0, 40.0),     # sample outside [-90, 90] and θi ≥ 90
        _point(2, 20.0, 2.0),      # detector in the beam (bistatic 2° < 5°)
        _point(3, 10.0, 160.0),    # collision with the source housing, θr behind sample
        _point(4, -10.0, 100.0),   # arm behind the sample holder (relative zone)
    ]
    with pytest.raises(GuardError) as exc:
        enforce(pts, prof)
    v = exc.value.violations
    assert {x.index for x in v} == {1, 2, 3, 4}
    reasons = {(x.index, x.reason) for x in v}
    assert (1, "limits") in reasons and (1, "hemisphere") in reasons
    assert (2, "beam") in reasons
    assert (3, "collision") in reasons and (4, "collision") in reasons
    msg = str(exc.value)
    assert "4 of 5 point(s) rejected" in msg
    assert "point 2 (" in msg and "incident beam" in msg and "source housing" in msg
    assert "θi=" in msg  # points are described by their angles
    assert "every point is rejected" not in msg  # only when the bench looks wrong
    with pytest.raises(GuardError, match=r"every point is rejected: is the bench"):
        enforce(pts[1:], prof)


def test_guard_rejects_unknown_axis_and_dark_points_may_sit_in_beam():
    prof = parse_profile(IDEAL_PROFILE)
    bad = ScanPoint(0, (("sample_phi", 0.0),), None)
    assert check([bad], prof)[0].reason == "missing_axis"
    dark = ScanPoint(1, (("sample_theta", 0.0), ("detector_theta", 0.0)),
                     Angles(0, 0, 0, 0), label="dark", light=False)
    assert all(v.reason != "beam" for v in check([dark], prof))


def test_move_time_trapezoid_and_triangle():
    dyn = AxisDynamics(velocity=10.0, acceleration=20.0)
    # Long move: cruise phase. d/v + v/a
    assert move_time(100.0, dyn) == pytest.approx(100 / 10 + 10 / 20)
    # Short move: triangular, 2 sqrt(d/a)
    assert move_time(1.0, dyn) == pytest.approx(2 * math.sqrt(1 / 20))
    # Continuous at the switch-over d = v²/a = 5
    assert move_time(5.0 - 1e-9, dyn) == pytest.approx(move_time(5.0 + 1e-9, dyn), rel=1e-6)
    assert move_time(0.0, dyn) == 0.0
    d = np.array([0.0, 1.0, -5.0, 100.0])
    assert np.allclose(move_times(d, dyn), [move_time(x, dyn) for x in d])


def test_route_time_slowest_axis_sets_each_step():
    dyn = {"a": AxisDynamics(10.0, 10.0), "b": AxisDynamics(1.0, 1.0)}
    t = np.array([[0.0, 0.0], [10.0, 1.0], [10.0, 3.0]])
    total, steps = route_time(t, ("a", "b"), dyn)
    ta = move_time(10.0, dyn["a"])
    tb = move_time(1.0, dyn["b"])
    assert steps[1] == pytest.approx(max(ta, tb))
    assert steps[2] == pytest.approx(move_time(2.0, dyn["b"]))
    assert total == pytest.approx(steps.sum())


def test_profile_geometry_extensions_validate_fields():
    from instrument.bench.profile import ProfileError

    bad = IDEAL_PROFILE.replace("velocity = 10.0\n", "velocity = 10.0\nsettle_s = -1\n", 1)
    bad += """
[[geometry.collision]]
axis = "nozzle"
range = [5.0, 1.0]
"""
    with pytest.raises(ProfileError) as exc:
        parse_profile(bad)
    paths = {e.path for e in exc.value.errors}
    assert {"devices.sample_theta.settle_s", "geometry.collision[0].axis",
            "geometry.collision[0].range"} <= paths
    ok = parse_profile(IDEAL_PROFILE.replace("velocity = 10.0\n",
                                             "velocity = 10.0\nsettle_s = 0.02\n", 1)
                       + COLLISION)
    assert ok.devices["sample_theta"].settle_s == 0.02
    assert len(ok.geometry.collisions) == 2
    assert ok.geometry.collisions[1].relative_to == "sample_theta"
