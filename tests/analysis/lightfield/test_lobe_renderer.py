"""The lobe-adaptive wall renderer against the reference quadrature, and its mirror limit.

Tolerance of every comparison: the reference's own quadrature error, estimated as its change
when its panels are halved, four times over, plus the rounding of sums of ~10⁴ terms
(10³ ε of the largest radiance). Where both quadratures have converged the two agree to
rounding; a real error in either (a lobe window too narrow, an edge missed, a wrong weight)
is many orders of magnitude larger.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.lightfield import FlatlandBRDF, SpatiallyVaryingBRDF
from hw_mocks.sim import lightfield_lobe
from hw_mocks.sim.lightfield_scene import BarObject, HiddenScene, PointObject, Wall

EPS = np.finfo(float).eps
OBJECTS = (
    PointObject(-8.0, -200.0, 1.5, 5.0),
    BarObject(15.0, 30.0, -260.0, 1.5),
    PointObject(40.0, -150.0, 2.0, 2.0, "gaussian"),
)
D2 = 30.0


def _rays(seed: int, n: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """Random rays, plus rays aimed at the disc's and the bar's edges in the mirror
    direction (the lobe straddles an object's edge there)."""
    rng = np.random.default_rng(seed)
    ym = rng.uniform(-50.0, 50.0, n)
    tm = rng.uniform(-0.6, 0.6, n)
    c0 = np.linspace(-40.0, 40.0, 9)
    edges = []
    for obj in OBJECTS[:2]:
        lo, hi = obj.interval(c0)
        edges += [(c0, lo), (c0, hi), (c0, lo + 1e-7), (c0, hi - 3e-6)]
    ce = np.concatenate([c for c, _ in edges])
    te = np.concatenate([t for _, t in edges])
    return np.concatenate([ym, ce + D2 * np.tan(te)]), np.concatenate([tm, te])


def _compare(wall: Wall, seed: int) -> None:
    ym, tm = _rays(seed)
    lobe = HiddenScene(OBJECTS, wall, D2).radiance(ym, tm)
    ref = HiddenScene(OBJECTS, wall, D2, renderer="reference").radiance(ym, tm)
    base = getattr(wall.brdf, "base", wall.brdf)
    finer = HiddenScene(OBJECTS, wall, D2, panel_rad=0.125 * base.specular_width_rad,
                        renderer="reference").radiance(ym, tm)
    tol = 4.0 * np.abs(ref - finer) + 1e3 * EPS * np.max(np.abs(ref))
    assert np.max(ref) > 0.01  # the rays see the objects
    assert np.all(np.abs(lobe - ref) <= tol), np.max(np.abs(lobe - ref) / tol)


@pytest.mark.parametrize("width_deg", [10.0, 1.0, 0.1, 0.01])
def test_lobe_renderer_matches_the_reference_on_a_flat_wall(width_deg):
    _compare(Wall(-150.0, 150.0, FlatlandBRDF(0.6, np.deg2rad(width_deg), 0.08)), seed=1)


@pytest.mark.parametrize("width_deg", [1.0, 0.05])
def test_matches_on_a_curved_stained_wall_with_a_window(width_deg):
    base = FlatlandBRDF(0.5, np.deg2rad(width_deg), 0.2, window_exponent=2.0)
    brdf = SpatiallyVaryingBRDF(base, lambda y: 1.0 - 0.5 * np.exp(-(y / 20.0) ** 2),
                                lambda y: 1.0 + 0.3 * np.tanh(y / 30.0))
    _compare(Wall(-150.0, 150.0, brdf, lambda c: 0.05 * np.sin(c / 40.0)), seed=2)


def test_a_perfect_mirror_returns_the_incident_radiance_in_the_mirror_direction():
    """σ = 0: ρ_s cos⁺ⁱ⁺ᵠ(θ_m − Θ) L(c, θ_m) plus the diffuse term (eq. 2-14 as σ → 0)."""
    base = FlatlandBRDF(0.7, 1e-3, 0.1, window_exponent=1.0)
    rng = np.random.default_rng(3)
    c = rng.uniform(-50.0, 50.0, 400)
    tm = rng.uniform(-0.3, 0.3, 400)
    normal = np.full(c.shape, 0.02)
    mirror = lightfield_lobe.lobe_radiance(base, normal, OBJECTS, c, tm, width_rad=0.0)
    diffuse = lightfield_lobe.lobe_radiance(FlatlandBRDF(0.0, 1e-3, 0.1), normal, OBJECTS,
                                            c, tm)
    # the incident radiance along the mirror direction, from the objects whose angular
    # interval holds it (the Gaussian profile is cut at its interval, as the renderer has it)
    incident = np.zeros(c.shape)
    for o in OBJECTS:
        lo, hi = o.interval(c)
        incident += np.where((lo <= tm) & (tm <= hi), o.radiance_at(c, tm), 0.0)
    assert np.count_nonzero(incident) > 20
    np.testing.assert_allclose(mirror - diffuse, 0.7 * np.cos(tm - 0.02) ** 2 * incident,
                               rtol=1e-12, atol=1e-12)


def test_a_vanishing_width_tends_to_the_mirror():
    """Away from the objects' edges (more than 8σ) a 10⁻⁹ rad lobe is the mirror to
    O(σ²); at an edge it is half the mirror's value (the lobe half on the object)."""
    base = FlatlandBRDF(0.7, 1e-3, 0.0)
    disc = (PointObject(-8.0, -200.0, 1.5, 5.0),)
    c = np.linspace(-20.0, 5.0, 301)
    lo, hi = disc[0].interval(c)
    tm = np.concatenate([0.5 * (lo + hi), lo, hi + 1e-3])
    cc = np.tile(c, 3)
    zero = np.zeros(cc.shape)
    mirror = lightfield_lobe.lobe_radiance(base, zero, disc, cc, tm, width_rad=0.0)
    thin = lightfield_lobe.lobe_radiance(base, zero, disc, cc, tm, width_rad=1e-9)
    n = c.size
    np.testing.assert_allclose(thin[:n], mirror[:n], rtol=1e-12)
    np.testing.assert_allclose(thin[n:2 * n], 0.5 * 0.7 * 5.0 * np.cos(lo), rtol=1e-6)
    assert np.all(thin[2 * n:] == 0.0) and np.all(mirror[2 * n:] == 0.0)


class _Counting(PointObject):
    """A Gaussian-profile object that counts the rays × nodes it is evaluated at."""

    calls: list[int]

    def radiance_at(self, c, theta):
        self.calls.append(int(np.broadcast(c, theta).size))
        return super().radiance_at(c, theta)


def test_cost_per_ray_does_not_grow_as_the_lobe_narrows():
    """The reference's node count grows as 1/σ; the lobe renderer's is bounded: the lobe
    takes max(16, span/PANEL_RAD) panels (16 units of t, or the object's varying radiance
    resolved), the diffuse term span/PANEL_RAD, 8 nodes each."""
    counts = {}
    rays = 50
    tm = np.linspace(-0.2, 0.2, rays)
    for width in (1e-2, 1e-4, 1e-6, 1e-8):
        obj = _Counting(40.0, -150.0, 2.0, 2.0, "gaussian")
        object.__setattr__(obj, "calls", [])
        brdf = FlatlandBRDF(0.6, width, 0.08)
        HiddenScene((obj,), Wall(-150, 150, brdf), D2).radiance(np.full(rays, 40.0), tm)
        counts[width] = sum(obj.calls) / rays
    span_panels = np.ceil(2 * np.arcsin(5 * 2.0 / 150.0) / lightfield_lobe.PANEL_RAD)
    assert max(counts.values()) <= 8 * (max(16, span_panels) + span_panels)
    assert counts[1e-8] <= counts[1e-2]


def test_renderer_choice_is_checked_and_a_plain_callable_uses_the_reference():
    wall = Wall(-50.0, 50.0, FlatlandBRDF(0.6, 0.01, 0.1))
    with pytest.raises(ValueError, match="renderer"):
        HiddenScene(OBJECTS, wall, D2, renderer="fast")
    brdf = FlatlandBRDF(0.6, 0.01, 0.1)
    plain = Wall(-50.0, 50.0, lambda ti, to: brdf(ti, to))
    ym, tm = _rays(4, 30)
    np.testing.assert_allclose(HiddenScene(OBJECTS, plain, D2).radiance(ym, tm),
                               HiddenScene(OBJECTS, wall, D2).radiance(ym, tm),
                               rtol=1e-9, atol=1e-12)
