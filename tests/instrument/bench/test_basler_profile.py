"""Basler cameras in bench profiles: named by serial number, options and settings validated
with the field's path, the real-bench example valid, the emulated bench opened."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.errors import ConnectionFailed
from instrument.bench.profile import ProfileError, load_profile, parse_profile

ROOT = Path(__file__).resolve().parents[3]

PROFILE = """
[bench]
name = "t"
[devices.camera]
driver = "basler"
{camera}
[geometry]
detector_distance_mm = 250
detector_aperture_mm = 4
"""


def camera(lines: str):
    return parse_profile(PROFILE.format(camera=lines)).device("camera")


def problems(lines: str) -> dict[str, str]:
    with pytest.raises(ProfileError) as err:
        parse_profile(PROFILE.format(camera=lines))
    return {e.path: e.message for e in err.value.errors}


def test_a_basler_camera_is_named_by_its_serial_number():
    spec = camera('serial = "40123456"\noptions = { pixel_format = "MONO12", '
                  'trigger_mode = "hardware", hardware_line = "Line1", buffers = 4 }\n'
                  'settings = { exposure_us = 500.0, gain = 6.0, black_level = 8.0 }')
    assert spec.url == "40123456"  # the serial stands where other devices have a url
    assert spec.options["trigger_mode"] == "hardware"
    assert spec.settings == {"exposure_us": 500.0, "gain": 6.0, "black_level": 8.0}


def test_serial_rules_are_reported_by_field():
    assert "is required" in problems("")["devices.camera.serial"]
    found = problems('url = "/dev/video0"')
    assert "serial number" in found["devices.camera.url"]
    assert "not a serial number" in problems('serial = "40 12"')["devices.camera.serial"]
    found = problems('serial = "1"\noptions = { pixel_format = "RGB8", buffers = 0, '
                     'trigger_mode = 3, emulation = "yes", colour = true }')
    assert "'MONO12'" in found["devices.camera.options.pixel_format"]
    assert "1 to 64" in found["devices.camera.options.buffers"]
    assert "'software'" in found["devices.camera.options.trigger_mode"]
    assert "true or false" in found["devices.camera.options.emulation"]
    assert "not an option" in found["devices.camera.options.colour"]
    assert "black_level" not in problems('serial = "1"\nsettings = { offset = 1.0 }')[
        "devices.camera.settings.offset"].split(":")[0]


def test_only_basler_cameras_take_a_serial():
    text = PROFILE.replace('driver = "basler"', 'driver = "sim_camera"\nurl = "simcam://c"')
    with pytest.raises(ProfileError) as err:
        parse_profile(text.format(camera='serial = "123"'))
    assert [e.path for e in err.value.errors] == ["devices.camera.serial"]


@given(st.text(st.characters(max_codepoint=0xFFFF, exclude_categories=("Cs",)),
               max_size=20))
def test_any_serial_text_is_taken_or_refused_with_its_path(text):
    try:
        spec = camera(f"serial = {json.dumps(text)}")  # a JSON string is a TOML string
    except ProfileError as err:
        assert {e.path for e in err.errors} == {"devices.camera.serial"}
        assert not re.fullmatch(r"[A-Za-z0-9]+(-[A-Za-z0-9]+)*", text, re.ASCII)
        return
    assert spec.url == text and text.replace("-", "").isascii()


def test_the_real_bench_example_is_valid():
    profile = load_profile(ROOT / "examples" / "bench_basler_real.toml")
    spec = profile.device("camera")
    assert spec.driver == "basler" and spec.url.isdigit() and len(spec.url) == 8
    assert spec.options == {"pixel_format": "MONO12", "trigger_mode": "software"}
    assert {"sample_theta", "detector_theta", "power_meter"} <= set(profile.devices)


def test_the_emulated_basler_bench_opens_its_camera():
    pytest.importorskip("pypylon", reason="pypylon (the basler extra) cannot be imported")
    from drivers.genicam_camera import GenICamCamera
    from instrument.bench.devices import open_device

    spec = load_profile("sim-basler").device("camera")
    with open_device(spec) as cam:
        assert isinstance(cam, GenICamCamera)
        assert cam.identity.serial == "0815-0000" and cam.bit_depth == 12
        assert cam.name == "camera"


def test_an_absent_camera_is_a_connection_failure_naming_the_role():
    pytest.importorskip("pypylon", reason="pypylon (the basler extra) cannot be imported")
    from instrument.bench.devices import open_device

    spec = camera('serial = "99999999"\noptions = { emulation = true }')
    with pytest.raises(ConnectionFailed, match="99999999") as err:
        open_device(spec)
    assert err.value.device == "camera"
