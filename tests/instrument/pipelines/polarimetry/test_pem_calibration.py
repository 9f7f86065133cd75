"""The PEM polarimeter's calibration through ``scatterlab calibrate polarimeter`` on
``sim-polarimetric-pem`` (its hidden train misaligned: modulator amplitude 3 % high and
its axis 0.4° off 45°, source polariser 0.3°, analyser retarder −0.4° and polariser −0.3°
off, extinction 1e-5; ADR 0113), and ``fit`` of a PEM run with it.

The cheap default-run twin of the multi-seed validation in
``benchmarks/bench_pem_calibration.py``: one seed, the polariser in the default run, air
and the glass behind ``slow``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from instrument.pipelines.polarimetry.calibration import CalibrationError
from instrument.pipelines.polarimetry.pipeline import choose_calibration
from tests.instrument.pipelines.polarimetry.validation import (
    calibrate,
    measure,
    sample,
    verdict,
)

#: The hidden train in the calibration's frame (azimuth 0 at the source polariser's
#: true axis, 0.3°): amplitude × 1.03, modulator 45.4 − 0.3 − 45, analyser retarder
#: −0.4 − 0.3, quarter wave, analyser polariser −0.3 − 0.3.
HIDDEN = np.array([1266.9 / 1230.0, 0.1, -0.7, math.pi / 2, -0.6])


@pytest.fixture(scope="module")
def pem_calibration(tmp_path_factory):  # type: ignore[no-untyped-def]
    folder = tmp_path_factory.mktemp("pemcal")
    bench, file = calibrate(folder, seed=3, pem=True)
    return folder, bench, file


def test_the_pem_calibration_finds_the_hidden_train(pem_calibration):
    _, _, file = pem_calibration
    data = json.loads(file.read_text(encoding="utf-8"))
    assert data["mode"] == "pem" and data["valid"], data["quality"]
    assert data["param_names"][0] == "amplitude_factor"
    p, cov = np.array(data["params"]), np.array(data["covariance"])
    d = p - HIDDEN
    # Mahalanobis² of five parameters: χ²(5) exceeds 20.5 once in 1000
    assert float(d @ np.linalg.solve(cov, d)) < 20.5, (d, np.sqrt(np.diag(cov)))
    assert data["psg_extinction"] == 1e-5 and data["psa_extinction"] == 1e-5


@pytest.mark.parametrize("name", [
    pytest.param("air", marks=pytest.mark.slow),  # a reference run more: ~20 s
    "polariser 30°",
    pytest.param("dielectric 50°", marks=pytest.mark.slow)])  # the glass's pBRDF: ~30 s
def test_calibrated_pem_runs_recover_the_truth_and_nominal_ones_are_off(pem_calibration,
                                                                       name, tmp_path):
    _, _, file = pem_calibration
    out = measure(sample(name), 3, tmp_path, file, pem=True)
    calibrated, nominal = verdict(out.calibrated, out.nominal)
    print(name, calibrated, nominal, sep="\n  ")
    assert calibrated.endswith("— recovered"), calibrated
    assert "visibly off" in nominal and "not visibly" not in nominal, nominal


def test_a_calibration_of_the_other_mode_is_refused_by_name(pem_calibration, tmp_path):
    folder, _, file = pem_calibration
    with pytest.raises(CalibrationError, match=r"a PEM polarimeter.*'drr' run"):
        choose_calibration(tmp_path / "run.h5", "sim-polarimetric-pem", file, "drr")
    data = json.loads(file.read_text(encoding="utf-8"))
    data["mode"] = "drr"
    drr = tmp_path / "drr.json"
    drr.write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(CalibrationError, match=r"a dual rotating retarder.*'pem' run"):
        choose_calibration(tmp_path / "run.h5", "sim-polarimetric-pem", drr, "pem")
    # found beside the run for a PEM run, never for a DRR run
    run = folder / "run.h5"
    assert choose_calibration(run, "sim-polarimetric-pem", None, "pem") is not None
    assert choose_calibration(run, "sim-polarimetric-pem", None, "drr") is None
