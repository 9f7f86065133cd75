"""The plan editor: every example loads, a broken field shows its error and Start is off."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.gui.conftest import connect

#: The example plan files (examples/ also holds bench profiles and a geometry file).
_EXAMPLE_DIR = Path(__file__).resolve().parents[2] / "examples"
EXAMPLES = sorted(p for p in _EXAMPLE_DIR.glob("*.toml")
                  if "[plan]" in p.read_text(encoding="utf-8"))
#: Plans the form cannot hold yet: an explicit list of [θi, θr] pairs (``[scan] points``)
#: is edited in the plan file and run from the command line.
EXPLICIT_POINTS = {"calibration_nd"}
EXAMPLES = [p for p in EXAMPLES if p.stem not in EXPLICIT_POINTS]
BENCH = {"brdf_hemisphere": "sim_out_of_plane", "lightfield_scan": "sim-lightfield",
         "sphere_capture": "sim-spheres", "brdf_spectral_lockin": "sim-spectral",
         "brdf_inplane_spin": str(_EXAMPLE_DIR / "bench_sim_laser.toml"),
         "brdf_polarimetric": "sim-polarimetric",
         "brdf_polarimetric_pem": "sim-polarimetric-pem"}


def _validated(qtbot, editor):
    qtbot.waitUntil(lambda: editor.status.text() not in ("", "checking …")
                    and editor.validation is not None, timeout=60000)


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_every_example_plan_loads_and_validates(qtbot, make_window, path):
    w = make_window(BENCH.get(path.stem, "sim"))
    editor = w.plan_editor
    assert editor.open_plan(path)
    _validated(qtbot, editor)
    assert editor.validation.ok, (editor.validation.errors, editor.validation.general)
    assert "valid on bench" in editor.status.text()
    assert editor.problems.text() == ""
    assert "points" in editor.preview.text() and "estimated duration" in editor.preview.text()
    if editor.plan.points[0].angles is not None or any(p.angles for p in editor.plan.points):
        assert editor.coverage.pixmap() is not None and not editor.coverage.pixmap().isNull()
    assert not editor.start.isEnabled()  # no bench connected yet


def test_a_broken_field_shows_its_error_and_disables_start(qtbot, make_window,
                                                           fast_bench_file, tmp_path):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    editor = w.plan_editor
    editor.open_plan(EXAMPLES[[p.stem for p in EXAMPLES].index("brdf_inplane")])
    _validated(qtbot, editor)
    qtbot.waitUntil(editor.start.isEnabled, timeout=60000)
    editor.set_field("acquisition.max_exposure_us", "5")  # below min_exposure_us = 10
    qtbot.waitUntil(lambda: editor.error_text("acquisition.min_exposure_us") != "",
                    timeout=60000)
    assert "must not exceed max_exposure_us" in editor.error_text("acquisition.min_exposure_us")
    assert not editor.start.isEnabled()
    assert "problem" in editor.status.text()
    editor.set_field("acquisition.max_exposure_us", "not a number")
    qtbot.waitUntil(lambda: "is not a number" in editor.error_text(
        "acquisition.max_exposure_us"), timeout=60000)
    editor.set_field("acquisition.max_exposure_us", "200000")
    qtbot.waitUntil(editor.start.isEnabled, timeout=60000)
    assert editor.error_text("acquisition.max_exposure_us") == ""
    # the file written is the plan the CLI reads
    saved = editor.save_plan(tmp_path / "p.toml")
    from instrument.plans import load_plan

    assert load_plan(saved).acquisition.max_exposure_us == 200000


def test_points_the_guard_rejects_are_listed(qtbot, make_window):
    w = make_window("sim")
    editor = w.plan_editor
    editor.new_plan("brdf_in_plane")
    editor.set_field("sample.name", "x")
    editor.set_field("scan.skip_beam_points", False)
    editor.set_field("scan.theta_i", "20")
    editor.set_field("scan.theta_r", "-20, 40")
    qtbot.waitUntil(lambda: "incident beam" in editor.problems.text(), timeout=60000)
    assert not editor.start.isEnabled()


def test_the_planner_finds_the_fastest_scan_and_applies_it(qtbot, make_window):
    w = make_window("sim")
    editor = w.plan_editor
    editor.new_plan("brdf_in_plane")
    editor.set_field("sample.name", "x")
    editor.set_field("scan.theta_i", "20, 40, 60")
    editor.set_field("acquisition.mode", "auto")
    _validated(qtbot, editor)
    qtbot.waitUntil(lambda: editor.validation.ok, timeout=60000)
    editor.target_sigma.setValue(0.01)
    editor.run_planner()
    qtbot.waitUntil(lambda: editor.planner_result.text().startswith(("fastest", "no option",
                                                                      "planner")),
                    timeout=60000)
    assert editor.planner_result.text().startswith("fastest"), editor.planner_result.text()
    assert editor.pareto.rowCount() >= 1
    best = editor._best.option
    editor.apply_best.click()
    assert editor.form.get("acquisition.frames") == str(best.frames)
    assert f"step {best.theta_r_step_deg:g}" in editor.form.get("scan.theta_r")
    # a row of the front chosen in the table is what Apply writes instead
    k = editor.pareto.rowCount() - 1
    chosen = editor._front[k].option
    editor.choose_row(k)
    assert editor.planner_result.text().startswith(f"chosen: {chosen.label()}")
    editor.apply_best.click()
    assert editor.form.get("acquisition.frames") == str(chosen.frames)
    assert f"step {chosen.theta_r_step_deg:g}" in editor.form.get("scan.theta_r")
    assert editor.form.get("acquisition.max_exposure_us") == f"{chosen.max_exposure_us:g}"
