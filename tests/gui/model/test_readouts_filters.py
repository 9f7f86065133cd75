"""The words of the lock-in, shutter and filter-wheel panels, and the profile's filter list
read defensively (plain values, no devices, no Qt)."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from gui.model import readouts
from gui.model.filters import (
    FilterBand,
    bands_from_info,
    bands_from_profile,
    merge_bands,
    slot_label,
)

PROFILE = """
[bench]
name = "x"

[[filter_wheel.filters]]
position = 1
centre_nm = 450.0
bandwidth_nm = 10.0
label = "blue"

[[filter_wheel.filters]]
position = 2
center_nm = 550

[[filter_wheel.filters]]
position = "three"
centre_nm = 650.0

[[filter_wheel.filters]]
position = 4
centre_nm = -1.0

[[filter_wheel.filters]]
position = 1
centre_nm = 999.0
"""


def test_the_profile_list_is_read_and_bad_entries_are_skipped_with_a_reason():
    bands, skipped = bands_from_profile(PROFILE, "filter_wheel")
    assert bands == {1: FilterBand(1, 450.0, 10.0, "blue"), 2: FilterBand(2, 550.0)}
    assert len(skipped) == 3
    assert any("three" in s for s in skipped)
    assert any("slot 4" in s and "centre_nm" in s for s in skipped)
    assert any("listed twice" in s for s in skipped)


def test_the_list_may_sit_under_the_device_role_and_nothing_raises():
    text = '[devices.wheel]\ndriver = "fw102c"\n[[devices.wheel.filters]]\nposition = 3\n' \
           'centre_nm = 650.0\nbandwidth_nm = 40.0\n'
    assert bands_from_profile(text, "wheel")[0] == {3: FilterBand(3, 650.0, 40.0)}
    assert bands_from_profile(text, "other") == ({}, [])
    assert bands_from_profile(None, "wheel") == ({}, [])
    assert bands_from_profile("filter_wheel = 3", "wheel") == ({}, [])
    bands, skipped = bands_from_profile("not [toml", "wheel")
    assert bands == {} and "not readable" in skipped[0]


def test_the_drivers_bands_win_and_the_profile_fills_the_rest():
    driver = bands_from_info({2: (532.0, 3.0, "laser line"), 5: (None, None, "")})
    profile = {2: FilterBand(2, 550.0, 10.0), 5: FilterBand(5, 700.0, 10.0)}
    merged = merge_bands(driver, profile)
    assert merged[2] == FilterBand(2, 532.0, 3.0, "laser line")
    assert merged[5] == FilterBand(5, 700.0, 10.0)
    assert slot_label(merged, 2) == "slot 2: 532 nm, FWHM 3 nm (laser line)"
    assert slot_label(merged, 4) == "slot 4: empty"
    assert slot_label({1: FilterBand(1, 550.0)}, 1) == "slot 1: 550 nm"
    assert slot_label(merged, None) == "—"


@given(st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(),
                    lambda inner: st.lists(inner, max_size=4)
                    | st.dictionaries(st.sampled_from(["position", "slot", "centre_nm",
                                                       "center_nm", "bandwidth_nm", "label"]),
                                      inner, max_size=5), max_leaves=12))
def test_any_entry_gives_a_band_or_a_reason(entry):
    from gui.model.filters import _parse_entry

    out = _parse_entry(entry)
    assert isinstance(out, str) or (out.slot >= 1 and out.centre_nm > 0
                                    and math.isfinite(out.centre_nm))


def test_lock_in_words():
    v = {"r_v": 1.2345e-3, "theta_deg": 12.34, "x_v": 1.2e-3, "y_v": -2e-4,
         "reference": "external", "frequency_hz": 137.0}
    assert readouts.lockin_reading(v) == "R 1.234 mV rms, θ 12.3°"
    assert readouts.lockin_detail(v) == "X 1.2 mV, Y -200 µV; reference external, 137 Hz"
    assert readouts.lockin_reading({}) == "R — rms, θ —"
    assert readouts.lockin_faults(v) == []
    faults = readouts.lockin_faults({**v, "reference_unlocked": True, "input_overload": True})
    assert [f.badge for f in faults] == ["INPUT OVERLOAD", "UNLOCKED"]
    assert "chopper" in faults[1].advice


def test_table_choices_and_the_entry_a_read_back_value_is():
    table = (1e-5, 3e-5, 1e-4)
    assert readouts.choices(table, "s") == [("10 µs", 1e-5), ("30 µs", 3e-5), ("100 µs", 1e-4)]
    assert readouts.nearest(table, 3.0000000001e-5) == 1
    assert readouts.nearest(table, 2e-5) is None
    assert readouts.nearest(table, None) is None
    assert readouts.nearest(table, math.nan) is None


def test_shutter_words():
    assert readouts.shutter_open({"state": "open"}) is True
    assert readouts.shutter_open({"state": "closed"}) is False
    assert readouts.shutter_open({}) is None
