"""Every BRDF plan kind on the type (i) bench (ADR 0104): the plan speaks in scattering
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


def test_the_spectral_lock_in_plan_runs_on_a_type_i_spectral_bench():
    """sim-spectral's devices and light path with its two rotation stages replaced by the
    type (i) arms of sim-type-i."""
    spectral = tomllib.loads((ROOT / "instrument/bench/profiles/sim-spectral.toml")
                             .read_text("utf-8"))
    arms = tomllib.loads((ROOT / "instrument/bench/profiles/sim-type-i.toml")
                         .read_text("utf-8"))
    for role in ("sample_theta", "detector_theta"):
        del spectral["devices"][role]
    spectral["devices"].update({r: arms["devices"][r] for r in TYPE_I_AXES})
    spectral["geometry"] = arms["geometry"]
    text = tomlw.dumps(spectral)
    profile = parse_profile(text)
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
