"""The profile's ``[optics]`` table: a polarimeter's elements, their mounts and nominal values."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from instrument.bench.optics import OpticalElement, parse_optics
from instrument.bench.profile import ProfileError, load_profile, parse_profile

AXES = {"psg_polariser", "psg_retarder", "psa_retarder", "psa_polariser", "sample_theta"}


def parse(table):
    errors: list[tuple[str, str]] = []
    train = parse_optics(table, AXES, lambda path, message: errors.append((path, message)))
    return train, errors


valid_retarder = st.fixed_dictionaries({
    "kind": st.just("retarder"),
    "mount": st.sampled_from(["psg_retarder", "psa_retarder"]),
    "orientation_deg": st.floats(-180, 180),
    "retardance_deg": st.floats(1, 359),
})
#: (field, a bad value) pairs: each must be reported on that field.
corruptions = st.sampled_from([
    ("kind", "waveplate"), ("mount", "no_such_axis"), ("mount", 3),
    ("orientation_deg", 400.0), ("orientation_deg", math.nan), ("orientation_deg", True),
    ("retardance_deg", 0.0), ("retardance_deg", 360.0), ("retardance_deg", "quarter"),
    ("retardance_deg", []), ("colour", "red"),
])


@given(valid_retarder)
def test_a_valid_retarder_keeps_its_nominal_values(element):
    train, errors = parse({"source": [element]})
    assert errors == []
    assert train is not None
    got = train.source[0]
    assert got == OpticalElement("retarder", element["mount"],
                                 float(element["orientation_deg"]),
                                 (float(element["retardance_deg"]),))
    assert got.retardance_at(550.0) == element["retardance_deg"]


@settings(max_examples=60)
@given(valid_retarder, corruptions, st.sampled_from(["source", "detector"]))
def test_a_bad_field_is_reported_on_that_field(element, corruption, arm):
    key, value = corruption
    bad = {**element, key: value}
    train, errors = parse({arm: [bad]})
    assert train is None
    assert f"optics.{arm}[0].{key}" in {path for path, _ in errors}, errors


@given(st.lists(st.floats(1, 359), min_size=2, max_size=5),
       st.lists(st.floats(100, 25000), min_size=2, max_size=5, unique=True))
def test_a_retardance_table_needs_one_increasing_wavelength_per_value(values, nm):
    element = {"kind": "retarder", "mount": "psg_retarder", "retardance_deg": values,
               "retardance_nm": nm}
    train, errors = parse({"source": [element]})
    fine = len(nm) == len(values) and all(b > a for a, b in itertools.pairwise(nm))
    if fine:
        assert errors == [] and train is not None
        # linear between the table's points, constant beyond its ends
        e = train.source[0]
        assert e.retardance_at(nm[0] - 10) == values[0]
        assert e.retardance_at(nm[-1] + 10) == values[-1]
        mid = 0.5 * (nm[0] + nm[1])
        assert e.retardance_at(mid) == pytest.approx(0.5 * (values[0] + values[1]))
    else:
        assert train is None
        assert ("optics.source[0].retardance_nm" in {p for p, _ in errors})


def test_a_mount_turns_one_element_and_a_polariser_needs_one():
    train, errors = parse({
        "source": [{"kind": "polariser", "mount": "psg_polariser"}],
        "detector": [{"kind": "polariser", "mount": "psg_polariser"},
                     {"kind": "polariser"},
                     {"kind": "polariser", "mount": "psa_polariser", "retardance_deg": 90}],
    })
    assert train is None
    paths = {p for p, _ in errors}
    assert paths == {"optics.detector[0].mount", "optics.detector[1].mount",
                     "optics.detector[2].retardance_deg"}


def test_a_pem_needs_no_mount():
    train, errors = parse({"source": [{"kind": "pem", "orientation_deg": 45.0}]})
    assert errors == [] and train is not None
    assert train.source[0].mount is None and train.mounts == ()


def test_the_polarimetric_profile_names_its_train():
    profile = load_profile("sim-polarimetric")
    assert profile.optics is not None
    assert [e.kind for e in profile.optics.source] == ["polariser", "retarder"]
    assert [e.kind for e in profile.optics.detector] == ["retarder", "polariser"]
    assert profile.optics.retarder("source").retardance_at(633.0) == 90.0
    assert set(profile.optics.mounts) <= set(profile.axes)


def test_a_profile_reports_optics_errors_by_field():
    text = load_profile("sim-polarimetric").source_text.replace(
        'mount = "psa_polariser"\norientation_deg = 0.0',
        'mount = "psa_polarizer"\norientation_deg = 0.0', 1)
    with pytest.raises(ProfileError) as err:
        parse_profile(text)
    assert [e.path for e in err.value.errors] == ["optics.detector[1].mount"]
    assert "psa_polarizer" in str(err.value)


@given(st.floats(0.0, 0.999))
def test_a_polarisers_extinction_is_kept_and_stored_with_the_train(extinction):
    train, errors = parse({"source": [{"kind": "polariser", "mount": "psg_polariser",
                                       "extinction": extinction}]})
    assert not errors and train is not None
    assert train.source[0].extinction == extinction
    assert train.as_dict()["source"][0]["extinction"] == extinction


def test_a_polariser_without_extinction_is_ideal():
    train, errors = parse({"source": [{"kind": "polariser", "mount": "psg_polariser"}]})
    assert not errors and train is not None and train.source[0].extinction == 0.0


@given(st.one_of(st.floats(max_value=-1e-300), st.floats(min_value=1.0),
                 st.just(math.nan), st.just("1e-5"), st.just(True)))
def test_an_extinction_outside_0_to_1_is_refused_on_its_field(extinction):
    _, errors = parse({"detector": [{"kind": "polariser", "mount": "psa_polariser",
                                     "extinction": extinction}]})
    assert [p for p, _ in errors] == ["optics.detector[0].extinction"]
    assert "datasheet" in errors[0][1]


def test_only_a_polariser_takes_an_extinction():
    _, errors = parse({"source": [{"kind": "retarder", "mount": "psg_retarder",
                                   "retardance_deg": 90.0, "extinction": 1e-5}]})
    assert [p for p, _ in errors] == ["optics.source[0].extinction"]


def test_the_sources_polarisation_is_the_generator_polarisers_only():
    train, errors = parse({"source": [{"kind": "polariser", "mount": "psg_polariser",
                                       "extinction": 1e-5, "source_dop": 0.98}]})
    assert not errors and train is not None and train.source[0].source_dop == 0.98
    assert train.as_dict()["source"][0]["source_dop"] == 0.98
    _, errors = parse({"detector": [{"kind": "polariser", "mount": "psa_polariser",
                                     "source_dop": 0.98}]})
    assert [p for p, _ in errors] == ["optics.detector[0].source_dop"]
    _, errors = parse({"source": [{"kind": "polariser", "mount": "psg_polariser",
                                   "source_dop": 1.5}]})
    assert [p for p, _ in errors] == ["optics.source[0].source_dop"]
