"""A plan's points are counted from its axes before any is made: the count matches what
the generator makes for every example plan, and a plan over the limit is refused at once,
naming its fields and the count, without allocating its points."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.plans import PlanError, build_plan, load_plan, parse_plan
from instrument.plans.build import _raw_points
from instrument.plans.count import count_points
from instrument.plans.grid import equal_solid_angle_count, equal_solid_angle_grid
from instrument.plans.planfile import MAX_POINTS
from instrument.plans.ranges import FloatRange

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
BENCHES = {"brdf_hemisphere": "sim_out_of_plane", "lightfield_scan": "sim-lightfield",
           "sphere_capture": "sim-spheres", "brdf_spectral_lockin": "sim-spectral"}

#: 10 × 10⁶ in-plane angles: 10⁷ points, ten times the limit.
HUGE = """
[plan]
kind = "brdf_in_plane"
name = "typo in the step"
[sample]
name = "grey"
[scan]
theta_i = {start = 0, stop = 45, step = 5}
theta_r = {start = -80, stop = 79.99992, step = 0.00016}
"""


def example_plans() -> list[str]:
    return sorted(p.stem for p in EXAMPLES.glob("*.toml")
                  if "[plan]" in p.read_text(encoding="utf-8"))


@pytest.mark.parametrize("name", example_plans())
def test_the_count_is_what_the_generator_makes(name):
    spec = load_plan(EXAMPLES / f"{name}.toml")
    profile = load_profile(BENCHES.get(name, "sim"))
    count = count_points(spec)
    made = len(_raw_points(spec, profile))
    if spec.spectral is not None:  # the wavelength axis is added after generation
        made *= len(spec.spectral["filters"])
    assert count.n == made if count.exact else count.n <= made, (count, made)


def test_a_ten_million_point_plan_is_refused_before_any_point_is_made():
    spec = parse_plan(HUGE)
    profile = load_profile("sim")
    tracemalloc.start()
    try:
        with pytest.raises(PlanError) as exc:
            build_plan(spec, profile)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # 10⁷ points would take gigabytes; the refusal takes no more than a message's worth.
    assert peak < 2 << 20, peak
    (err,) = exc.value.errors
    assert err.path == "scan.theta_r"
    assert "10000000 points" in err.message and f"at most {MAX_POINTS}" in err.message
    assert "scan.theta_i (10) × scan.theta_r (1000000)" in err.message


def test_the_command_line_refuses_it_in_one_message(tmp_path, capsys):
    plan = tmp_path / "huge.toml"
    plan.write_text(HUGE)
    for command in ("plan", "run"):
        assert main([command, str(plan), "--out", str(tmp_path / "runs")]) == 2
        captured = capsys.readouterr()
        assert "Traceback" not in captured.err and captured.out == ""
        assert "scan.theta_r: the plan expands to 10000000 points" in captured.err
    assert not (tmp_path / "runs").exists()  # refused before anything was made


@pytest.mark.parametrize(("scan", "n"), [
    # 1.6 × 10⁶ points made, but ±30° are mirror images: reciprocity may keep 400 001
    ("theta_i = [-30.0, 30.0]\ntheta_r = {start = -80, stop = 80, step = 0.0002}\n"
     "reciprocity = true", 400001),
    ("theta_i = [10.0]\ntheta_r = [20.0]\nspecular = {half_width_deg = 5, step_deg = 0.01}",
     1),
])
def test_lower_bounds_never_refuse_a_plan_that_may_fit(scan, n):
    """With reciprocity or a specular search the count is a lower bound: a plan that may
    fit the limit after de-duplication is not refused for points it would not have."""
    spec = parse_plan(f'[plan]\nkind = "brdf_in_plane"\n[sample]\nname = "s"\n[scan]\n{scan}\n')
    count = count_points(spec)
    assert not count.exact and count.n == n


def test_the_hemisphere_grid_count_is_the_grid_length():
    for n in (1, 7, 100, 1234, 100000):
        for theta_max in (10.0, 60.0, 89.0):
            assert equal_solid_angle_count(n, theta_max) == len(
                equal_solid_angle_grid(n, theta_max)[0])


@settings(max_examples=60, deadline=None)
@given(start=st.floats(-90, 90), span=st.floats(0, 180), step=st.floats(1e-3, 50))
def test_a_range_has_the_values_of_the_plan_file_formula(start, span, step):
    r = FloatRange(start, start + span, step)
    values = list(r)
    assert len(values) == len(r) >= 1
    assert values[0] == start and values[-1] <= start + span + 1e-6 * step
    assert r[-1] == values[-1] and r[1:3] == values[1:3]
