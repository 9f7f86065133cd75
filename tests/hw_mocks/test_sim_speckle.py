"""Laser speckle on the simulated camera (hw_mocks.sim.speckle and the camera's use of it).

Statistics are checked with tolerances from the number of grains a statistic averages
(a sample contrast over K independent grains scatters by ≈ 1/√K relative).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hw_mocks import registry
from hw_mocks.sim.camera import OpticsParams, SimulatedCamera
from hw_mocks.sim.goniometer_scene import GoniometerScene
from hw_mocks.sim.sensor import SensorParams
from hw_mocks.sim.speckle import (
    SpeckleOptics,
    decorrelation_angle_deg,
    speckle_image,
    speckle_seed,
)
from hw_mocks.sim.state import SourceState
from hw_mocks.sim.world import VirtualBench, reset_worlds

WAVELENGTH_NM = 633.0
F_NUMBER = 5.0  # grain λ·F# = 3.165 µm


@pytest.fixture(autouse=True)
def _clean() -> None:
    registry.reset()
    reset_worlds()


def spot(h: int = 96, w: int = 128) -> np.ndarray:
    """A broad Gaussian spot (photons/s per pixel) whose core is flat to ±10 %."""
    y, x = np.mgrid[0:h, 0:w]
    return 1e6 * np.exp(-2.0 * (((x - w / 2) / (0.6 * w)) ** 2 + ((y - h / 2) / (0.6 * h)) ** 2))


def contrast(image: np.ndarray, mean: np.ndarray) -> float:
    core = mean > 0.8 * mean.max()
    return float((image[core] / mean[core]).std())


def test_fully_developed_speckle_has_unit_contrast_on_fine_pixels() -> None:
    # 1 µm pixels: a pixel is a third of a grain; ≈ 10⁴/(4/π·10) ≈ 800 grains in the core
    optics = SpeckleOptics(WAVELENGTH_NM, F_NUMBER, 1.0)
    rate = spot()
    image = speckle_image(rate, optics, [speckle_seed(7, [1.0, 2.0], 0)])
    assert contrast(image, rate) == pytest.approx(1.0, abs=0.15)
    # exponential statistics: P(I < ⟨I⟩/10) = 1 − e^(−0.1) = 0.095
    core = rate > 0.8 * rate.max()
    dark = np.mean(image[core] < 0.1 * rate[core])
    assert dark == pytest.approx(1.0 - math.exp(-0.1), abs=0.04)


def grains_per_pixel(pitch_um: float, grain_um: float) -> float:
    """M of a square pixel: 1/M = (1/A²) ∬ K(Δ) |μ(Δ)|² dΔ, K the pixel's overlap with
    itself shifted by Δ and μ = 2 J₁(v)/v the field correlation of a circular pupil
    (Goodman 2007, ch. 4, integrated speckle), by a midpoint rule."""
    from scipy.special import j1

    n = 400
    x = (np.arange(-n, n) + 0.5) * (pitch_um / n)
    gx, gy = np.meshgrid(x, x)
    v = math.pi / grain_um * np.hypot(gx, gy)
    mu = 2.0 * j1(v) / v
    overlap = (pitch_um - np.abs(gx)) * (pitch_um - np.abs(gy))
    return float(pitch_um**4 / (np.sum(overlap * mu**2) * (pitch_um / n) ** 2))


def test_pixel_larger_than_the_grain_lowers_the_contrast() -> None:
    # 12 µm pixels over 3.2 µm grains: M = 15.0 grains per pixel (above p²/A_c = 11.3,
    # A_c = (4/π)(λF#)²: grains at the pixel's edge count in part)
    optics = SpeckleOptics(WAVELENGTH_NM, F_NUMBER, 12.0)
    rate = spot()
    image = speckle_image(rate, optics, [speckle_seed(7, [1.0, 2.0], 0)])
    m = grains_per_pixel(12.0, optics.grain_um)
    # ≈ 550 pixels in the core: the sample contrast within ±15 % (about 3σ)
    assert contrast(image, rate) == pytest.approx(1.0 / math.sqrt(m), rel=0.15)


@pytest.mark.parametrize("n", [4, 16, 64])
def test_averaging_n_patterns_lowers_the_contrast_as_one_over_root_n(n: int) -> None:
    optics = SpeckleOptics(WAVELENGTH_NM, F_NUMBER, 1.0)
    rate = spot()
    seeds = [speckle_seed(3, [0.0], k) for k in range(min(n, 8))]
    image = speckle_image(rate, optics, seeds, patterns=n)
    assert contrast(image, rate) * math.sqrt(n) == pytest.approx(1.0, abs=0.15)


def test_expected_total_is_the_incoherent_total() -> None:
    optics = SpeckleOptics(WAVELENGTH_NM, F_NUMBER, 5.5)
    rate = spot(48, 64)
    totals = [speckle_image(rate, optics, [speckle_seed(s, [0.0], 0)]).sum() / rate.sum()
              for s in range(8)]
    # each total sums ≈ 2000 grains (relative σ ≈ 2 %); the mean of 8 within 4σ
    assert np.mean(totals) == pytest.approx(1.0, abs=4 * 0.025 / math.sqrt(8))


def test_seed_fixes_the_pattern() -> None:
    optics = SpeckleOptics(WAVELENGTH_NM, F_NUMBER, 5.5)
    rate = spot(32, 32)
    a = speckle_image(rate, optics, [speckle_seed(1, [10.0, 20.0], 0)])
    b = speckle_image(rate, optics, [speckle_seed(1, [10.0, 20.0], 0)])
    c = speckle_image(rate, optics, [speckle_seed(1, [10.0, 22.0], 0)])
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_decorrelation_angle_from_spot_and_wavelength() -> None:
    # λ/(L·|q_t|/k): 633 nm over a 4 mm spot and a tangential sum of 0.5 → 3.2e-4 rad
    got = decorrelation_angle_deg(633.0, 2.0, 1.0, 0.5, 0.02)
    assert got == pytest.approx(math.degrees(633e-6 / (4.0 * 0.5)), rel=1e-12)
    # at the specular direction the pupil's own spread sets it
    assert decorrelation_angle_deg(633.0, 2.0, 1.0, 0.0, 0.02) == pytest.approx(
        math.degrees(633e-6 / (4.0 * 0.02)), rel=1e-12)


def test_options_validated() -> None:
    with pytest.raises(ValueError, match="must be > 0"):
        SpeckleOptics(633.0, 0.0, 5.5)
    with pytest.raises(ValueError, match="patterns"):
        speckle_image(spot(8, 8), SpeckleOptics(633.0, 5.0, 5.5), [[1]], patterns=0.5)
    with pytest.raises(ValueError, match="coherence"):
        SourceState(coherence="partial")


# --------------------------------------------------------------------------- camera


def bench(coherence: str) -> tuple[VirtualBench, SimulatedCamera]:
    world = VirtualBench(
        "speckle", scene=GoniometerScene(),
        source=SourceState(on=True, power_w=1e-4, beam_radius_mm=0.3, coherence=coherence),
        roles={"sample_theta": 30.0, "detector_theta": 70.0})
    camera = SimulatedCamera(
        "camera", world=world, seed=5,
        sensor=SensorParams(width=64, height=64, pixel_pitch_um=5.5),
        optics=OpticsParams(pupil="chief"))
    camera.exposure_us = 1000.0
    return world, camera


def test_static_sample_shows_a_frozen_pattern() -> None:
    world, camera = bench("laser")
    state = world.snapshot()
    rate = camera.photon_rate(state)
    first = camera._speckled(state, camera.roi, rate, world.spin(), 1000.0).copy()
    camera._speckle_rate = None  # recompute, not reuse
    again = camera._speckled(state, camera.roi, rate, world.spin(), 1000.0)
    np.testing.assert_array_equal(first, again)
    assert contrast(first, rate.astype(float)) > 0.3  # speckled, not the smooth image
    world.set_role("detector_theta", 72.0)
    moved = world.snapshot()
    other = camera._speckled(moved, camera.roi, camera.photon_rate(moved), world.spin(),
                             1000.0)
    assert not np.allclose(other, first)
    camera.close()


def test_incoherent_frames_are_unchanged() -> None:
    _world, camera = bench("incoherent")
    frame = camera.acquire(1)[0]
    expected = camera.expected_dn()
    # no speckle: the frame scatters about the smooth image by the sensor's noise alone
    lit = expected > 0.5 * expected.max()
    assert np.mean(frame.data[lit] / expected[lit]) == pytest.approx(1.0, abs=0.05)
    assert camera._speckle_rate is None
    camera.close()


def test_spinning_sample_sweeps_patterns() -> None:
    world, camera = bench("laser")
    state = world.snapshot()
    step = camera.speckle_decorrelation_deg(state)
    first, n = camera.speckle_patterns(state, (10.0, 360.0), 1e4)  # 1 rev/s, 10 ms
    assert n == pytest.approx(3.6 / step, rel=1e-12)
    assert first == math.floor(10.0 / step)
    assert camera.speckle_patterns(state, (10.0, 0.0), 1e4) == (math.floor(10.0 / step), 1.0)
    camera.close()
