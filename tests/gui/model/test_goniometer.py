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
