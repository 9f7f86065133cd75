"""Per-point render time of the simulated light-field wall against its specular width.

One "point" is what the simulated camera does after the ``camera_z`` stage moved: render the
new view (1024 × 8 px, 4 mm lens, 5.5 µm pixels, the ``sim-lightfield`` bench's camera) of
the bench's scene (a disc and a bar behind the wall, d2 = 30 mm) — ``photon_rate`` on a state
it has not cached.  For each specular width (ρ_s = 0.6, ρ_d = 0.08, the brushed-metal wall's
reflectances) and renderer (``lobe``, the default; ``reference``, the panel quadrature) the
median over ``--points`` camera positions, and the largest difference between the two
renderers' views relative to the view's peak where both ran; beside each time, the cost
model the duration estimate uses (:mod:`instrument.bench.render_cost`).

Run: ``python benchmarks/bench_lightfield_render.py`` (the reference down to 0.001°; it
takes ~20 s a view there) — ``--quick``: the lobe renderer only, 3 points a width.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from hw_mocks.sim.camera import OpticsParams, SimulatedCamera
from hw_mocks.sim.sensor import SensorParams
from hw_mocks.sim.world import VirtualBench
from instrument.bench.render_cost import lightfield_render_s

WIDTHS_DEG = (10.0, 1.0, 0.1, 0.01, 0.001, 0.0001)


def scene(width_deg: float, renderer: str) -> dict:
    """The sim-lightfield bench's scene on a wall of the given specular width."""
    return {
        "kind": "lightfield",
        "brdf": {"specular_reflectance": 0.6, "specular_width_deg": width_deg,
                 "diffuse_reflectance": 0.08},
        "wall": [-150.0, 150.0],
        "camera_track": {"x0_mm": 0.0, "z_mm": 30.0, "direction": 1.0},
        "renderer": renderer,
        "objects": [
            {"kind": "point", "y_mm": -8.0, "z_mm": -200.0, "radius_mm": 1.5,
             "radiance": 5.0},
            {"kind": "bar", "y_min_mm": 15.0, "y_max_mm": 30.0, "z_mm": -260.0,
             "radiance": 1.5},
        ],
    }


def world(width_deg: float, renderer: str) -> VirtualBench:
    return VirtualBench.from_config("lf-bench", {
        "roles": {"camera_z": 0.0},
        "source": {"power_w": 1e-3, "on": True},
        "scene": scene(width_deg, renderer),
    })


def render_times(width_deg: float, renderer: str, positions) -> tuple[list[float], list]:
    w = world(width_deg, renderer)
    cam = SimulatedCamera("camera", world=w,
                          sensor=SensorParams(width=1024, height=8, pixel_pitch_um=5.5),
                          optics=OpticsParams(4.0, 1.0))
    times, views = [], []
    for z in positions:
        w.set_role("camera_z", float(z))
        t0 = time.perf_counter()
        views.append(np.asarray(cam.photon_rate(w.snapshot()), dtype=float))
        times.append(time.perf_counter() - t0)
    return times, views


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--points", type=int, default=3)
    ap.add_argument("--reference-down-to", type=float, default=0.001,
                    help="narrowest width (deg) the reference renderer is timed at")
    args = ap.parse_args()
    positions = np.linspace(-30.0, 30.0, args.points)
    print(f"{'width (deg)':>11} | {'lobe s/point':>12} | {'model':>6} | "
          f"{'reference s/point':>17} | {'model':>6} | {'max |Δ|/peak':>12}")
    for width in WIDTHS_DEG:
        t_lobe, v_lobe = render_times(width, "lobe", positions)
        ref = "—"
        diff = "—"
        if not args.quick and width >= args.reference_down_to * (1 - 1e-9):
            t_ref, v_ref = render_times(width, "reference", positions[:1])
            ref = f"{statistics.median(t_ref):.3f}"
            peak = float(np.max(v_ref[0]))
            diff = f"{float(np.max(np.abs(v_lobe[0] - v_ref[0]))) / peak:.1e}"
        m_lobe = lightfield_render_s(scene(width, "lobe"), 1024)
        m_ref = lightfield_render_s(scene(width, "reference"), 1024)
        print(f"{width:>11g} | {statistics.median(t_lobe):>12.4f} | {m_lobe:>6.3f} | "
              f"{ref:>17} | {m_ref:>6.3g} | {diff:>12}")


if __name__ == "__main__":
    main()
