"""Plan files, generators, grids, order and commands; fuzzed plan/profile files."""

from __future__ import annotations

import copy
import math
import tomllib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from instrument.bench.dynamics import route_time
from instrument.bench.guard import GuardError
from instrument.bench.kinematics import Angles
from instrument.bench.profile import ProfileError, load_profile, parse_profile
from instrument.plans import (
    Acquire,
    Move,
    PlanError,
    PointDone,
    SetLight,
    build_plan,
    load_plan,
    parse_plan,
)
from instrument.plans.build import dynamics_of
from instrument.plans.grid import dedupe_reciprocal, equal_solid_angle_grid, specular_cone
from tests.instrument import tomlw
from tests.instrument.helpers import IDEAL_PROFILE, inplane_plan

PROFILE = parse_profile(IDEAL_PROFILE)
OOP_PROFILE = parse_profile(IDEAL_PROFILE.replace('kind = "in_plane"', 'kind = "out_of_plane"')
                            + """
[devices.sample_phi]
driver = "thorlabs_apt"
url = "ideal://sample_phi"
limits = [-180.0, 180.0]
velocity = 20.0
acceleration = 20.0
[devices.sample_tilt]
driver = "thorlabs_apt"
url = "ideal://sample_tilt"
limits = [-60.0, 60.0]
velocity = 5.0
acceleration = 5.0
""".replace("[geometry]", "[geometry]"))


def test_field_level_errors_all_reported():
    text = """
[plan]
kind = "brdf_in_plane"
order = "sideways"
[sample]
[scan]
theta_i = [10, "x", 95]
theta_r = { start = 10, stop = 0, step = 1 }
bogus = 1
[acquisition]
mode = "sometimes"
frames = 0
detectors = ["camera", "microphone"]
"""
    with pytest.raises(PlanError) as exc:
        parse_plan(text, source="t.toml")
    paths = {e.path for e in exc.value.errors}
    assert {"plan.order", "sample.name", "scan.theta_i[1]", "scan.theta_i[2]", "scan.theta_r",
            "scan.bogus", "acquisition.mode", "acquisition.frames",
            "acquisition.detectors"} <= paths
    assert "t.toml is not valid" in str(exc.value)


def test_in_plane_plan_points_and_commands():
    plan = build_plan(parse_plan(inplane_plan(step=15.0)), PROFILE)
    # θr from -45 to 75 in 15° steps (9) for each of 2 θi; beam points dropped.
    assert plan.dropped_in_beam == 1  # θi=30, θr=-30 source side → bistatic 0
    assert len(plan.points) == 2 * 9 - 1
    assert [p.index for p in plan.points] == list(range(len(plan.points)))
    for p in plan.points:
        a = p.angles
        assert a.theta_i in (10.0, 30.0)
        pos = p.target_dict()
        assert pos["sample_theta"] == pytest.approx(a.theta_i)
    cmds = list(plan.commands())
    assert isinstance(cmds[0], SetLight) and cmds[0].on
    body = cmds[1:]
    assert len(body) == 3 * len(plan.points)
    for k in range(len(plan.points)):
        m, a, d = body[3 * k: 3 * k + 3]
        assert isinstance(m, Move) and isinstance(a, Acquire) and isinstance(d, PointDone)
        assert m.index == a.index == d.index == k
    skipped = list(plan.commands(done={0, 1, 2}))
    assert [c.index for c in skipped if isinstance(c, Move)] == list(range(3, len(plan.points)))


def test_specular_refinement_and_reciprocity():
    text = inplane_plan(step=15.0).replace(
        "skip_beam_points = true",
        "skip_beam_points = true\nspecular = { half_width_deg = 3.0, step_deg = 1.0 }")
    plan = build_plan(parse_plan(text), PROFILE)
    near = [p for p in plan.points if p.angles.phi_r == 180.0
            and abs(p.angles.theta_r - p.angles.theta_i) <= 3.0]
    assert len(near) == 2 * 7  # -3..3 around each specular angle (the 0 offset included)
    angles = [Angles(10, 0, 40, 180), Angles(40, 0, 10, 180), Angles(40, 180, 10, 0),
              Angles(20, 0, 20, 180)]
    assert dedupe_reciprocal(angles) == [0, 3]
    assert dedupe_reciprocal(angles, isotropic=False) == [0, 1, 3]


@pytest.mark.parametrize("n", [1, 7, 50, 400])
def test_equal_solid_angle_grid(n):
    dirs, omega = equal_solid_angle_grid(n, 80.0)
    total = 2 * math.pi * (1 - math.cos(math.radians(80.0)))
    assert omega * len(dirs) == pytest.approx(total)
    assert abs(len(dirs) - n) <= max(1, 0.1 * n)
    assert np.all(dirs[:, 0] < 80.0) and np.all(dirs[:, 0] >= 0.0)
    # Equal-area check by Monte Carlo: counts of uniform directions per nearest cell are
    # not needed; instead each cell's band/azimuth slice has area omega by construction,
    # so the mean of cos θ over cells equals the solid-angle mean (1 + cos θmax)/2.
    if n >= 50:
        c = np.cos(np.radians(dirs[:, 0]))
        assert c.mean() == pytest.approx((1 + math.cos(math.radians(80))) / 2, rel=2e-3)


def test_specular_cone_is_around_specular():
    dirs = specular_cone(30.0, 0.0, half_width_deg=4.0, rings=2, per_ring=6)
    assert len(dirs) == 12
    spec = Angles(30, 180, 30, 180).omega_r
    for th, ph in dirs:
        d = Angles(th, ph, 0, 0).omega_i
        ang = math.degrees(math.acos(np.clip(np.dot(d, spec), -1, 1)))
        assert ang == pytest.approx(2.0, abs=1e-6) or ang == pytest.approx(4.0, abs=1e-6)


def test_hemisphere_plan_on_out_of_plane_bench():
    text = """
[plan]
kind = "brdf_hemisphere"
[sample]
name = "s"
[scan]
theta_i = [30.0]
n_directions = 60
theta_max_deg = 70.0
skip_beam_points = true
reciprocity = true
"""
    plan = build_plan(parse_plan(text), OOP_PROFILE)
    assert 40 <= len(plan.points) <= 62
    kin_axes = {"sample_theta", "sample_tilt", "sample_phi", "detector_theta"}
    assert set(plan.axes) == kin_axes
    from instrument.bench.kinematics import OutOfPlaneKinematics, same_directions
    kin = OutOfPlaneKinematics()
    for p in plan.points:
        assert same_directions(kin.angles(p.target_dict()), p.angles, tol=1e-7)
    # Out-of-plane angles on an in-plane bench: one error naming the plan kind and the fix.
    with pytest.raises(PlanError, match="needs an out-of-plane bench") as info:
        build_plan(parse_plan(text), PROFILE)
    assert len(info.value.errors) == 1 and info.value.errors[0].path == "plan.kind"


def test_optimised_order_beats_raster():
    text = inplane_plan(step=5.0)
    spec = parse_plan(text)
    opt = build_plan(spec, PROFILE)
    raster = build_plan(parse_plan(text.replace('name = "test"', 'name = "t"\norder = "raster"')),
                        PROFILE)
    assert sorted(p.angles.as_tuple() for p in opt.points) == \
        sorted(p.angles.as_tuple() for p in raster.points)
    dyn = dynamics_of(PROFILE, opt.axes)
    t_opt, _ = route_time(opt.targets_array(), opt.axes, dyn)
    t_raster, _ = route_time(raster.targets_array(), raster.axes, dyn)
    # At least the return sweep of the detector between the two rows is saved.
    assert t_opt < 0.93 * t_raster


def test_guard_runs_before_anything():
    text = inplane_plan(step=15.0).replace("skip_beam_points = true", "")
    with pytest.raises(GuardError, match="incident beam"):
        build_plan(parse_plan(text), PROFILE)


def test_calibration_and_lightfield_kinds():
    plans = {
        "dark": '[scan]\nexposures_us = [100, 1000]\nframes = 3\n',
        "flat_field": '[scan]\nexposures_us = [500]\nframes = 2\n'
                      'positions = { sample_theta = 0.0 }\n',
        "photon_transfer": '[scan]\nexposures_us = { start = 10, stop = 1e5, n = 5 }\n',
        "signature": '[scan]\ntheta_i = [20]\ntheta_r = [40, 60]\n',
        "reference": '[sample]\nname = "Spectralon"\n[scan]\ntheta_i = [20]\n'
                     'theta_r = [40, 60]\nreference_name = "SRS-99"\nreflectance = 0.99\n',
        "lightfield": '[sample]\nname = "wall"\n[scan]\ncamera_z = { start = 0, stop = 20, '
                      'step = 5 }\nsample_theta = 10.0\n',
    }
    counts = {}
    for kind, body in plans.items():
        plan = build_plan(parse_plan(f'[plan]\nkind = "{kind}"\n{body}'), PROFILE)
        counts[kind] = plan
    assert len(counts["dark"].points) == 6 and not any(p.light for p in counts["dark"].points)
    ptc = counts["photon_transfer"].points
    assert len(ptc) == 5 * (2 * 2 + 2)
    assert sorted({p.exposure_us for p in ptc})[-1] == pytest.approx(1e5)
    assert {p.label for p in counts["signature"].points} == {"signature"}
    lf = counts["lightfield"].points
    assert [p.target_dict()["camera_z"] for p in lf] == [0, 5, 10, 15, 20]
    assert all(p.angles is None for p in lf)


# --------------------------------------------------------------------------- fuzzing

BASE_PLAN = tomllib.loads(inplane_plan(step=15.0))
BASE_PROFILE = tomllib.loads(load_profile("sim").source_text)

junk = st.one_of(
    st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8), st.booleans(), st.lists(st.integers(-200, 200), max_size=4),
    st.lists(st.floats(-1e3, 1e3), max_size=3), st.just({}),
    st.dictionaries(st.sampled_from(["start", "stop", "step", "n"]),
                    st.floats(-1e9, 1e9), max_size=3),
)


def _paths(d, prefix=()):
    for k, v in d.items():
        yield (*prefix, k)
        if isinstance(v, dict):
            yield from _paths(v, (*prefix, k))


@st.composite
def mutated(draw, base):
    data = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 4))):
        paths = list(_paths(data))
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = data
        for k in path[:-1]:
            parent = parent[k]
        if not isinstance(parent, dict) or path[-1] not in parent:
            continue
        op = draw(st.sampled_from(["delete", "replace", "add"]))
        if op == "delete":
            del parent[path[-1]]
        elif op == "replace":
            parent[path[-1]] = draw(junk)
        else:
            parent[draw(st.text("abcdefgh_", min_size=1, max_size=6))] = draw(junk)
    return tomlw.dumps(data)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated(BASE_PLAN))
def test_fuzzed_plan_files_give_field_errors(text):
    try:
        spec = parse_plan(text, source="fuzz.toml")
    except PlanError as err:
        assert err.errors and all(e.path and e.message for e in err.errors)
        return
    try:
        plan = build_plan(spec, PROFILE)
    except (PlanError, GuardError):
        return
    assert len(plan.points) >= 1


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated(BASE_PROFILE))
def test_fuzzed_profile_files_give_field_errors(text):
    try:
        parse_profile(text, source="fuzz.toml")
    except ProfileError as err:
        assert err.errors and all(e.path and e.message for e in err.errors)


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=200))
def test_random_text_is_rejected_cleanly(text):
    with pytest.raises(PlanError):
        parse_plan(text)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(mutated(BASE_PLAN))
def test_fuzzed_plan_through_the_cli_never_opens_or_moves_anything(tmp_path, text):
    """`scatterlab run` on an invalid plan: exit code 2, field errors, and not one device
    of the emulated bench opened (so nothing can have moved)."""
    from hw_mocks import registry
    from instrument.cli import main

    try:
        spec = parse_plan(text)
        build_plan(spec, load_profile("sim"))
        return  # a valid plan may run; only invalid ones are under test here
    except (PlanError, GuardError):
        pass
    registry.reset()
    path = tmp_path / "fuzz.toml"
    path.write_text(text)
    assert main(["run", str(path), "--out", str(tmp_path / "runs")]) == 2
    assert registry.all_emulators() == []
    assert not (tmp_path / "runs").exists()


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(mutated(BASE_PROFILE))
def test_fuzzed_profile_through_the_cli_never_opens_or_moves_anything(tmp_path, text):
    from hw_mocks import registry
    from instrument.cli import main

    try:
        parse_profile(text)
        return  # still valid: opening it is allowed
    except ProfileError:
        pass
    registry.reset()
    bench = tmp_path / "bench.toml"
    bench.write_text(text)
    plan = tmp_path / "plan.toml"
    plan.write_text(inplane_plan(step=15.0))
    assert main(["run", str(plan), "--bench", str(bench), "--out", str(tmp_path / "r")]) == 2
    assert registry.all_emulators() == []
    assert not (tmp_path / "r").exists()


_EXAMPLES = __import__("pathlib").Path(__file__).resolve().parents[3] / "examples"
#: Every example plan with the bench it is written for (fuzzed below, each kind).
_EXAMPLE_BENCH = {p.stem: {"brdf_hemisphere": "sim_out_of_plane",
                           "lightfield_scan": "sim-lightfield", "lightfield": "sim-lightfield",
                           "sphere_capture": "sim-spheres",
                           "brdf_polarimetric_pem": "sim-polarimetric-pem"}.get(p.stem, "sim")
                  for p in sorted(_EXAMPLES.glob("*.toml"))
                  if "[plan]" in p.read_text(encoding="utf-8")}  # not the bench profiles


@st.composite
def mutated_example(draw):
    name = draw(st.sampled_from(sorted(_EXAMPLE_BENCH)))
    base = tomllib.loads((_EXAMPLES / f"{name}.toml").read_text())
    return name, draw(mutated(base))


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated_example())
def test_fuzzed_example_plans_of_every_kind_dry_run_or_give_field_errors(case):
    """Every plan kind, mutated: field errors, or a plan whose dry run (estimate and
    coverage picture) works; nothing else escapes."""
    from instrument.plans.coverage import coverage_image

    name, text = case
    try:
        plan = build_plan(parse_plan(text, source="fuzz.toml"),
                          load_profile(_EXAMPLE_BENCH[name]))
    except PlanError as err:
        assert err.errors and all(e.path and e.message for e in err.errors)
        return
    except GuardError as err:
        assert err.violations
        return
    est = plan.estimate()
    assert est.n_points == len(plan.points) >= 1
    assert math.isfinite(est.total_s) and est.total_s >= 0
    assert coverage_image(plan).shape[2] == 3


def test_coverage_separates_incidence_angles_and_writes_a_png(tmp_path):
    """In-plane plans get one panel per θi (never overlaid); hemisphere plans a polar panel
    per incidence direction; both write a PNG."""
    from instrument.plans.coverage import _in_plane, _incidences, write_coverage_png

    inplane = build_plan(load_plan(_EXAMPLES / "brdf_inplane.toml"), load_profile("sim"))
    angled = [p for p in inplane.points if p.angles is not None]
    groups = _incidences(angled)
    assert [ti for ti, _, _ in groups] == [20.0, 40.0, 60.0] and _in_plane(angled)
    assert sum(len(pts) for _, _, pts in groups) == len(angled)
    hemi = build_plan(load_plan(_EXAMPLES / "brdf_hemisphere.toml"),
                      load_profile("sim_out_of_plane"))
    assert not _in_plane([p for p in hemi.points if p.angles is not None])
    for plan, name in ((inplane, "a.png"), (hemi, "b.png")):
        png = write_coverage_png(plan, tmp_path / name)
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(OSError, match=r"must end in \.png"):
        write_coverage_png(inplane, tmp_path / "c.jpg")
