"""Master dark, flat field and the frame → radiance conversion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.radiometry import (
    CameraResponse,
    apply_dark_flat,
    flat_field,
    master_dark,
    pinhole_relative_illumination,
    to_radiance,
)

SHAPE = (128, 128)


def test_master_dark_median_rejects_outliers_and_mean_averages():
    rng = np.random.default_rng(0)
    offset = 100.0 + 3.0 * rng.standard_normal(SHAPE)  # DSNU
    stack = offset + 2.0 * rng.standard_normal((9, *SHAPE))
    stack[4, 10, 10] = 60000.0  # a cosmic ray
    med = master_dark(stack)
    mean = master_dark(stack, method="mean")
    assert med[10, 10] == pytest.approx(offset[10, 10], abs=5)
    assert mean[10, 10] > 1000
    mask = np.ones(SHAPE, bool)
    mask[10, 10] = False
    # Temporal noise of a mean of 9 frames: 2/3 DN.
    assert np.std((mean - offset)[mask]) == pytest.approx(2.0 / 3.0, rel=0.05)
    with pytest.raises(ValueError):
        master_dark(stack, method="mode")


def test_dark_and_flat_remove_fixed_pattern_to_shot_noise_level():
    rng = np.random.default_rng(1)
    k = 0.5  # DN/e⁻
    prnu = 1.0 + 0.03 * rng.standard_normal(SHAPE)
    vignette = pinhole_relative_illumination(SHAPE, focal_length_px=150.0)
    response = prnu * vignette
    dsnu = 5.0 * rng.standard_normal(SHAPE)

    def frame(electrons):
        e = rng.poisson(electrons * response)
        return np.rint(k * e + 100.0 + dsnu + 1.0 * rng.standard_normal(SHAPE))

    dark = master_dark(np.stack([np.rint(100.0 + dsnu + rng.standard_normal(SHAPE))
                                 for _ in range(32)]), method="mean")
    flat = flat_field(np.stack([frame(20000.0) for _ in range(64)]), dark)
    assert flat.valid.all()
    assert flat.response.mean() == pytest.approx(1.0, rel=1e-9)
    raw = frame(5000.0)
    corrected = apply_dark_flat(raw, dark=dark, flat=flat)
    # Shot + read noise of the corrected frame (DN), and what remains of the flat's noise.
    mean_dn = corrected.mean()
    temporal = math.sqrt(k * mean_dn + 1.0)
    assert raw.std() > 5 * temporal  # the raw frame is dominated by the fixed pattern
    assert corrected.std() == pytest.approx(temporal, rel=0.1)


def test_flat_marks_dead_pixels_invalid():
    flat_frames = np.full((2, 8, 8), 1100.0)
    flat_frames[:, 0, 0] = 100.0
    flat = flat_field(flat_frames, 100.0)
    assert not flat.valid[0, 0]
    assert flat.response[0, 0] == 1.0
    assert flat.mean_signal_dn == pytest.approx(1000.0)


def test_relative_illumination_is_cos4():
    ri = pinhole_relative_illumination((101, 201), focal_length_px=100.0)
    assert ri[50, 100] == pytest.approx(1.0)
    tan_a = math.hypot(100, 50) / 100.0
    assert ri[0, 0] == pytest.approx(math.cos(math.atan(tan_a)) ** 4)


def test_to_radiance_inverts_the_camera_equation():
    resp = CameraResponse(system_gain_dn_per_e=0.2, quantum_efficiency=0.6,
                          wavelength_nm=633.0, pixel_pitch_um=5.5, focal_length_mm=50.0,
                          aperture_diameter_mm=12.5)
    radiance = 3.7  # W m⁻² sr⁻¹
    t_us = 250.0
    area = math.pi * (6.25e-3) ** 2
    power = radiance * area * (5.5e-6 / 50e-3) ** 2
    photons = power * t_us * 1e-6 / (6.62607015e-34 * 299792458.0 / 633e-9)
    dn = 40.0 + 0.2 * 0.6 * photons
    frame = np.full((4, 4), dn)
    out = to_radiance(frame, dark=40.0, exposure_us=t_us, response=resp)
    np.testing.assert_allclose(out, radiance, rtol=1e-12)
    with pytest.raises(ValueError):
        to_radiance(frame, dark=40.0, exposure_us=0.0, response=resp)
