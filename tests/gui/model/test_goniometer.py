"""The goniometer drawing's geometry (Qt-free)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gui.model.goniometer import hemisphere_view, top_view
from instrument.bench.kinematics import Angles
from instrument.bench.profile import load_profile, parse_profile
from tests.instrument.helpers import IDEAL_PROFILE

ZONE = """
[[geometry.collision]]
axis = "detector_theta"
relative_to = "sample_theta"
range = [95.0, 200.0]
reason = "behind the holder"
"""


def test_top_view_puts_arm_normal_and_beam_where_the_positions_say():
    prof = parse_profile(IDEAL_PROFILE + ZONE)
    R = prof.geometry.detector_distance_mm
    scene = top_view(prof, {"sample_theta": 20.0, "detector_theta": 40.0, "camera_z": 5.0})
    arm = scene.by_role("arm")[0].xy
    assert arm[1] == pytest.approx((R + 5) * np.array([math.cos(math.radians(40)),
                                                        math.sin(math.radians(40))]))
    normal = scene.by_role("normal")[0].xy[1]
    assert math.degrees(math.atan2(normal[1], normal[0])) == pytest.approx(20.0)
    beam = scene.by_role("beam")[0].xy
    assert beam[0][1] == pytest.approx(0.0) and beam[0][0] > R  # source on +X
    cone = scene.by_role("bistatic_cone")[0].xy
    az = np.degrees(np.arctan2(cone[:, 1], cone[:, 0]))
    assert az.min() == pytest.approx(-5.0) and az.max() == pytest.approx(5.0)
    zone = scene.by_role("collision")[0].xy
    zaz = np.degrees(np.arctan2(zone[:, 1], zone[:, 0])) % 360
    # the relative zone follows the sample: [95, 200] + 20
    assert zaz.min() == pytest.approx(115.0, abs=1e-6)
    assert zaz.max() == pytest.approx(220.0, abs=1e-6)


def test_plan_points_split_into_done_and_to_do():
    prof = parse_profile(IDEAL_PROFILE)
    planned = [{"sample_theta": 10.0, "detector_theta": d} for d in (20, 30, 40, 50)]
    scene = top_view(prof, {}, planned=planned, done=[True, True])
    assert len(scene.by_role("points_done")[0].xy) == 2
    assert len(scene.by_role("points_todo")[0].xy) == 2
    assert not scene.by_role("arm") and "not homed" in " ".join(scene.notes)


def test_hemisphere_view_of_an_out_of_plane_bench():
    prof = load_profile("sim_out_of_plane")
    kin_pos = {"sample_theta": 30.0, "sample_tilt": 0.0, "sample_phi": 0.0,
               "detector_theta": 60.0}
    scene = hemisphere_view(prof, kin_pos, planned_angles=[Angles(30, 0, 30, 180), None],
                            done=[True])
    inc = scene.by_role("incident")[0].xy[0]
    assert math.hypot(*inc) == pytest.approx(30.0)  # radius = θi
    det = scene.by_role("detector")[0].xy[0]
    assert math.hypot(*det) == pytest.approx(30.0)  # specular: θr = θi
    cone = scene.by_role("bistatic_cone")[0].xy
    assert np.all(np.hypot(cone[:, 0] - inc[0], cone[:, 1] - inc[1]) < 8.0)
    assert len(scene.by_role("points_done")[0].xy) == 1
    assert hemisphere_view(prof, {}).notes  # unhomed: directions unknown


def test_a_type_i_bench_is_drawn_as_its_arms_over_the_stationary_sample():
    from instrument.bench.kinematics import kinematics_of

    prof = load_profile("sim-type-i")
    kin = kinematics_of(prof.geometry)
    pose = kin.positions(Angles(30.0, 0.0, 40.0, 180.0))
    scene = top_view(prof, pose)
    assert "type (i)" in scene.title
    assert scene.by_role("stationary_sample")[0].xy.tolist() == [[0.0, 0.0]]
    # heads where the angles say (radius θ, azimuth φ); rails are diameters at their azimuth
    assert scene.by_role("incident")[0].xy[0] == pytest.approx((30.0, 0.0), abs=1e-9)
    assert scene.by_role("detector")[0].xy[0] == pytest.approx((-40.0, 0.0), abs=1e-9)
    rail = scene.by_role("detector_rail")[0].xy
    assert rail == pytest.approx(np.array([[-90.0, 0.0], [90.0, 0.0]]), abs=1e-9)
    # the zone where the arms touch: a ring of α_s + α_d around the source head
    touch = prof.geometry.source_arm.half_width_deg + prof.geometry.detector_arm.half_width_deg
    ring = scene.by_role("collision")[0].xy
    # (radius θ is exact in this projection; the azimuth is not: check along the radius)
    r = np.hypot(ring[:, 0], ring[:, 1])
    assert (r.min(), r.max()) == pytest.approx((30.0 - touch, 30.0 + touch), abs=1e-6)
    # an arm not homed is not drawn, and the caption says so
    partial = top_view(prof, {k: v for k, v in pose.items() if not k.startswith("detector")})
    assert not partial.by_role("detector") and "detector arm not homed" in partial.notes[0]


def test_the_type_i_view_shows_the_lit_zone_where_the_beam_rule_reaches_further():
    text = load_profile("sim-type-i").source_text.replace(
        "width_mm = 14.0", "width_mm = 4.0").replace(
        "detector_aperture_mm = 5.0", "detector_aperture_mm = 5.0\nbeam_radius_mm = 6.0")
    prof = parse_profile(text)
    from instrument.bench.kinematics import kinematics_of

    pose = kinematics_of(prof.geometry).positions(Angles(30.0, 0.0, 40.0, 180.0))
    lit = top_view(prof, pose).by_role("bistatic_cone")
    # detector head 300 mm out: w/2 + b = 8 mm from the beam axis, asin(8/300) = 1.53°...
    # ...wider than the heads' 2.86° + 0.38°? no: the ring is drawn only where it is wider
    touch = prof.geometry.source_arm.half_width_deg + prof.geometry.detector_arm.half_width_deg
    reach = math.degrees(math.asin(8.0 / 300.0))
    assert bool(lit) == (reach > touch)
