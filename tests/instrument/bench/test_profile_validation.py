"""Bench profiles are untrusted input: every problem is reported with its field path."""

from __future__ import annotations

import contextlib
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from instrument.bench.profile import ProfileError, builtin_profiles, load_profile, parse_profile

GOOD = """
[bench]
name = "t"
[devices.sample_theta]
driver = "thorlabs_apt"
url = "simapt://s"
limits = [-90, 90]
velocity = 5.0
[devices.camera]
driver = "sim_camera"
url = "simcam://c"
[geometry]
detector_distance_mm = 250
detector_aperture_mm = 4
"""


def test_builtin_sim_profile_is_valid_and_complete():
    assert "sim" in builtin_profiles()
    profile = load_profile("sim")
    assert {"sample_theta", "detector_theta", "camera", "power_meter", "source"} <= set(
        profile.devices)
    assert profile.device("sample_theta").limits == (-85.0, 85.0)
    assert profile.simulation is not None


def test_good_profile_parses_with_units():
    p = parse_profile(GOOD)
    assert p.device("sample_theta").velocity == 5.0
    assert p.device("sample_theta").retry.on_failure == "pause"
    # Solid angle of a 4 mm aperture at 250 mm: cone formula, close to A/R^2.
    small_angle = math.pi * 2.0**2 / 250.0**2
    assert p.geometry.detector_solid_angle_sr == pytest.approx(small_angle, rel=1e-4)


@pytest.mark.parametrize(
    ("edit", "path"),
    [
        (("limits = [-90, 90]", "limits = [90, -90]"), "devices.sample_theta.limits"),
        (("limits = [-90, 90]", 'limits = ["a", 1]'), "devices.sample_theta.limits"),
        (("velocity = 5.0", "velocity = -5.0"), "devices.sample_theta.velocity"),
        (('driver = "thorlabs_apt"', 'driver = "nope"'), "devices.sample_theta.driver"),
        (('url = "simcam://c"', "url = 3"), "devices.camera.url"),
        (("detector_aperture_mm = 4", "detector_aperture_mm = 0"),
         "geometry.detector_aperture_mm"),
        (('name = "t"', 'name = "t"\ncolour = "red"'), "bench.colour"),
    ],
)
def test_each_bad_field_is_named(edit, path):
    text = GOOD.replace(*edit)
    with pytest.raises(ProfileError) as info:
        parse_profile(text, source="p.toml")
    assert path in [e.path for e in info.value.errors]
    assert "p.toml" in str(info.value)


def test_all_errors_reported_at_once():
    text = GOOD.replace("velocity = 5.0", "velocity = 0").replace(
        'driver = "sim_camera"', 'driver = "x"')
    with pytest.raises(ProfileError) as info:
        parse_profile(text)
    assert len(info.value.errors) >= 2


def test_missing_file_and_unknown_name():
    with pytest.raises(ProfileError):
        load_profile("/nonexistent/bench.toml")
    with pytest.raises(ProfileError, match="built-in"):
        load_profile("no-such-bench")


toml_scalars = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=False),
                         st.text(max_size=8), st.booleans())
toml_values = st.recursive(toml_scalars, lambda c: st.lists(c, max_size=3), max_leaves=6)
keys = st.sampled_from(["driver", "url", "limits", "velocity", "acceleration", "stage",
                        "retry", "options", "position_tolerance", "bogus"])


def _toml(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.encode("unicode_escape").decode().replace('"', '\\"') + '"'
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return str(value)


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(keys, toml_values, max_size=6),
       st.sampled_from(["sample_theta", "camera", "weird role"]))
def test_fuzzed_device_tables_give_field_errors_never_tracebacks(table, role):
    body = "\n".join(f"{k} = {_toml(v)}" for k, v in table.items())
    text = f'[bench]\nname = "f"\n[devices."{role}"]\n{body}\n'
    try:
        profile = parse_profile(text)
    except ProfileError as err:
        assert err.errors and all(e.path and e.message for e in err.errors)
    else:
        spec = profile.device(role)
        assert spec.driver and spec.url is not None


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=200))
def test_arbitrary_text_raises_only_profile_error(text):
    with contextlib.suppress(ProfileError):
        parse_profile(text)


def test_device_settings_are_validated_and_applied():
    text = GOOD + '[devices.pm]\ndriver = "pm100usb"\nurl = "simusb://pm"\n' \
        'settings = { wavelength_nm = 850.0, averaging = 10 }\n'
    assert parse_profile(text).device("pm").settings == {"wavelength_nm": 850.0,
                                                         "averaging": 10}
    for bad, path in (("wavelength_nm = -1.0", "devices.pm.settings.wavelength_nm"),
                      ("averaging = 2.5", "devices.pm.settings.averaging"),
                      ("colour = 3", "devices.pm.settings.colour")):
        broken = GOOD + f'[devices.pm]\ndriver = "pm100usb"\nurl = "simusb://pm"\n' \
            f'settings = {{ {bad} }}\n'
        with pytest.raises(ProfileError) as info:
            parse_profile(broken)
        assert path in [e.path for e in info.value.errors]


def test_sim_power_meter_is_set_to_the_source_wavelength():
    from instrument.bench.devices import open_bench

    profile = load_profile("sim")
    with open_bench(profile, roles=["power_meter"]) as bench:
        assert bench.power_meter.wavelength_nm == pytest.approx(633.0, abs=0.5)
