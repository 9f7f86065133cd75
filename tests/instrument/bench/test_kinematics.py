"""Kinematics: both directions, sign conventions, handedness, round trips (hypothesis)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from instrument.bench.kinematics import (
    Angles,
    InPlaneKinematics,
    OutOfPlaneKinematics,
    positions_close,
    same_directions,
    wrap180,
)

deg = st.floats(-89.0, 89.0, allow_nan=False)


def test_in_plane_conventions():
    kin = InPlaneKinematics()
    # Normal incidence: sample faces the source.
    a = kin.angles({"sample_theta": 0.0, "detector_theta": 30.0})
    assert a.theta_i == pytest.approx(0.0) and a.theta_r == pytest.approx(30.0)
    # Specular: detector arm at twice the sample rotation, on the far side of the normal.
    a = kin.angles({"sample_theta": 25.0, "detector_theta": 50.0})
    assert (a.theta_i, a.phi_i) == pytest.approx((25.0, 0.0))
    assert (a.theta_r, a.phi_r) == pytest.approx((25.0, 180.0))
    assert a.bistatic_deg == pytest.approx(50.0)
    # Detector on the source side (backscatter side) keeps φr = φi.
    a = kin.angles({"sample_theta": 40.0, "detector_theta": 10.0})
    assert (a.theta_r, a.phi_r) == pytest.approx((30.0, 0.0))
    # Negative sample rotation puts the source at φi = 180°.
    assert kin.angles({"sample_theta": -20.0, "detector_theta": 10.0}).phi_i == 180.0


@settings(max_examples=200, deadline=None)
@given(deg, st.floats(-170.0, 170.0))
def test_in_plane_round_trip(sample_theta, detector_theta):
    kin = InPlaneKinematics(source_theta_deg=12.0)
    pos = {"sample_theta": sample_theta, "detector_theta": detector_theta}
    back = kin.positions(kin.angles(pos))
    assert positions_close(back, pos, kin.axes, tol=1e-9)


@settings(max_examples=200, deadline=None)
@given(deg, st.floats(-170.0, 170.0))
def test_in_plane_closed_form_matches_rotation_matrices(sample_theta, detector_theta):
    """The closed form and the general sample→lab rotation agree (one convention)."""
    kin = InPlaneKinematics(source_theta_deg=-30.0)
    pos = {"sample_theta": sample_theta, "detector_theta": detector_theta}
    a = kin.angles(pos)
    b = kin._angles_general(pos)
    assume(a.theta_r < 179.0)
    assert same_directions(a, b, tol=1e-9)


def test_sample_frame_is_right_handed_and_in_plane_at_zero():
    kin = OutOfPlaneKinematics()
    for pos in ({}, {"sample_theta": 33.0, "sample_tilt": 20.0, "sample_phi": -70.0}):
        m = kin.sample_to_lab(pos)
        assert np.linalg.det(m) == pytest.approx(1.0)
        assert np.allclose(m.T @ m, np.eye(3))
    m = kin.sample_to_lab({"sample_theta": 0.0})
    assert np.allclose(m[:, 2], [1, 0, 0])   # normal points at the source (+X)
    assert np.allclose(m[:, 1], [0, 0, -1])  # sample y points down
    # A positive tilt raises the normal above the horizontal plane.
    assert kin.sample_to_lab({"sample_tilt": 10.0})[2, 2] > 0


@settings(max_examples=300, deadline=None)
@given(st.floats(-80.0, 80.0), st.floats(-80.0, 80.0), st.floats(-179.0, 179.0),
       st.floats(-170.0, 170.0))
def test_out_of_plane_round_trip_positions(sample_theta, tilt, phi, detector_theta):
    assume(abs(detector_theta) > 1.0)
    kin = OutOfPlaneKinematics(source_theta_deg=5.0)
    pos = {"sample_theta": sample_theta, "sample_tilt": tilt, "sample_phi": phi,
           "detector_theta": detector_theta}
    sols = kin.solutions(kin.angles(pos))
    assert any(positions_close(s, pos, kin.axes, tol=1e-6) for s in sols)
    for s in sols:  # every solution realises the same directions
        assert same_directions(kin.angles(s), kin.angles(pos), tol=1e-7)


@settings(max_examples=300, deadline=None)
@given(st.floats(0.0, 85.0), st.floats(0.0, 360.0), st.floats(0.0, 85.0),
       st.floats(0.0, 360.0))
def test_out_of_plane_round_trip_angles(ti, pi, tr, pr):
    a = Angles(ti, pi, tr, pr)
    assume(2.0 < a.bistatic_deg < 178.0)
    kin = OutOfPlaneKinematics()
    sols = kin.solutions(a)
    assert len(sols) >= 1
    for s in sols:
        assert same_directions(kin.angles(s), a, tol=1e-7)


@settings(max_examples=100, deadline=None)
@given(deg, st.floats(-170.0, 170.0))
def test_out_of_plane_reduces_to_in_plane(sample_theta, detector_theta):
    pos = {"sample_theta": sample_theta, "sample_tilt": 0.0, "sample_phi": 0.0,
           "detector_theta": detector_theta}
    a = OutOfPlaneKinematics().angles(pos)
    b = InPlaneKinematics().angles(pos)
    assume(b.theta_r < 179.0)
    assert same_directions(a, b, tol=1e-9)


def test_unreachable_in_plane_out_of_plane_angles():
    kin = InPlaneKinematics()
    assert kin.solutions(Angles(30.0, 45.0, 30.0, 225.0)) == []
    with pytest.raises(ValueError, match="cannot be reached"):
        kin.positions(Angles(30.0, 45.0, 30.0, 225.0))


def test_out_of_plane_azimuth_is_rotation_about_normal():
    """Turning the azimuth stage by +δ lowers every sample-frame φ by δ."""
    kin = OutOfPlaneKinematics()
    base = {"sample_theta": 30.0, "sample_tilt": 10.0, "sample_phi": 0.0,
            "detector_theta": 70.0}
    a0 = kin.angles(base)
    a1 = kin.angles({**base, "sample_phi": 15.0})
    assert a1.theta_i == pytest.approx(a0.theta_i)
    assert wrap180(a1.phi_i - a0.phi_i) == pytest.approx(-15.0)
    assert wrap180(a1.phi_r - a0.phi_r) == pytest.approx(-15.0)


def test_wrap180():
    assert wrap180(190.0) == pytest.approx(-170.0)
    assert wrap180(-180.0) == pytest.approx(180.0)
    assert math.isclose(wrap180(360.0), 0.0, abs_tol=1e-12)


@settings(max_examples=150, deadline=None)
@given(st.floats(-80.0, 80.0), st.floats(-60.0, 60.0), st.floats(-179.0, 179.0),
       st.floats(-170.0, 170.0))
def test_agrees_with_the_virtual_bench_written_independently(st_, tilt, phi, dt):
    """hw_mocks.sim.world derives the sample frame on its own (rotations about its y axis);
    both must give the same sample-frame directions for the same axis readings."""
    from hw_mocks.sim.world import VirtualBench

    pos = {"sample_theta": st_, "sample_tilt": tilt, "sample_phi": phi, "detector_theta": dt}
    pose = VirtualBench("kinematics-check").pose(pos)
    ti, pi = pose.local_angles(pose.source_dir)
    tr, pr = pose.local_angles(pose.detector_dir)
    world = Angles(math.degrees(ti), math.degrees(pi), math.degrees(tr), math.degrees(pr))
    ours = OutOfPlaneKinematics().angles(pos)
    # 1e-6: the world takes θ with arccos, which loses ~1e-8 rad near the pole.
    assert same_directions(ours, world, tol=1e-6)
