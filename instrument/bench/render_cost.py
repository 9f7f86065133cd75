"""What rendering one view of a simulated light-field wall costs, for duration estimates.

The emulated light-field bench (``[simulation.scene] kind = "lightfield"``) renders every
view after a move: one flatland ray per sensor column, and per ray and hidden object a
Gauss–Legendre quadrature whose node count depends on the renderer and the wall's specular
width σ (``hw_mocks.sim.lightfield_lobe``, ``hw_mocks.sim.lightfield_scene``):

* ``renderer = "lobe"`` (default): the lobe in units of σ over at most ±8σ clipped to the
  object's angular span s: ``8 ⌈min(16, s/σ)⌉`` nodes; for an object of varying radiance
  (a Gaussian-profile disc) the lobe's panels are also at most 2 mrad wide and the diffuse
  term takes ``8 ⌈s/2 mrad⌉`` more; a uniform object's diffuse term is closed-form.
* ``renderer = "reference"``: panels of σ/4 over the whole span: ``8 ⌈s/(σ/4)⌉`` nodes,
  which grows as 1/σ (41.7 s a view at σ = 0.001° on the dev box, BENCHMARKS.md).

The span of a disc of radius r at depth |z| is ``2 asin(r/|z|)`` (its Gaussian profile
reaches 5 r), of a bar of length ℓ ``2 atan(ℓ/(2|z|))`` (the widest, seen from its middle).
Seconds per node and per view are measured on the project's dev box
(``benchmarks/bench_lightfield_render.py``), so that
``render_s = VIEW_S + node_s × columns × Σ_objects nodes`` (never zero for a lit view).
The node rules are kept in step with the renderer by
``tests/instrument/bench/test_render_cost.py``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["NODE_S", "VIEW_S", "lightfield_render_s", "nodes_per_ray"]

#: Seconds per view besides the quadrature: the lens grid, the flatland mapping of the
#: rays, the cache (measured: a lit view of a wall with no object in sight).
VIEW_S = 0.01
#: Seconds per ray and quadrature node, by renderer (the lobe's uniform objects skip the
#: object's radiance function; measured with bench_lightfield_render.py at 0.0001°–10°).
NODE_S = {"lobe": 1.0e-7, "reference": 2.6e-7}
_GL_NODES = 8
_LOBE_WINDOW = 8.0
_PANEL_RAD = 2e-3


def _width_rad(scene: Mapping[str, Any]) -> float:
    if "brdf" in scene:
        return math.radians(float(scene["brdf"]["specular_width_deg"]))
    # imported here: analysis.lightfield pulls in scipy.optimize and scipy.stats (~0.6 s
    # CPU), and every `scatterlab run` and `plan` imports this module for other benches
    from analysis.lightfield.brdf import MATERIALS

    name = str(scene.get("material", "brushed_metal"))
    material = MATERIALS.get(name)
    if material is None:
        raise ValueError(f"[simulation.scene]: unknown material {name!r}; choose from "
                         f"{sorted(MATERIALS)}")
    return float(material.specular_width_rad)


def _span_rad(obj: Mapping[str, Any]) -> tuple[float, bool]:
    """(angular span at the wall in rad, True if the object's radiance is uniform)."""
    depth = abs(float(obj["z_mm"]))
    if obj.get("kind", "point") == "bar":
        length = float(obj["y_max_mm"]) - float(obj["y_min_mm"])
        return 2.0 * math.atan(0.5 * length / depth), True
    radius = float(obj.get("radius_mm", 1.0))
    uniform = obj.get("profile", "disc") == "disc"
    reach = radius if uniform else 5.0 * radius
    return 2.0 * math.asin(min(1.0, reach / depth)), uniform


def nodes_per_ray(span_rad: float, width_rad: float, uniform: bool,
                  renderer: str = "lobe") -> int:
    """Quadrature nodes one ray costs for one object (module docstring)."""
    if renderer == "reference":
        return _GL_NODES * max(1, math.ceil(span_rad / (0.25 * width_rad)))
    t_range = min(2 * _LOBE_WINDOW, span_rad / width_rad)
    panels = max(1, math.ceil(t_range))
    if uniform:
        return _GL_NODES * panels
    lobe = max(panels, math.ceil(t_range * width_rad / _PANEL_RAD))
    diffuse = max(1, math.ceil(span_rad / _PANEL_RAD))
    return _GL_NODES * (lobe + diffuse)


def lightfield_render_s(scene: Mapping[str, Any], columns: int) -> float:
    """Seconds one lit view of the light-field ``scene`` (its ``[simulation.scene]``
    table) takes to render on a camera ``columns`` pixels wide."""
    renderer = str(scene.get("renderer", "lobe"))
    if renderer not in NODE_S:
        raise ValueError(f"[simulation.scene]: renderer {renderer!r}; choose one of "
                         f"{sorted(NODE_S)}")
    width = _width_rad(scene)
    nodes = 0
    for obj in scene.get("objects", ()):
        span, uniform = _span_rad(obj)
        nodes += nodes_per_ray(span, width, uniform, renderer)
    return VIEW_S + NODE_S[renderer] * int(columns) * nodes
