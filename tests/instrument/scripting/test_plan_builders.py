"""Plans written in Python (instrument.plans.scripted): the same plan, validation and
stored text as a plan file."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from instrument import plans
from instrument.bench.profile import load_profile
from instrument.plans import PlanError, build_plan
from instrument.plans.scripted import to_toml

ROOT = Path(__file__).resolve().parents[3]


def test_the_example_plan_built_in_python_is_the_plan_file():
    """examples/brdf_inplane.toml, said with the builder's keywords, gives the same points
    in the same order and the same acquisition policy on the sim bench."""
    from_file = plans.load(ROOT / "examples" / "brdf_inplane.toml")
    built = plans.in_plane(
        theta_i=[20.0, 40.0, 60.0], theta_r=range(-70, 81, 10),
        specular={"half_width_deg": 4.0, "step_deg": 2.0}, skip_beam_points=True,
        sample="sim-grey", name=from_file.name, order="optimised",
        description=from_file.sample_description,
        acquisition={"mode": "auto", "exposure_us": 2000, "min_exposure_us": 10,
                     "max_exposure_us": 200000, "hdr": True, "frames": 1,
                     "dark": "per_point", "detectors": ["camera", "power_meter"]})
    assert built.acquisition == from_file.acquisition
    assert (built.kind, built.name, built.sample_name) == (
        from_file.kind, from_file.name, from_file.sample_name)
    sim = load_profile("sim")
    a, b = build_plan(built, sim), build_plan(from_file, sim)
    assert [p.targets for p in a.points] == [p.targets for p in b.points]
    assert [p.label for p in a.points] == [p.label for p in b.points]
    assert len(a.points) == 57


def test_the_stored_text_is_a_plan_file_that_reads_back_the_same():
    spec = plans.hemisphere(theta_i=[30.0], phi_i=[0.0, 90.0], n_directions=40,
                            theta_max_deg=70.0, sample="paint",
                            acquisition={"dark": "start"})
    again = plans.load_plan  # the file reader, on the text a run file stores
    assert spec.source_text.startswith("[plan]\nkind = \"brdf_hemisphere\"")
    from instrument.plans import parse_plan

    reread = parse_plan(spec.source_text)
    assert reread == spec
    assert again is plans.load_plan


def test_numpy_values_and_ranges_are_written_as_numbers():
    spec = plans.in_plane(theta_i=np.array([20.0, 40.0]), theta_r=np.arange(-60, 61, 30),
                          sample=np.str_("s"), acquisition={"frames": np.int64(3)})
    assert spec.scan["theta_i"] == [20.0, 40.0]
    assert spec.scan["theta_r"] == [-60, -30, 0, 30, 60]
    assert spec.acquisition.frames == 3
    assert plans.dark(exposures_us=range(100, 301, 100), frames=2).scan["exposures_us"] \
        == [100, 200, 300]


def test_bad_values_are_named_as_in_a_plan_file():
    with pytest.raises(PlanError) as err:
        plans.in_plane(theta_i=[20.0, 95.0, math.nan], theta_r=[10.0], sample="s",
                       acquisition={"mode": "fast", "colour": 1})
    text = str(err.value)
    for field in ("scan.theta_i[1]", "scan.theta_i[2]", "acquisition.mode",
                  "acquisition.colour"):
        assert field in text, text
    assert "plans.brdf_in_plane(...)" in text


def test_unknown_scan_keywords_are_refused_with_their_name():
    with pytest.raises(PlanError, match=r"scan\.theta_x"):
        plans.make("brdf_in_plane", theta_i=[20.0], theta_r=[10.0], theta_x=[1.0],
                   sample="s")
    with pytest.raises(PlanError, match=r"plan\.kind"):
        plans.make("brdf_sideways", sample="s")


def test_a_value_no_plan_file_could_hold_is_a_type_error_naming_it():
    with pytest.raises(TypeError, match=r"scan\.theta_i\[1\]: a plan cannot hold object"):
        plans.in_plane(theta_i=[20.0, object()], theta_r=[10.0], sample="s")


_keys = st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), min_size=1,
                max_size=8)
_scalars = (st.booleans() | st.integers(-10**12, 10**12)
            | st.floats(allow_nan=False, allow_infinity=False)
            | st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=12))
_values = st.recursive(_scalars, lambda inner: st.lists(inner, max_size=4)
                       | st.dictionaries(_keys, inner, max_size=3), max_leaves=12)


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(_keys, st.dictionaries(_keys, _values, max_size=5), max_size=4))
def test_the_toml_writer_round_trips_what_a_plan_can_hold(tables):
    assert tomllib.loads(to_toml(tables)) == tables
