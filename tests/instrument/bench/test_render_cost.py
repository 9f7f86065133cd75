"""The light-field wall's render cost in the estimate (instrument.bench.render_cost).

The node rules of the cost model are checked against the node counts of the renderers
themselves (a Gaussian-profile object counts the evaluations it is asked for), so the model
cannot drift from the code it prices; the estimate of the example scan counts the render
per lit view, grows as 1/σ with the reference renderer and stays bounded with the lobe one.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from analysis.lightfield import FlatlandBRDF
from hw_mocks.sim.lightfield_scene import HiddenScene, PointObject, Wall
from instrument.bench.profile import load_profile, parse_profile
from instrument.bench.render_cost import NODE_S, VIEW_S, lightfield_render_s, nodes_per_ray
from instrument.bench.timing import bench_timing
from instrument.plans import build_plan, load_plan

ROOT = Path(__file__).resolve().parents[3]


class _Counting(PointObject):
    """A Gaussian-profile disc that counts the ray × node evaluations asked of it."""

    def radiance_at(self, c, theta):
        self.calls.append(int(np.broadcast(c, theta).size))
        return super().radiance_at(c, theta)


@pytest.mark.parametrize(("renderer", "width_rad"), [
    ("lobe", 0.1), ("lobe", 3e-3), ("lobe", 1e-4), ("lobe", 1e-6),
    ("reference", 0.1), ("reference", 3e-3), ("reference", 1e-4),
])
def test_node_rule_is_the_renderers_own_count(renderer, width_rad):
    obj = _Counting(0.0, -150.0, 2.0, 1.0, "gaussian")
    object.__setattr__(obj, "calls", [])
    # rays leaving the wall point nearest the object (its widest span), all inside it
    rays = 40
    tm = np.linspace(-0.01, 0.01, rays)
    d2 = 30.0
    scene = HiddenScene((obj,), Wall(-100, 100, FlatlandBRDF(0.5, width_rad, 0.1)), d2,
                        renderer=renderer)
    scene.radiance(d2 * np.tan(tm), tm)
    span = 2 * np.arcsin(5 * 2.0 / 150.0)
    assert sum(obj.calls) / rays == nodes_per_ray(span, width_rad, False, renderer)


def _scene(width_deg: float, renderer: str = "lobe") -> dict:
    profile = load_profile("sim-lightfield")
    scene = dict(profile.simulation["scene"])
    scene.pop("material")
    scene["brdf"] = {"specular_reflectance": 0.6, "specular_width_deg": width_deg,
                     "diffuse_reflectance": 0.08}
    scene["renderer"] = renderer
    return scene


def test_render_cost_is_never_zero_bounded_for_the_lobe_and_1_over_width_for_the_reference():
    lobe = [lightfield_render_s(_scene(w), 1024) for w in (10, 1, 0.1, 0.01, 1e-3, 1e-4)]
    ref = [lightfield_render_s(_scene(w, "reference"), 1024) for w in (1e-2, 1e-3, 1e-4)]
    assert min(lobe) > VIEW_S
    # two uniform objects: at most 16 panels of 8 nodes each, per ray
    assert max(lobe) <= VIEW_S + NODE_S["lobe"] * 1024 * 2 * 16 * 8 + 1e-12
    assert ref[1] / ref[0] == pytest.approx(10, rel=0.01)
    assert ref[2] / ref[1] == pytest.approx(10, rel=0.01)
    with pytest.raises(ValueError, match="renderer"):
        lightfield_render_s({**_scene(1), "renderer": "fast"}, 1024)
    with pytest.raises(ValueError, match="material"):
        lightfield_render_s({"kind": "lightfield", "material": "chrome"}, 1024)


def _profile_with(scene: dict):
    base = load_profile("sim-lightfield")
    return replace(base, simulation={**base.simulation, "scene": scene})


def test_the_estimate_counts_the_render_per_lit_view():
    plan = load_plan(ROOT / "examples" / "lightfield_scan.toml")
    est = {}
    for width, renderer in ((2.0, "lobe"), (1e-3, "lobe"), (1e-3, "reference")):
        profile = _profile_with(_scene(width, renderer))
        timing = bench_timing(profile, ("camera_z",))
        assert timing.render_s == pytest.approx(
            lightfield_render_s(_scene(width, renderer), 1024))
        est[(width, renderer)] = build_plan(plan, profile).estimate().bench_acquisition_s
    views = sum(1 for p in build_plan(plan, load_profile("sim-lightfield")).points if p.light)
    assert views == 101
    for key in ((1e-3, "lobe"), (1e-3, "reference")):
        extra = est[key] - est[(2.0, "lobe")]
        render = (lightfield_render_s(_scene(*key), 1024)
                  - lightfield_render_s(_scene(2.0), 1024))
        assert extra == pytest.approx(views * render, rel=1e-9)
    # the reference near-mirror wall: about 35 s a view, an hour for the scan, not 3 s
    assert est[(1e-3, "reference")] > 100 * est[(1e-3, "lobe")]


def test_a_scene_that_is_not_a_light_field_adds_no_render_model():
    assert bench_timing(load_profile("sim")).render_s == 0.0
    text = load_profile("sim-lightfield").source_text.replace("width=1024&", "")
    bare = parse_profile(text, source="no width")
    assert bench_timing(bare).render_s == pytest.approx(
        lightfield_render_s(tomllib.loads(text)["simulation"]["scene"], 1024))
