"""The candidates' models through the sample plan give the detection of the runs' sums.

``detect_objects(sample_plan=True)`` (the default) takes every point-response model's
samples as sparse products laid out once (:class:`analysis.lightfield.wall_samples.
SamplePlan`); ``sample_plan=False`` sums each over the rays' runs, as before.  The stacks
agree to rounding (``test_wall_samples.py``), so the whole detection must: the same
objects, candidates below the threshold, flags, intervals and notes.  A bright and a 100×
dimmer disc behind the brushed metal (the scene of the significance tests; many
candidates examined, so many models), rendered by the continuous renderer with seeded
noise.
"""

from __future__ import annotations

import functools

import numpy as np

from analysis.lightfield import detect_objects, effective_p_max, material, reconstruct
from analysis.lightfield.wall_samples import SamplePlan
from hw_mocks.sim.lightfield_scene import HiddenScene, PointObject, Wall

DOMAIN = (-0.6, 0.6)


@functools.cache
def _reconstruction():
    brdf = material("brushed_metal")
    objects = (PointObject(-20.0, -200.0, 1.5, 1.0), PointObject(20.0, -220.0, 1.5, 0.01))
    scene = HiddenScene(objects, Wall(-150.0, 150.0, brdf), d2_mm=100.0)
    lf = scene.measured_field(np.linspace(-180.0, 180.0, 361), DOMAIN, 128)
    rng = np.random.default_rng(22)
    noisy = lf.with_radiance(lf.radiance + rng.normal(0.0, 2e-4, lf.shape))
    return reconstruct(noisy, brdf, d2_mm=100.0, points_mm=np.arange(-100.0, 100.1, 1.0))


def _detect(sample_plan: bool):
    rec = _reconstruction()
    return detect_objects(
        rec.incident_field, p_max=effective_p_max(rec.regularization.filter_factors,
                                                   rec.orders),
        y_mm=np.arange(-90.0, 90.1, 2.0), z_mm=np.arange(-400.0, -59.0, 4.0),
        solvable_domain_rad=rec.solvable_domain_rad,
        filter_factors=rec.regularization.filter_factors,
        noise_power=rec.regularization.noise_power, min_measure_fraction=0.1,
        sample_plan=sample_plan)


def test_the_sample_plan_gives_the_detection_of_the_runs():
    planned, runs = _detect(True), _detect(False)
    assert planned.count == runs.count >= 1
    assert planned.below_significance.size == runs.below_significance.size >= 1
    assert planned.quality == runs.quality
    assert planned.notes == runs.notes
    np.testing.assert_array_equal(planned.depth_open, runs.depth_open)
    # rounding of the sums' order only: far below any blur (mm) or significance (σ)
    for name in ("positions_mm", "depth_interval_mm", "significance", "extent_mm",
                 "below_positions_mm", "below_significance", "brightness_rp",
                 "across_interval_mm"):
        np.testing.assert_allclose(getattr(planned, name), getattr(runs, name), rtol=0,
                                   atol=1e-9, err_msg=name)


def test_a_plan_over_its_memory_budget_is_not_made():
    y = np.arange(-90.0, 90.1, 0.5)
    zs = np.arange(-400.0, -59.0, 10.0)
    t = np.tan(np.linspace(-0.5, 0.5, 64))
    whole = SamplePlan.build(60, 32, -30.0, 1.0, y, zs, t, 29.0)
    assert whole is not None and whole.nbytes > 0
    assert SamplePlan.build(60, 32, -30.0, 1.0, y, zs, t, 29.0,
                            max_bytes=0.5 * whole.nbytes) is None
