"""The polarimetric fit's options of ``scatterlab fit`` and ``scatterlab batch fit``: the
pBRDF start values (numbers or name=value pairs), the parameters held, the calibration
choice (file, name beside each run, none), each bad value refused with the option and the
parameter named."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.polarimetry.pbrdf import PBRDF_BOUNDS, PBRDF_PARAMS
from instrument.batch.polarimetric_options import (
    BatchRuns,
    PolarimetricOptionError,
    batch_notes,
    calibration_choice,
    calibration_choices,
    fit_keywords,
    parse_fixed,
    parse_start,
    polarimetric_fit_options,
    resolve_calibration,
)
from instrument.pipelines.polarimetry.calibration import CalibrationError
from instrument.pipelines.polarimetry.pipeline import DEFAULT_START
from tests.instrument.batch.runs import parse_cli


def test_start_values_as_numbers_or_as_named_changes_of_the_default():
    assert parse_start(None) is None
    assert parse_start("1.6,0,0.3,0.05,1") == [1.6, 0.0, 0.3, 0.05, 1.0]
    assert parse_start("1.6,0,0.3,0.05") == [1.6, 0.0, 0.3, 0.05, 0.0]  # frame at 0
    expected = list(DEFAULT_START)
    expected[2], expected[3] = 0.3, 0.05
    assert parse_start("alpha=0.3, albedo=0.05") == expected


@pytest.mark.parametrize(("text", "parameter", "words"), [
    ("alfa=0.3", "alfa", "no pBRDF parameter 'alfa'"),
    ("alpha=0.3,alpha=0.2", "alpha", "given twice"),
    ("n=x", "n", "must be a number"),
    ("n=nan", "n", "must be finite"),
    ("n=0.5", "n", "outside the fit's bounds [1, 10]"),
    ("1.5,0,2.0,0.1", "alpha", "alpha = 2 is outside"),
    ("1.5,0,0.2", None, "four or five numbers"),
    ("alpha=0.2,1.5", None, "not both"),
])
def test_a_bad_start_value_names_the_option_and_the_parameter(text, parameter, words):
    with pytest.raises(PolarimetricOptionError) as err:
        parse_start(text)
    assert err.value.option == "--pbrdf-start"
    assert err.value.parameter == parameter
    assert str(err.value).startswith("--pbrdf-start: ") and words in str(err.value)


@settings(max_examples=60, deadline=None)
@given(st.dictionaries(st.sampled_from(PBRDF_PARAMS), st.floats(allow_nan=True,
                                                                allow_infinity=True),
                       min_size=1))
def test_named_start_values_are_taken_exactly_when_in_bounds(values):
    text = ",".join(f"{k}={v!r}" for k, v in values.items())
    ok = all(math.isfinite(v) and PBRDF_BOUNDS[k][0] <= v <= PBRDF_BOUNDS[k][1]
             for k, v in values.items())
    if not ok:
        with pytest.raises(PolarimetricOptionError) as err:
            parse_start(text)
        assert err.value.parameter in values
        return
    got = parse_start(text)
    assert got is not None
    for k, v in zip(PBRDF_PARAMS, got, strict=True):
        assert v == values.get(k, DEFAULT_START[PBRDF_PARAMS.index(k)])


def test_fixed_parameters_are_checked_by_name():
    assert parse_fixed(None) is None
    assert parse_fixed("") == []
    assert parse_fixed("k, frame_deg,k") == ["k", "frame_deg"]
    with pytest.raises(PolarimetricOptionError) as err:
        parse_fixed("k,kappa")
    assert (err.value.option, err.value.parameter) == ("--pbrdf-fixed", "kappa")


def test_the_calibration_is_a_file_a_name_beside_each_run_or_none(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.json").write_text("{}", encoding="utf-8")
    assert calibration_choice(None) is None
    assert calibration_choice("none") == "none"
    assert calibration_choice("mine.json") == str(tmp_path / "mine.json")  # a file here
    assert calibration_choice("lab-a") == "lab-a"  # a name, looked up beside each run
    with pytest.raises(PolarimetricOptionError, match="--calibration: no such file"):
        calibration_choice("cals/missing.json")
    # a name resolves in calibrations/ beside the run, with or without .json
    run = tmp_path / "day1" / "run.h5"
    (run.parent / "calibrations").mkdir(parents=True)
    (run.parent / "calibrations" / "lab-a.json").write_text("{}", encoding="utf-8")
    assert resolve_calibration(run, "lab-a") == str(run.parent / "calibrations" /
                                                     "lab-a.json")
    assert resolve_calibration(run, "lab-a.json") == resolve_calibration(run, "lab-a")
    assert resolve_calibration(run, None) is None
    assert resolve_calibration(run, "none") == "none"
    with pytest.raises(CalibrationError) as err:
        resolve_calibration(run, "lab-b")
    text = str(err.value)
    assert "lab-b" in text and "run.h5" in text and "it holds lab-a.json" in text
    with pytest.raises(CalibrationError, match="no such folder"):
        resolve_calibration(tmp_path / "day2" / "run.h5", "lab-a")


def test_the_command_line_gives_the_same_plain_options_to_fit_and_batch_fit(tmp_path):
    argv = ["--pbrdf-start", "alpha=0.3", "--pbrdf-fixed", "k", "--calibration", "lab-a",
            "--distribution", "ggx"]
    from instrument.cli.fit import fit_options

    single = fit_options(parse_cli(["fit", "r.h5", *argv]))["polarimetric"]
    batch = fit_options(parse_cli(["batch", "fit", "r.h5", *argv]))["polarimetric"]
    assert single == batch == polarimetric_fit_options("lab-a", "alpha=0.3", "k", "ggx")
    assert batch["fixed"] == ["k"] and batch["start"][2] == 0.3
    # no options: the defaults the pipeline had before (newest calibration beside the run)
    kw = fit_keywords(tmp_path / "r.h5", None)
    assert kw == {"calibration": None, "start": DEFAULT_START, "fixed": None,
                  "distribution": "beckmann"}


def test_a_batch_says_once_which_runs_do_not_take_the_options(tmp_path):
    runs = BatchRuns(polarimetric=[tmp_path / "p.h5"], pem=[], scalar=[tmp_path / "s.h5",
                                                                      tmp_path / "t.h5"])
    options = polarimetric_fit_options("none", "alpha=0.3")
    (note,) = batch_notes(runs, options)
    assert note == ("note: --calibration, --pbrdf-start apply to polarimetric runs only; "
                    "the 2 scalar runs of this batch are fitted without them")
    assert batch_notes(runs, polarimetric_fit_options()) == []  # nothing given
    assert batch_notes(BatchRuns([tmp_path / "p.h5"], [], []), options) == []
    # a PEM run takes the calibration of its mode (ADR 0113): nothing to say about it
    pem = BatchRuns([tmp_path / "p.h5"], [tmp_path / "p.h5"], [])
    (tmp_path / "cal.json").write_text("{}", encoding="utf-8")
    assert batch_notes(pem, polarimetric_fit_options(str(tmp_path / "cal.json"))) == []


def test_the_calibration_is_chosen_per_polarimeter_mode(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "pem=odd.json").write_text("{}", encoding="utf-8")
    assert calibration_choices(None) == {"drr": None, "pem": None}
    # a plain value is every mode's; MODE=VALUE that mode's, over a plain one
    assert calibration_choices("lab-a") == {"drr": "lab-a", "pem": "lab-a"}
    assert calibration_choices(["pem=lab-p"]) == {"drr": None, "pem": "lab-p"}
    assert calibration_choices(["drr=lab-a", "pem=none"]) == {"drr": "lab-a", "pem": "none"}
    assert calibration_choices(["lab-a", "pem=lab-p"]) == {"drr": "lab-a", "pem": "lab-p"}
    # a file that exists is a file, '=' in its name or not
    odd = str(tmp_path / "pem=odd.json")
    assert calibration_choices(["pem=odd.json"]) == {"drr": odd, "pem": odd}
    # the plain data again: as it is (workers get it so)
    assert calibration_choices({"drr": "lab-a", "pem": None}) == {"drr": "lab-a",
                                                                   "pem": None}


@pytest.mark.parametrize(("values", "words"), [
    (["lab-a", "lab-b"], "2 calibrations for every mode ('lab-a', 'lab-b')"),
    (["pem=a", "pem=b"], "the pem calibration is given twice ('a' and 'b')"),
    (["ddr=lab-a"], "before '=' give the polarimeter mode (drr or pem)"),
    (["pem=cals/missing.json"], "no such file cals/missing.json"),
    ({"ddr": "lab-a"}, "no polarimeter mode 'ddr'"),
])
def test_a_calibration_choice_that_cannot_be_used_is_refused_by_option(values, words):
    with pytest.raises(PolarimetricOptionError) as err:
        calibration_choices(values)
    assert err.value.option == "--calibration" and words in str(err.value), str(err.value)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["", "drr=", "pem="]),
                          st.sampled_from(["lab-a", "lab-b", "none"])), max_size=3))
def test_each_mode_gets_its_own_value_else_the_plain_one_else_the_default(pairs):
    values = [k + v for k, v in pairs]
    keys = [k for k, _ in pairs]
    if keys.count("") > 1 or keys.count("drr=") > 1 or keys.count("pem=") > 1:
        with pytest.raises(PolarimetricOptionError):
            calibration_choices(values)
        return
    plain = next((v for k, v in pairs if k == ""), None)
    got = calibration_choices(values)
    for mode in ("drr", "pem"):
        assert got[mode] == next((v for k, v in pairs if k == f"{mode}="), plain)
