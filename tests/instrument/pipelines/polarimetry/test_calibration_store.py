"""The polarimeter calibration as a file: written, read back, looked up by bench and date,
its quality gate; and the degree-of-polarisation numbers the report plots."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from analysis.polarimetry.calibration import DrrCalibration
from analysis.polarimetry.elements import depolariser, linear_polariser
from instrument.pipelines.polarimetry.calibration import (
    CalibrationError,
    PolarimeterCalibration,
    calibration_folder,
    find_calibration,
    load_calibration,
    quality,
    save_calibration,
)
from instrument.pipelines.polarimetry.pipeline import choose_calibration
from instrument.pipelines.polarimetry.reduce import dop


def _cal(bench: str = "sim-polarimetric", date: str = "2026-11-27T04:00:00Z", *,
         valid: bool = True, offset: float = 2.0) -> PolarimeterCalibration:
    params = np.array([offset, -2.0, math.radians(94.5), math.radians(85.5), -0.6])
    cov = np.diag([1e-4, 1e-4, 1e-6, 1e-6, 1e-4])
    drr = DrrCalibration(params=params, cov=cov, sample_params=((2e-3,), (2e-3, 30.0)),
                         chi2=98.0, dof=100)
    return PolarimeterCalibration(drr=drr, bench=bench, source_scale_w=2e-3, date=date,
                                  references=({"kind": "air", "run": "air.h5"},),
                                  valid=valid, quality="χ²/dof = 0.98 (100 dof)")


def test_a_calibration_round_trips_with_its_covariance_and_provenance(tmp_path):
    path = save_calibration(_cal(), calibration_folder(tmp_path))
    assert path.parent == tmp_path / "calibrations"
    back = load_calibration(path)
    np.testing.assert_allclose(back.drr.params, _cal().drr.params)
    np.testing.assert_allclose(back.drr.cov, _cal().drr.cov)
    assert back.drr.sample_params == ((2e-3,), (2e-3, 30.0))
    assert (back.bench, back.source_scale_w, back.valid, back.path) == (
        "sim-polarimetric", 2e-3, True, path)
    data = json.loads(path.read_text(encoding="utf-8"))
    assert data["references"] == [{"kind": "air", "run": "air.h5"}]
    assert data["software_version"] and data["param_names"][0] == "psg_retarder_offset_deg"


def test_fit_takes_the_newest_valid_calibration_of_the_runs_bench(tmp_path):
    folder = calibration_folder(tmp_path)
    save_calibration(_cal(date="2026-11-26T10:00:00Z", offset=1.0), folder)
    newest = save_calibration(_cal(date="2026-11-27T10:00:00Z", offset=2.0), folder)
    save_calibration(_cal(date="2026-11-28T10:00:00Z", valid=False), folder)
    save_calibration(_cal(bench="other", date="2026-11-29T10:00:00Z"), folder)
    (folder / "polarimeter-damaged.json").write_text("{", encoding="utf-8")
    run = tmp_path / "run.h5"
    found = find_calibration(run, "sim-polarimetric")
    assert found is not None and found.path == newest
    assert choose_calibration(run, "sim-polarimetric", None).path == newest
    assert choose_calibration(run, "sim-polarimetric", "none") is None
    assert find_calibration(run, "sim") is None
    assert find_calibration(tmp_path / "elsewhere" / "run.h5", "sim-polarimetric") is None


def test_a_file_that_is_not_a_calibration_is_refused_by_name(tmp_path):
    bad = tmp_path / "camera_calibration.json"
    bad.write_text(json.dumps({"K": 1.0}), encoding="utf-8")
    with pytest.raises(CalibrationError, match=r"camera_calibration\.json is not a polarimeter"):
        load_calibration(bad)
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps({"kind": "polarimeter_calibration", "params": [1, 2]}),
                      encoding="utf-8")
    with pytest.raises(CalibrationError, match=r"broken\.json: malformed"):
        load_calibration(broken)
    with pytest.raises(CalibrationError, match="cannot read"):
        load_calibration(tmp_path / "missing.json")


def test_the_quality_gate_passes_chi2_near_its_dof_and_fails_far_from_it():
    good = _cal().drr
    assert quality(good)[0]
    bad = DrrCalibration(params=good.params, cov=good.cov, chi2=400.0, dof=100)
    ok, why = quality(bad)
    assert not ok and "χ²/dof = 4" in why
    nan = DrrCalibration(params=good.params, cov=np.full((5, 5), np.inf), chi2=100.0,
                         dof=100)
    assert not quality(nan)[0]


def test_degree_of_polarisation_of_a_polariser_and_a_depolariser():
    pol = dop(linear_polariser(0.0))
    for state in ("unpolarised", "H", "+45°", "−45°"):
        assert pol[state] == pytest.approx(1.0)
    assert math.isnan(pol["V"])  # nothing passes: the DoP is undefined, not 0 or 1
    assert pol["depolarisation index"] == pytest.approx(1.0)
    d = dop(depolariser(1.0, 0.2))
    assert d["H"] == pytest.approx(0.2) and d["unpolarised"] == pytest.approx(0.0)
    assert d["depolarisation index"] == pytest.approx(0.2)
    assert dop(np.eye(4))["depolarisation index"] == pytest.approx(1.0)


def test_the_reference_profile_puts_the_reference_in_a_straight_through_beam():
    from instrument.bench.profile import load_profile, parse_profile
    from instrument.cli._calibrate_polarimeter import _simulated_reference

    text = load_profile("sim-polarimetric").source_text
    ref = _simulated_reference(text, "retarder", 30.0)
    prof = parse_profile(ref)
    assert prof.name == "sim-polarimetric"
    assert "simsmc://detector_theta_straight?sr=181&kind=rotary" in ref
    assert prof.axes["detector_theta"].limits == (-170.0, 181.0)
    assert ref.count("[simulation.scene]") == 1 and "pbrdf" not in ref.split(
        "[simulation.scene]")[1]
    assert 'sample = "retarder"' in ref and "orientation_deg = 30.0" in ref
    air = _simulated_reference(text, "air", 0.0)
    assert 'sample = "air"' in air and "[simulation.scene.air]" not in air
    # the hidden optics stay: they are what the calibration finds
    assert "[[simulation.optics.source]]" in air


def test_calibrate_polarimeter_refuses_a_bench_without_a_simulated_scene(capsys):
    from instrument.cli import main

    assert main(["calibrate", "polarimeter", "--bench", "sim"]) == 2
    assert "not a simulated polarimetric bench" in capsys.readouterr().out
    assert main(["calibrate", "polarimeter", "--bench", "sim-polarimetric", "--steps",
                 "20"]) == 2
    assert "--steps must be ≥ 25" in capsys.readouterr().out
