"""Closed loops of the polarimetric fit through the engine on ``sim-polarimetric``: a fast
copy of the bench, a plan, a run and the world's truth at each geometry (shared by the
slow tests and ``benchmarks/bench_polarimetric_fit.py``)."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from analysis.polarimetry.elements import rotated
from hw_mocks.sim.world import find_world
from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.run.runfile import read_run

#: The generator polariser's hidden azimuth: the calibration's frame is turned by it.
FRAME_DEG = 0.3

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "{name}"
order = "raster"
[sample]
name = "{name}"
[scan]
theta_i = [{ti}]
theta_r = [{tr}]
[acquisition]
detectors = ["power_meter"]
dark = "per_point"
[polarimetry]
mode = "drr"
steps = 25
"""


def plan_text(name: str, theta_i: str, theta_r: str) -> str:
    """A 25-step polarimetric in-plane plan (θ lists as TOML text, e.g. ``"40.0, 50.0"``)."""
    return PLAN.format(name=name, ti=theta_i, tr=theta_r)


def fast_bench(folder: Path, scene: str | None = None, seed: int | None = None) -> Path:
    """``sim-polarimetric`` with mounts 100× faster, another sample table (``scene``,
    the text of a ``[simulation.scene.pbrdf]`` table) or another meter noise seed."""
    text = load_profile("sim-polarimetric").source_text.replace(
        "model=K10CR1&speed=50", "model=K10CR1&speed=5000")
    if scene is not None:
        text = re.sub(r"\[simulation\.scene\.pbrdf\][^\[]*", scene, text, flags=re.DOTALL)
    if seed is not None:
        text = text.replace("world=sim-polarimetric&seed=2",
                            f"world=sim-polarimetric&seed={seed}")
    path = folder / f"bench-{abs(hash((scene, seed))) % 10**8}.toml"
    path.write_text(text, encoding="utf-8")
    return path


def run_with_truth(folder: Path, bench: Path, plan: str, steps: int = 25, *,
                   world_name: str = "sim-polarimetric", frame_deg: float = FRAME_DEG,
                   straight_through: bool = False
                   ) -> tuple[Path, dict[tuple[int, int], np.ndarray]]:
    """Run ``plan`` on ``bench``; the world's aperture-averaged, normalised matrix at each
    geometry's read-back pose (keyed by rounded (θi, θr)), in the calibration's frame
    (turned by ``frame_deg``), taken while the emulated bench's world ``world_name`` is
    still alive. ``steps``: points per geometry. ``straight_through``: the world's own pose
    (a reference in the beam, the world's detector arm held by ``[simulation.roles]``)
    instead of the run's read-back one."""
    path_plan = folder / "plan.toml"
    path_plan.write_text(plan, encoding="utf-8")
    out = folder / "runs"
    assert main(["run", str(path_plan), "--bench", str(bench), "--out", str(out),
                 "--no-fsync", "--quiet"]) == 0
    (path,) = out.glob("*.h5")
    world = find_world(world_name)
    assert world is not None
    run = read_run(path)
    truths = {}
    for row in range(0, run.n_points, steps):
        state = world.snapshot()
        if not straight_through:
            state = replace(state, pose=world.pose(
                {a: float(run.positions[row, k]) for k, a in enumerate(run.axes)}))
        pose = state.pose
        state = replace(state, source=replace(state.source, on=True))
        head = world.power_meter
        m = np.asarray(state.scene.mueller_on_aperture(  # type: ignore[union-attr]
            pose.detector_dir * head.distance_mm, -pose.detector_dir,
            head.aperture_diameter_mm, state))
        key = (round(float(run.theta_i[row])), round(float(run.theta_r[row])))
        truths[key] = rotated(m / m[0, 0], -math.radians(frame_deg))
    return path, truths


def pulls(point, truth: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    """(m_ij/m00 − truth)/σ of the 15 normalised elements (m00's σ is 0)."""
    s = np.where(point.brdf.sigma_normalised > 0, point.brdf.sigma_normalised, 1.0)
    return np.asarray(((point.brdf.m_normalised - truth) / s).ravel()[1:])
