"""Every BRDF plan kind on the type (i) bench (ADR 0099): the plan speaks in scattering
angles, the profile decides the axes; a plan the arms cannot run is refused before any
motion."""

from __future__ import annotations

import itertools
import tomllib
from pathlib import Path

import numpy as np
import pytest

from instrument.bench import guard
from instrument.bench.dynamics import dynamics_of
from instrument.bench.kinematics import TYPE_I_AXES, kinematics_of
from instrument.bench.profile import load_profile, parse_profile
from instrument.plans.build import build_plan
from instrument.plans.planfile import load_plan, parse_plan
from tests.instrument import tomlw
from tests.instrument.bench.test_spectral_bench import LOCKIN_PLAN

ROOT = Path(__file__).resolve().parents[3]
TYPE_I = load_profile("sim-type-i")


def _check(plan, profile) -> None:
    """Each point realises its angles on the arms, and the order is routable."""
    kin = kinematics_of(profile.geometry)
    for p in plan.points:
        if p.angles is None:
            continue
        got = kin.angles(p.target_dict())
        assert np.allclose(got.omega_i, p.angles.omega_i, atol=1e-9)
        assert np.allclose(got.omega_r, p.angles.omega_r, atol=1e-9)
        assert set(dict(p.targets)) >= set(TYPE_I_AXES)
    dyn = dynamics_of(profile, TYPE_I_AXES)
    assert guard.check_route([p for p in plan.points if p.targets], profile, dyn) == []


@pytest.mark.parametrize("example, twin", [
    ("brdf_inplane.toml", "sim"),
    ("brdf_hemisphere.toml", "sim-out-of-plane"),
    ("brdf_lobe.toml", "sim"),
])
def test_the_example_plans_run_unchanged_on_the_type_i_bench(example, twin):
    spec = load_plan(ROOT / "examples" / example)
    plan = build_plan(spec, TYPE_I)
    _check(plan, TYPE_I)
    # the same scattering angles as on the type (ii) bench, less the points each bench's
    # own rules drop near the source direction
    on_ii = build_plan(spec, load_profile(twin))

    def key(p):
        return tuple(np.round(np.concatenate([p.angles.omega_i, p.angles.omega_r]), 9))

    a_i = {key(p) for p in plan.points if p.angles is not None}
    a_ii = {key(p) for p in on_ii.points if p.angles is not None}
    assert a_ii <= a_i
    assert len(a_i - a_ii) == on_ii.dropped_in_beam - plan.dropped_in_beam


def test_a_reciprocity_hemisphere_plan_runs_on_the_type_i_bench():
    text = (ROOT / "examples" / "brdf_hemisphere.toml").read_text(encoding="utf-8")
    text = text.replace("reciprocity = false", "reciprocity = true")
    plan = build_plan(parse_plan(text), TYPE_I)
    _check(plan, TYPE_I)
    assert plan.spec.scan["reciprocity"] is True


def type_i_spectral_text() -> str:
    """sim-spectral's devices and light path with its two rotation stages replaced by the
    type (i) arms of sim-type-i (a bench profile's text)."""
    spectral = tomllib.loads((ROOT / "instrument/bench/profiles/sim-spectral.toml")
                             .read_text("utf-8"))
    arms = tomllib.loads((ROOT / "instrument/bench/profiles/sim-type-i.toml")
                         .read_text("utf-8"))
    for role in ("sample_theta", "detector_theta"):
        del spectral["devices"][role]
    spectral["devices"].update({r: arms["devices"][r] for r in TYPE_I_AXES})
    spectral["geometry"] = arms["geometry"]
    spectral["bench"]["name"] = "sim-type-i-spectral"
    return tomlw.dumps(spectral)


def test_the_spectral_lock_in_plan_runs_on_a_type_i_spectral_bench():
    profile = parse_profile(type_i_spectral_text())
    assert profile.geometry.is_type_i
    plan = build_plan(load_plan(ROOT / "examples" / "brdf_spectral_lockin.toml"), profile)
    _check(plan, profile)
    assert {dict(p.meta).get("filter") for p in plan.points} == {1, 2, 3}


COLLIDING = """
[plan]
kind = "brdf_in_plane"
name = "detector onto the source"
[sample]
name = "sim"
[scan]
points = [[30.0, 60.0], [30.0, -30.0], [30.0, 10.0]]
[acquisition]
detectors = ["power_meter"]
"""


def test_a_plan_with_a_point_where_the_arms_collide_is_refused_naming_the_rule():
    with pytest.raises(guard.GuardError) as err:
        build_plan(parse_plan(COLLIDING), TYPE_I)
    # exactly on the source direction: the heads touch, and the detector blocks the beam
    assert [(v.index, v.reason) for v in err.value.violations] == [(1, "arms"), (1, "beam")]
    assert "source and detector arms collide" in str(err.value)
    # skip_beam_points drops it, as it drops the type (ii) beam cone
    plan = build_plan(parse_plan(COLLIDING.replace("[acquisition]",
                                                   "skip_beam_points = true\n[acquisition]")),
                      TYPE_I)
    assert len(plan.points) == 2 and plan.dropped_in_beam == 1


SPECULAR_30 = """
[plan]
kind = "brdf_in_plane"
name = "one specular point"
[sample]
name = "sim"
[scan]
points = [[30.0, 30.0]]
[acquisition]
detectors = ["power_meter"]
"""
#: The arms swapped on one ring: each stands where the other must go.
SWAPPED = {"source_arc": -30.0, "source_azimuth": 180.0, "detector_arc": 90.0,
           "detector_azimuth": 0.0}


def test_arms_swapped_on_a_ring_pass_over_each_other():
    plan = build_plan(parse_plan(SPECULAR_30), TYPE_I, start=SWAPPED)
    assert plan.points[0].target_dict()["source_azimuth"] == 0.0


def test_an_order_the_arms_cannot_run_is_refused_as_path():
    """The same swap on a bench whose arcs cannot leave that ring (soft limits hugging
    it): no tried order or detour, so the plan is refused before any motion."""
    text = (ROOT / "instrument/bench/profiles/sim-type-i.toml").read_text("utf-8")
    text = text.replace("limits = [-145.0, 25.0]", "limits = [-30.01, -29.99]")
    text = text.replace("limits = [-25.0, 145.0]", "limits = [89.99, 90.01]")
    profile = parse_profile(text)
    build_plan(parse_plan(SPECULAR_30), profile)  # no start pose: nothing to route from
    with pytest.raises(guard.GuardError) as err:
        build_plan(parse_plan(SPECULAR_30), profile, start=SWAPPED)
    assert [v.reason for v in err.value.violations] == ["path"]
    assert "no collision-free route" in str(err.value)


def test_the_estimate_counts_the_legs_of_split_moves():
    """A move the arms cannot make together runs as legs one after the other: the
    estimate adds what they take beyond the one concurrent move."""
    from instrument.bench.arms import safe_route
    from instrument.bench.dynamics import move_time, route_time

    plan = build_plan(load_plan(ROOT / "examples" / "brdf_inplane.toml"), TYPE_I)
    dyn = dynamics_of(TYPE_I, plan.axes)
    concurrent, _ = route_time(plan.targets_array(), plan.axes, dyn)
    lim = {r: d.limits for r, d in TYPE_I.axes.items()}
    pts = [p.target_dict() for p in plan.points]
    routed = 0.0
    for here, there in itertools.pairwise(pts):
        route = safe_route(TYPE_I.geometry, dyn, here, there, limits=lim)
        # each leg's slowest axis, one leg after the other
        at = here
        for leg in route.moves:
            routed += max(move_time(leg[r] - at[r], dyn[r]) for r in leg)
            at = leg
    assert plan.estimate().motion_s == pytest.approx(routed, rel=1e-9)
    assert routed > concurrent  # the README's plan has moves past the source arm


#: The spectral bench's lock-in scan with a wavelength axis of two filters.
SPECTRAL_RUN = LOCKIN_PLAN + '[spectral]\nfilters = [1, 3]\norder = "motion"\n'


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_a_spectral_plan_runs_through_the_engine_on_type_i_and_reads_as_on_type_ii(
        tmp_path):
    """The engine runs a wavelength axis on the type (i) arms (the filter wheel turned per
    filter, the arms routed between points); every point is stored with its filter, and
    the lock-in reads the same light as on sim-spectral at the same angles and filter:
    the world renders the same sample on both types (ADR 0099)."""
    from instrument.cli import main
    from instrument.run.runfile import read_run

    plan = tmp_path / "plan.toml"
    plan.write_text(SPECTRAL_RUN, encoding="utf-8")
    bench = tmp_path / "type_i_spectral.toml"
    bench.write_text(type_i_spectral_text(), encoding="utf-8")
    runs = {}
    for name, profile in (("i", str(bench)), ("ii", "sim-spectral")):
        out = tmp_path / name
        assert main(["run", str(plan), "--bench", profile, "--out", str(out),
                     "--no-fsync", "--quiet"]) == 0
        (path,) = out.glob("*.h5")
        runs[name] = read_run(path)

    def readings(run):
        rows = run.brdf_rows()
        # the read-back angles, to within the stages' tolerance: θr, its side of the
        # normal in the plane of incidence (φr ≈ 0 or 180°; none at the normal) and the
        # filter
        theta_r = np.round(run.theta_r[rows], 1)
        side = np.where(theta_r == 0, 0, np.round(np.cos(np.radians(run.phi_r[rows]))))
        key = zip(theta_r, side.astype(int), run.filter_position[rows], strict=True)
        return dict(zip(key, run.lockin_r_v[rows], strict=True))

    on_i, on_ii = readings(runs["i"]), readings(runs["ii"])
    assert len(on_i) == 6 and set(on_i) == set(on_ii)
    assert {k[2] for k in on_i} == {1, 3}
    for k, v in on_i.items():
        # they differ by the stages' read-back (within 0.01°) and the lock-in's noise
        # (its seed shared): ≤ 4e-4 seen; 5e-3 leaves a tenfold margin
        assert v == pytest.approx(on_ii[k], rel=5e-3), k
