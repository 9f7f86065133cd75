"""The power meter's relative noise per reading: from the profile, the emulated meter's
documented model, or assumed with a warning that names the key."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest

from instrument.bench.meter_noise import (
    ASSUMED_RELATIVE_NOISE,
    EMULATED_PM100_RELATIVE_NOISE,
    meter_noise,
)
from instrument.bench.profile import ProfileError, load_profile, parse_profile

ROOT = Path(__file__).resolve().parents[3]


def _profile(name: str) -> dict:
    return tomllib.loads(load_profile(name).source_text)


def test_the_emulated_meter_reads_its_documented_noise_not_half_a_percent():
    sim = _profile("sim")
    noise = meter_noise(sim)
    # the sim profile declares the emulated meter's documented noise
    assert noise.relative == pytest.approx(1e-4) and noise.warning is None
    assert noise.floor_w == pytest.approx(2.6e-10)
    # a sim profile without the keys: the same from the emulated meter's kind
    bare = load_profile("sim").source_text.replace("relative_noise = 1e-4\n", "")
    noise = meter_noise(tomllib.loads(bare))
    assert noise.relative == pytest.approx(1e-4) and noise.warning is None
    assert "emulated PM100USB" in noise.source
    # the meter averages n samples per reading: σ/√n
    text = bare.replace(
        "settings = { wavelength_nm = 633.0 }",
        "settings = { wavelength_nm = 633.0, averaging = 16 }")
    assert meter_noise(tomllib.loads(text)).relative == pytest.approx(
        EMULATED_PM100_RELATIVE_NOISE / 4)


def test_a_declared_relative_noise_wins_and_is_validated():
    text = load_profile("sim").source_text.replace("relative_noise = 1e-4",
                                                   "relative_noise = 0.002")
    parse_profile(text)
    noise = meter_noise(tomllib.loads(text))
    assert noise.relative == 0.002 and "(profile)" in noise.source
    for bad in ("-0.1", '"x"', "1.5"):
        with pytest.raises(ProfileError, match=r"devices\.power_meter\.relative_noise"):
            parse_profile(text.replace("relative_noise = 0.002", f"relative_noise = {bad}"))
    with pytest.raises(ProfileError, match=r"devices\.sample_theta\.relative_noise.*power"):
        parse_profile(text.replace('stage = "K10CR1"\n',
                                   'stage = "K10CR1"\nrelative_noise = 0.01\n', 1))


def test_a_real_meter_without_the_key_is_assumed_and_named():
    data = {"devices": {"power_meter": {"driver": "pm100usb", "url": "USB0::0x1313"}}}
    noise = meter_noise(data)
    assert noise.relative == ASSUMED_RELATIVE_NOISE
    assert noise.warning is not None
    assert "devices.power_meter.relative_noise" in noise.warning
    assert math.isfinite(noise.relative)
