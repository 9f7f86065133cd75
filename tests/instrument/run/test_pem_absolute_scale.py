"""A PEM run's absolute scale and σ over the glass (ADR 0106, amendment "PEM scale and σ").

The glass of ``sim-polarimetric-pem`` (its hidden train ideal, the nominal reduction) at
θi 50°, θr 50° over three lock-in seeds: m00 against the world's own aperture-averaged
BRDF (``mueller_on_aperture`` over P Ω cos θr, W per unit source Stokes vector), and the
pulls (m_ij − truth)/σ of the sixteen absolute elements by column. Columns 0 and 2 come
from the DC (Aux In 1, 16-bit: the glass's 3–8 mV are 10–25 codes, σ ~1 % of m00),
columns 1 and 3 from the 1f and 2f (the lock-in's noise, σ ~10⁻⁵ of m00): a ratio of
σ of a thousand between the columns is the instrument's, and each column's pulls spread
about 1. The same glass and geometry on the DRR bench (``sim-polarimetric``, its hidden
optics as its calibration, the air scan's scale) gives the same m00 within the two runs'
combined σ: both benches' photodiode/meter scales are the truth's, by design.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from analysis.brdf.reduction.detector import solid_angle_sr
from hw_mocks.sim.world import find_world
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from instrument.pipelines.polarimetry.reduce import MuellerPoint
from instrument.run.runfile import read_run
from tests.instrument.pipelines.polarimetry.closed_loop import (
    fast_bench,
    run_with_truth,
)
from tests.instrument.pipelines.polarimetry.closed_loop import (
    plan_text as drr_plan_text,
)
from tests.instrument.pipelines.polarimetry.test_polarimetric_fit import _oracle
from tests.instrument.run.test_pem_run import fast_pem_bench, plan_text

#: The benches' source power (W), receiver aperture and distance (mm).
POWER_W, APERTURE_MM, DISTANCE_MM = 1e-3, 5.0, 300.0


def _fit_with_truth(folder: Path, bench: Path, plan: str, steps: int, world: str
                    ) -> tuple[MuellerPoint, np.ndarray]:
    """The run's one geometry fitted, and the world's absolute BRDF matrix (1/sr) there."""
    path, _ = run_with_truth(folder, bench, plan, steps=steps, world_name=world,
                             frame_deg=0.0)
    bench_world = find_world(world)
    assert bench_world is not None
    run = read_run(path)
    state = bench_world.snapshot()
    state = replace(state, source=replace(state.source, on=True), pose=bench_world.pose(
        {a: float(run.positions[0, k]) for k, a in enumerate(run.axes)}))
    head = bench_world.power_meter
    power = np.asarray(state.scene.mueller_on_aperture(  # type: ignore[union-attr]
        state.pose.detector_dir * head.distance_mm, -state.pose.detector_dir,
        head.aperture_diameter_mm, state))
    if world == "sim-polarimetric":
        _oracle(folder / "runs")  # the hidden optics as the calibration beside the run
    (point,) = fit_polarimetric_run(path, report=False, write=False).points
    omega, _ = solid_angle_sr(APERTURE_MM, DISTANCE_MM)
    return point, power / (POWER_W * omega * math.cos(math.radians(point.group.theta_r)))


@pytest.mark.slow  # three PEM runs over the glass's pBRDF world: about a minute
def test_pem_m00_is_the_truth_and_each_column_pulls_spread_about_one(tmp_path):
    pulls, sigmas, found = [], [], []
    for seed in (1, 2, 3):
        folder = tmp_path / f"s{seed}"
        folder.mkdir()
        point, truth = _fit_with_truth(folder, fast_pem_bench(folder, seed=seed),
                                       plan_text(ti="50.0", tr="50.0"), 8,
                                       "sim-polarimetric-pem")
        m, s = point.brdf.m, point.brdf.sigma
        found.append((m[0, 0], s[0, 0], truth[0, 0]))
        # m00 ≈ 0.59 1/sr with σ ≈ 0.005 (the DC's quantisation); half of it before the fix
        assert abs(m[0, 0] - truth[0, 0]) < 3.0 * s[0, 0] < 0.03 * truth[0, 0], found[-1]
        pulls.append((m - truth) / s)
        sigmas.append(s)
    p = np.array(pulls)  # (seed, row, column)
    # 12 pulls per column; columns 0 and 2 rest on the DC, whose quantisation error is the
    # same for every seed (a steady input reads one code), so they hold 4 independent
    # values: their rms within 0.3–2.0 (a unit-variance χ²₄/4 is outside 1 time in 100);
    # columns 1 and 3, 12 independent values: 0.5–1.6 (χ²₁₂/12, 1 in 100)
    rms = np.sqrt(np.mean(p**2, axis=(0, 1)))
    assert 0.3 < rms[0] < 2.0 and 0.3 < rms[2] < 2.0, rms
    assert 0.5 < rms[1] < 1.6 and 0.5 < rms[3] < 1.6, rms
    sig = np.sqrt(np.mean(np.array(sigmas) ** 2, axis=(0, 1)))  # rms σ per column
    # the DC-read columns' σ is far above the harmonics' (the Aux In's step against the
    # lock-in's noise): the instrument's, not an error of the σ
    assert sig[0] > 100 * sig[1] and sig[2] > 100 * sig[3], sig


@pytest.mark.slow  # a 25-step DRR run and a PEM run over the glass: about a minute
def test_the_glass_m00_agrees_on_the_drr_and_pem_benches(tmp_path):
    (tmp_path / "drr").mkdir()
    (tmp_path / "pem").mkdir()
    drr, truth_drr = _fit_with_truth(
        tmp_path / "drr", fast_bench(tmp_path / "drr"), drr_plan_text("glass", "50.0", "50.0"),
        25, "sim-polarimetric")
    pem, truth_pem = _fit_with_truth(
        tmp_path / "pem", fast_pem_bench(tmp_path / "pem"), plan_text(ti="50.0", tr="50.0"),
        8, "sim-polarimetric-pem")
    a, sa = drr.brdf.m[0, 0], drr.brdf.sigma[0, 0]
    b, sb = pem.brdf.m[0, 0], pem.brdf.sigma[0, 0]
    # the same sample (n 1.5, slope 0.15, albedo 0.3) and geometry on both worlds; the
    # DRR's read-back pose differs from the PEM's by the stages' steps only
    assert truth_drr[0, 0] == pytest.approx(truth_pem[0, 0], rel=2e-3)
    # within the combined σ (3σ: one time in 370 by chance); before, PEM read 0.52 of DRR
    assert abs(a - b) < 3.0 * math.hypot(sa, sb), (a, sa, b, sb)
