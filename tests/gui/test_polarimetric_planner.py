"""The plan editor's planner on polarimetric plans: a dual-rotating-retarder plan shows the
Pareto front of ``scatterlab plan`` (the values of
:mod:`instrument.plans.polarimetric_tradeoff`), computed on the background thread, and a
row chosen in the table is what Apply writes into the plan's steps; a PEM plan shows κ per
wavelength and says that no front is computed."""

from __future__ import annotations

from pathlib import Path

import pytest

from gui.model import format as fmt
from instrument.bench.profile import load_profile
from instrument.plans import load_plan
from instrument.plans.polarimetric_tradeoff import plan_candidates, polarimetric_sweep
from instrument.plans.tradeoff import pareto_front

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
#: the table shows three significant digits: half a unit of the third is ≤ 0.5 %
SHOWN = 5e-3


def _editor(qtbot, make_window, path: Path, bench: str):
    """The plan editor of a window on ``bench`` with plan ``path`` open and validated."""
    editor = make_window(bench).plan_editor
    assert editor.open_plan(path)
    qtbot.waitUntil(lambda: editor.status.text() not in ("", "checking …")
                    and editor.validation is not None, timeout=60000)
    assert editor.validation.ok, (editor.validation.errors, editor.validation.general)
    return editor


def _cells(table) -> list[list[str]]:
    return [[table.item(k, j).text() for j in range(table.columnCount())]
            for k in range(table.rowCount())]


def test_a_drr_plan_shows_the_polarimetric_front_and_applies_the_chosen_row(qtbot,
                                                                            make_window):
    path = EXAMPLES / "brdf_polarimetric.toml"
    editor = _editor(qtbot, make_window, path, "sim-polarimetric")
    assert "retarder steps per geometry" in editor.planner_box.title()
    editor.target_sigma.setValue(0.003)
    editor.run_planner()
    # the answer comes back as a signal on this thread's event loop, not within the call
    assert editor.planner_result.text() == "searching …"
    qtbot.waitUntil(lambda: editor.planner_result.text().startswith(
        ("fastest", "no step", "planner")), timeout=60000)
    assert editor.planner_result.text().startswith("fastest"), editor.planner_result.text()

    spec = load_plan(path)
    results = polarimetric_sweep(spec, load_profile("sim-polarimetric"),
                                 plan_candidates(spec))
    front = pareto_front(results, "sigma_mean")
    headers = [editor.pareto.horizontalHeaderItem(j).text()
               for j in range(editor.pareto.columnCount())]
    assert headers == ["steps", "points", "duration", "κ", "σ mean", "σ worst"]
    shown = _cells(editor.pareto)
    assert len(shown) == len(front) >= 2
    for cells, r in zip(shown, front, strict=True):
        steps, points, duration, kappa, mean, worst = cells
        assert int(steps.split()[0]) == r.option.steps
        assert ("(this plan)" in steps) == (r.option.steps == 36)  # the example's steps
        assert int(points) == r.n_points
        assert duration == fmt.duration(r.duration_s)
        assert float(kappa) == pytest.approx(r.kappa, rel=SHOWN)
        assert float(mean) == pytest.approx(r.sigma["sigma_mean"], rel=SHOWN)
        assert float(worst) == pytest.approx(r.sigma["sigma_max"], rel=SHOWN)
    # the fastest candidate whose mean σ reaches the target is offered first
    reaching = [r for r in results if r.sigma["sigma_mean"] <= 0.003]
    fastest = min(reaching, key=lambda r: r.duration_s)
    assert f"{fastest.option.steps} steps per geometry" in editor.planner_result.text()
    assert editor.apply_best.isEnabled()

    # choosing a row makes it the point Apply writes: the plan's steps change
    k = len(front) - 1
    editor.choose_row(k)
    assert editor.planner_result.text().startswith(f"chosen: {front[k].option.steps} steps")
    editor.apply_best.click()
    assert editor.form.get("polarimetry.steps") == str(front[k].option.steps)
    qtbot.waitUntil(lambda: editor.validation is not None and editor.validation.spec
                    is not None and editor.validation.spec.polarimetry is not None
                    and editor.validation.spec.polarimetry["steps"] == front[k].option.steps,
                    timeout=60000)
    assert editor.validation.ok


def test_an_unknown_axis_is_named(qtbot, make_window):
    editor = _editor(qtbot, make_window, EXAMPLES / "brdf_polarimetric.toml",
                     "sim-polarimetric")
    editor.target_param.setText("m01")
    editor.run_planner()
    qtbot.waitUntil(lambda: editor.planner_result.text().startswith("planner"),
                    timeout=60000)
    assert "no axis 'm01'" in editor.planner_result.text()
    assert "sigma_mean, sigma_max, kappa" in editor.planner_result.text()
    assert not editor.apply_best.isEnabled()


def test_a_pem_plan_shows_its_conditioning_and_no_front(qtbot, make_window):
    from instrument.plans.build import plan_filter_wavelengths
    from instrument.plans.polarimetry import plan_wavelengths
    from instrument.plans.polarimetry_pem import pem_conditioning

    path = EXAMPLES / "brdf_polarimetric_pem.toml"
    editor = _editor(qtbot, make_window, path, "sim-polarimetric-pem")
    assert "PEM" in editor.planner_box.title()
    editor.run_planner()
    qtbot.waitUntil(lambda: editor.planner_result.text().startswith(("PEM plan", "planner")),
                    timeout=60000)
    text = editor.planner_result.text()
    assert text.startswith("PEM plan"), text
    assert "no speed/accuracy front" in text
    spec, profile = load_plan(path), load_profile("sim-polarimetric-pem")
    assert spec.polarimetry is not None
    expected = pem_conditioning(spec.polarimetry, profile,
                                plan_wavelengths(profile, plan_filter_wavelengths(spec,
                                                                                  profile)))
    shown = _cells(editor.pareto)
    assert len(shown) == len(expected) >= 1
    for (lam, kappa, amp, ret), c in zip(shown, expected, strict=True):
        assert lam == ("—" if c.wavelength_nm is None else f"{c.wavelength_nm:g}")
        assert float(kappa) == pytest.approx(c.kappa, rel=SHOWN)
        assert float(amp) == pytest.approx(c.amplitude_rad, abs=5e-4)
        assert float(ret) == pytest.approx(c.analyser_retardance_deg)
    est = editor.plan.estimate()
    assert f"{est.n_points} points, {fmt.duration(est.real_time_s)} of instrument time" in text
    # nothing to apply: a row of the conditioning is not a choice of scan
    editor.choose_row(0)
    assert not editor.apply_best.isEnabled()
