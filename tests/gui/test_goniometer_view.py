"""The goniometer view follows the emulators' read-back positions."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hw_mocks import registry
from tests.gui.conftest import connect


def test_the_drawing_follows_the_stages(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    view = w.goniometer
    qtbot.waitUntil(lambda: view.scene is not None and view.profile is not None, timeout=60000)
    assert not view.scene.by_role("arm")  # not homed: the arm's position is unknown
    for role in ("sample_theta", "detector_theta"):
        w.bench_panel.panels[role].home.click()
    det = w.bench_panel.panels["detector_theta"]
    qtbot.waitUntil(lambda: w.session.states()["detector_theta"].value("homed")
                    and w.session.states()["sample_theta"].value("homed"), timeout=60000)
    det.target.setValue(40.0)
    det.go.click()
    sample = w.bench_panel.panels["sample_theta"]
    sample.target.setValue(15.0)
    sample.go.click()

    def arm_at(angle):
        arms = view.scene.by_role("arm") if view.scene else []
        if not arms:
            return False
        x, y = arms[0].xy[1]
        return abs(math.degrees(math.atan2(y, x)) - angle) < 0.01

    qtbot.waitUntil(lambda: arm_at(40.0), timeout=60000)
    stage = registry.get("simsmc", "detector_theta").stage.physical_position()
    x, y = view.scene.by_role("arm")[0].xy[1]
    assert math.degrees(math.atan2(y, x)) == pytest.approx(stage, abs=0.01)
    qtbot.waitUntil(lambda: abs(np.degrees(np.arctan2(*view.scene.by_role("normal")[0].xy[1]
                                                      [::-1])) - 15.0) < 0.02, timeout=60000)
    assert "min_bistatic" not in view.caption.text()
    assert view.scene.by_role("bistatic_cone")


def test_a_type_i_bench_draws_both_arms_the_sample_and_the_zones(qtbot, tmp_path):
    """The view alone, given the sim-type-i profile, a pose and a plan (no bench open)."""
    from gui.qt.goniometer_view import GoniometerView
    from instrument.bench.kinematics import Angles, kinematics_of
    from instrument.bench.profile import load_profile
    from instrument.plans.build import build_plan
    from instrument.plans.planfile import load_plan

    root = Path(__file__).resolve().parents[2]
    profile = load_profile("sim-type-i")
    view = GoniometerView()
    qtbot.addWidget(view)
    view.resize(640, 640)
    view.set_profile(profile)
    assert not view.which.model().item(1).isEnabled()  # its top view is the hemisphere
    pose = kinematics_of(profile.geometry).positions(Angles(30.0, 0.0, 50.0, 180.0))
    view.set_positions(pose)
    view.set_plan(build_plan(load_plan(root / "examples" / "brdf_hemisphere.toml"), profile))
    view.set_done([True] * 20)
    view.show()
    view.redraw()
    roles = {s.role for s in view.scene.shapes}
    assert {"source_rail", "detector_rail", "incident", "detector", "stationary_sample",
            "collision", "points_done", "points_todo"} <= roles
    assert "type (i)" in view.caption.text()
    # pytest-qt's own grab: a picture of what was drawn, kept for a look by eye
    view.grab().save(str(tmp_path / "goniometer_type_i.png"))
    assert (tmp_path / "goniometer_type_i.png").stat().st_size > 0
