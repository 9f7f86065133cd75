"""The simulated camera's fast renderer against its reference (exhaustive) renderer on the
same seeded scenes: the noise-free photon rates agree within the pupil rule's own
tolerance, and the frames (same seed, so the same noise realisation) have the same
statistics — mean signal, shot and read noise, dark level, saturated pixels."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from drivers.base import PixelFormat, Roi
from hw_mocks.sim import lens
from hw_mocks.sim.camera import (
    OpticsParams,
    SimulatedCamera,
    _disk_dilation,
    _disk_structure,
    open_from_url,
)
from hw_mocks.sim.goniometer_scene import GoniometerScene, brdf_from_model
from hw_mocks.sim.sensor import SensorParams
from hw_mocks.sim.world import VirtualBench, reset_worlds

# 1024 px of the full sensor seen by 160 px (the same field, coarser pixels): every test
# renders in well under a second with both renderers
SENSOR = SensorParams(width=160, height=160, pixel_pitch_um=5.5 * 1024 / 160)
RTOL, ATOL_OF_MAX = 1e-6, 1e-9  # the pupil rule's tolerance (OpticsParams, camera.py)
F32 = 2.0**-23  # two float32 roundings of the returned photon rate


@pytest.fixture(autouse=True)
def _fresh_worlds():
    reset_worlds()
    yield
    reset_worlds()


def bench(theta_s: float, theta_d: float, scene: GoniometerScene | None = None,
          **source) -> VirtualBench:
    world = VirtualBench("t", roles={"sample_theta": theta_s, "detector_theta": theta_d},
                         scene=scene if scene is not None else GoniometerScene(
                             brdf=brdf_from_model("lambert+ggx", [0.5, 0.2, 0.2])))
    world.update_source(**({"on": True, "power_w": 1e-3} | source))
    return world


def rates(world: VirtualBench, optics: OpticsParams | None = None,
          sensor: SensorParams = SENSOR, roi: Roi | None = None
          ) -> tuple[np.ndarray, np.ndarray]:
    out = []
    for renderer in ("reference", "fast"):
        cam = SimulatedCamera(world=world, sensor=sensor, optics=optics, renderer=renderer)
        if roi is not None:
            cam.roi = roi
        out.append(np.array(cam.photon_rate(), dtype=np.float64))
    return out[0], out[1]


def assert_same_rendering(ref: np.ndarray, fast: np.ndarray) -> None:
    """Each renderer is within RTOL·|value| + ATOL·max of the converged integral, so the
    two within twice that (plus the float32 rounding of the result)."""
    tol = 2.0 * (RTOL * np.abs(ref) + ATOL_OF_MAX * ref.max()) + F32 * np.abs(ref)
    assert np.all(np.abs(fast - ref) <= tol)
    assert fast.sum() == pytest.approx(ref.sum(), rel=2.0 * RTOL)


LIT_VIEWS = [
    (20.0, 40.0), (40.0, 80.0), (60.0, 120.0),  # the main job's specular points
    (20.0, -30.0), (40.0, 10.0), (0.0, 30.0),  # off-specular, back-scatter side
    (80.0, 160.0),  # grazing: the footprint reaches far beyond the sample's rim
]


@pytest.mark.parametrize(("theta_s", "theta_d"), LIT_VIEWS)
def test_fast_renderer_matches_the_reference(theta_s, theta_d):
    ref, fast = rates(bench(theta_s, theta_d))
    assert ref.max() > 10.0 * ref.min()  # a lit view (the test can fail)
    assert_same_rendering(ref, fast)


@pytest.mark.parametrize(("theta_s", "theta_d"), [(40.0, 80.0), (80.0, 160.0)])
def test_sharp_lobe_needs_the_finer_rungs_and_gets_them(theta_s, theta_d):
    """GGX α = 0.02 at its specular peak: the first check fails on the lobe, so the
    ladder goes on (as in the reference); both agree within the tolerance."""
    scene = GoniometerScene(brdf=brdf_from_model("lambert+ggx", [0.3, 0.5, 0.02]))
    world = bench(theta_s, theta_d, scene=scene)
    ref, fast = rates(world)
    assert_same_rendering(ref, fast)
    chief = np.array(SimulatedCamera(world=world, sensor=SENSOR,
                                     optics=OpticsParams(pupil="chief")).photon_rate())
    assert abs(chief.sum() / fast.sum() - 1.0) > 0.05  # the pupil matters here


def test_beam_wider_than_the_sample_and_the_veil():
    """The sample's rim clips a 10 mm beam, and the ambient light and the instrument
    signature add a veil over the whole frame: outside the lit box the fast renderer
    takes the veil from one ray."""
    scene = GoniometerScene(brdf=brdf_from_model("lambert+ggx", [0.5, 0.2, 0.2]),
                            ambient_radiance=0.05, signature_sr=1e-3)
    ref, fast = rates(bench(30.0, 70.0, scene=scene, beam_radius_mm=10.0))
    assert_same_rendering(ref, fast)
    ref, fast = rates(bench(30.0, 170.0, scene=scene))  # near the beam: signature peak
    assert_same_rendering(ref, fast)


@pytest.mark.parametrize("case", ["dark", "no_sample", "back", "chief", "roi", "camera_z"])
def test_fast_renderer_edge_cases(case):
    world = bench(30.0, 60.0)
    optics, roi = None, None
    if case == "dark":
        world.update_source(on=False)
    elif case == "no_sample":
        world = bench(30.0, 60.0, scene=GoniometerScene(target="none", ambient_radiance=0.1))
    elif case == "back":  # the camera behind the sample's plane
        world = bench(60.0, -120.0)
    elif case == "chief":
        optics = OpticsParams(pupil="chief")
    elif case == "roi":
        roi = Roi(40, 72, 64, 48)  # part of the spot, off centre
    elif case == "camera_z":
        world.set_role("camera_z", 60.0)  # focus and magnification change with it
    ref, fast = rates(world, optics=optics, roi=roi)
    assert_same_rendering(ref, fast)


def frame_statistics(frames: list, saturation: float) -> dict[str, float]:
    stack = np.stack([f.data.astype(np.float64) for f in frames])
    diff = stack[0] - stack[1]
    return {"mean": float(stack.mean()), "pair_var": float(diff.var() / 2.0),
            "saturated": float(np.count_nonzero(stack >= saturation))}


@pytest.mark.parametrize(("exposure_us", "light"), [(2000.0, True), (200.0, True),
                                                      (2000.0, False)])
def test_frames_have_the_reference_statistics(exposure_us, light):
    """Same seed, same frame indices: the sensor draws the same noise for both
    renderers, so the frames can differ only where the photon rates round differently
    (by 1 DN, in a few pixels at most); their statistics then agree far inside their
    noise. 2000 µs saturates the specular peak; 200 µs does not; the dark frame shows
    dark current and read noise alone."""
    world = bench(40.0, 80.0)
    world.update_source(on=light)
    stats, frames = {}, {}
    for renderer in ("reference", "fast"):
        cam = SimulatedCamera(world=world, seed=11, sensor=SENSOR, renderer=renderer,
                              pixel_format=PixelFormat.MONO12)
        cam.exposure_us = exposure_us
        frames[renderer] = cam.acquire(2)
        stats[renderer] = frame_statistics(frames[renderer], cam.sensor.saturation_dn(
            gain_db=0.0, bits=12))
    for a, b in zip(frames["reference"], frames["fast"], strict=True):
        changed = np.abs(a.data.astype(int) - b.data.astype(int))
        assert changed.max() <= 1 and np.count_nonzero(changed) <= 1e-3 * changed.size
    n = SENSOR.width * SENSOR.height
    ref, fast = stats["reference"], stats["fast"]
    # a pixel changed by 1 DN moves the mean by 1/n and the variance by ~2 DN/n each
    budget = 1e-3 * n
    assert fast["mean"] == pytest.approx(ref["mean"], abs=budget / n)
    assert fast["pair_var"] == pytest.approx(ref["pair_var"], abs=8.0 * 4096 * budget / n)
    assert abs(fast["saturated"] - ref["saturated"]) <= budget
    if light and exposure_us == 2000.0:
        assert ref["saturated"] > 0  # the saturated case is exercised


def test_lens_grid_is_computed_once_and_read_only():
    a = lens.lens_grid((0, 0, 32, 16), (32, 16), 5.5, 50.0, 6.25, 300.0)
    assert lens.lens_grid((0, 0, 32, 16), (32, 16), 5.5, 50.0, 6.25, 300.0) is a
    assert not a.obliquity.flags.writeable
    # on axis the obliquity is the exact mean of cos⁴γ to (ρ/F)⁶: 1 − 2(ρ/F)²/… ≈ 1/(1+(ρ/F)²)
    centre = a.obliquity[7:9, 15:17].mean()
    assert centre == pytest.approx(1.0 / (1.0 + (6.25 / 300.0) ** 2), rel=1e-6)
    assert math.isclose(a.cos_alpha.max(), 1.0, rel_tol=1e-6)


def test_renderer_option():
    cam = open_from_url("simcam://c?renderer=reference&width=8&height=8")
    assert cam.renderer == "reference"
    assert open_from_url("simcam://c?width=8&height=8").renderer == "fast"
    with pytest.raises(ValueError, match="renderer"):
        open_from_url("simcam://c?renderer=quick")


def test_threaded_pupil_integral_is_the_single_threaded_one(monkeypatch):
    """Pixels split between worker threads are computed exactly as in one piece."""
    from hw_mocks.sim import workers

    world = bench(40.0, 80.0)
    monkeypatch.setattr(workers, "THREADS", 1)
    one = np.array(SimulatedCamera(world=world, sensor=SENSOR).photon_rate())
    monkeypatch.setattr(workers, "THREADS", 3)
    monkeypatch.setattr(workers, "BLOCK_PIXELS", 64)
    split = np.array(SimulatedCamera(world=world, sensor=SENSOR).photon_rate())
    np.testing.assert_array_equal(split, one)


def test_pupil_bundle_projections_are_the_rays():
    """The bundle's projections (per-pixel part computed once) equal the pupil rays'
    directions projected, to rounding, for index arrays and broadcast rows × columns."""
    grid = lens.lens_grid((0, 0, 64, 48), (64, 48), 5.5 * 16, 50.0, 6.25, 300.0)
    rng = np.random.default_rng(5)
    axes = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    right, down, forward = axes[:, 0], axes[:, 1], axes[:, 2]
    rows, cols = rng.integers(0, 48, 500), rng.integers(0, 64, 500)
    bundle = grid.pupil_bundle(rows, cols, right, down, forward)
    for x, y in ((0.0, 0.0), (0.8, -0.1), (-0.3, 0.9)):
        d, cos_g = grid.pupil_rays(x, y, rows, cols, right, down, forward)
        project, cos_b = bundle.rays(x, y)
        np.testing.assert_allclose(cos_b, cos_g, rtol=1e-15, atol=0.0)
        for a in (np.array([0.3, -1.2, 0.5]), -forward, right):
            # a few roundings of unit-scale terms in either order: 4 ε |a|
            np.testing.assert_allclose(project(a), d @ a, rtol=0.0,
                                       atol=4.0 * 2.0**-52 * np.linalg.norm(a))
    r, c = np.arange(10, 20)[:, None], np.arange(3, 40)[None, :]
    project, cos_b = grid.pupil_bundle(r, c, right, down, forward).rays(0.0, 0.0)
    dirs = grid.chief_directions(slice(10, 20), slice(3, 40), right, down, forward)
    assert cos_b.shape == (10, 37)
    np.testing.assert_allclose(project(forward), dirs @ forward, rtol=0.0,
                               atol=4.0 * 2.0**-52)


@settings(max_examples=150, deadline=None)
@given(mask=hnp.arrays(np.bool_, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1,
                                                   max_side=48),
                       elements=st.sampled_from([False, False, False, False, True])),
       radius=st.integers(0, 60))
def test_the_refined_region_is_the_disk_dilation_and_the_distance_transform(mask, radius):
    """The fast renderer grows its refined region row by row (``_disk_dilation``): the same
    pixels as the reference's disk dilation and the distance transform ≤ radius it
    replaces, at every radius (wider than the mask too) and with no pixel lit."""
    from scipy import ndimage

    got = _disk_dilation(mask, radius)
    assert got.dtype == np.bool_ and got.shape == mask.shape
    want = ndimage.binary_dilation(mask, structure=_disk_structure(radius)) if radius else mask
    assert np.array_equal(got, want)
    if mask.any():
        assert np.array_equal(got, ndimage.distance_transform_edt(~mask) <= radius)
