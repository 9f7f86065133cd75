"""``scatterlab calibrate camera``: an engine photon-transfer run on the emulated sphere
bench → EMVA 1288 parameters within 2σ of the simulated sensor's, the calibration file
``fit`` reads, and a BRDF fit with it that agrees with the fit under the true calibration.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from instrument.bench.camera_calibration import CameraCalibration, simulated_camera_calibration
from instrument.cli import main
from instrument.pipelines.brdf.analyse import analyse
from instrument.pipelines.brdf.reduce import ReductionOptions, reduce_run
from tests.instrument.pipelines.camera.ptc_sim import run_ptc, truth, z_scores
from tests.instrument.sim_scan import SAMPLES, ScanSetup, render, write_run_file
from tests.shared_files import made_once


@pytest.fixture(scope="module")
def truth_values():
    return truth()


@pytest.fixture(scope="module")
def ptc_run(tmp_path_factory):
    # the seeded sweep once per session, not once per xdist worker (tests/shared_files.py)
    return made_once(tmp_path_factory, "ptc", lambda folder: run_ptc(7, folder))


@pytest.fixture(scope="module")
def recovered(ptc_run, truth_values, tmp_path_factory):
    def calibrate(folder):
        out = folder / "camera.json"
        rc = main(["calibrate", "camera", str(ptc_run), "-o", str(out),
                   "--photons-per-pixel-s", repr(truth_values["photons_per_pixel_s"])])
        assert rc == 0
        return out
    return made_once(tmp_path_factory, "cal", calibrate)


def test_recovers_the_simulated_sensor_within_two_sigma(recovered, truth_values) -> None:
    content = json.loads(recovered.read_text(encoding="utf-8"))
    z = z_scores(content, truth_values)
    assert all(abs(v) < 2.0 for v in z.values()), z
    e = content["emva1288"]
    # the uncertainties are those of a 256 × 256 px sweep, not vacuous
    assert e["system_gain_dn_per_e"][1] < 0.005 * 0.2
    assert e["prnu_rel"][1] < 0.05 * 0.01 and e["dsnu_e"][1] < 0.05 * 1.5
    assert e["saturation_capacity_e"][1] < 0.02 * truth_values["saturation_capacity_e"]
    assert e["warnings"] == []
    assert e["camera_settings"]["camera"] == "scatterlab SimCam EMVA1288 SIM000007"
    # the settings the calibration holds for, as the run file recorded them
    assert e["camera_settings"]["gain_db"] == 0.0
    assert e["camera_settings"]["pixel_format"] == "MONO12"


def test_writes_the_file_fit_reads_and_the_report(recovered, ptc_run) -> None:
    cal = CameraCalibration.from_json(recovered)
    content = json.loads(recovered.read_text(encoding="utf-8"))
    assert cal.noise.system_gain_dn_per_e == content["system_gain_dn_per_e"]
    assert cal.noise.read_noise_e == content["read_noise_e"]
    assert cal.prnu_rel == content["prnu_rel"]
    # the optics of a simulated camera are the simulator's
    sim = simulated_camera_calibration("simcam://camera?world=sim&seed=1")
    assert cal.pupil_diameter_mm == sim.pupil_diameter_mm
    assert cal.wavelength_nm == 633.0 and cal.chief_ray_only is False
    # u(Kη) from u(K) and u(η)
    e = content["emva1288"]
    assert cal.u_responsivity_rel == pytest.approx(math.hypot(
        e["system_gain_dn_per_e"][1] / e["system_gain_dn_per_e"][0],
        e["quantum_efficiency"][1] / e["quantum_efficiency"][0]))
    png = recovered.with_name("camera_emva1288.png")
    assert png.stat().st_size > 10_000


def test_default_output_next_to_the_run_and_given_quantum_efficiency(ptc_run, capsys) -> None:
    assert main(["calibrate", "camera", str(ptc_run), "--quantum-efficiency", "0.55",
                 "--quantum-efficiency-u", "0.02", "--no-figure"]) == 0
    out = capsys.readouterr().out
    folder = ptc_run.with_suffix("") / "camera"
    content = json.loads((folder / "camera_calibration.json").read_text(encoding="utf-8"))
    assert content["quantum_efficiency"] == 0.55
    assert content["emva1288"]["quantum_efficiency_from"] == "given (data sheet)"
    assert "system gain K" in out and "0.55 ± 0.02, given (data sheet)" in out
    assert not (folder / "emva1288.png").exists()


def test_errors_name_the_fix(ptc_run, tmp_path, capsys) -> None:
    # no photon count and no data-sheet η
    assert main(["calibrate", "camera", str(ptc_run), "-o", str(tmp_path / "c.json")]) == 2
    assert "--photons-per-pixel-s" in capsys.readouterr().out
    assert main(["calibrate", "camera", str(ptc_run), "--quantum-efficiency", "1.5"]) == 2
    assert "(0, 1]" in capsys.readouterr().out
    assert main(["calibrate", "camera", str(tmp_path / "missing.h5"),
                 "--quantum-efficiency", "0.5"]) == 2
    assert "missing.h5" in capsys.readouterr().out
    glossy = write_run_file(render(ScanSetup(), SAMPLES[1]), 3, tmp_path / "glossy.h5")
    assert main(["calibrate", "camera", str(glossy), "--quantum-efficiency", "0.5"]) == 2
    assert "photon_transfer" in capsys.readouterr().out


@pytest.mark.slow  # a BRDF run fitted twice: ~7 s on top of the shared calibration run
def test_fit_with_the_recovered_calibration_matches_the_true_one(recovered, tmp_path,
                                                                 capsys) -> None:
    """The same BRDF, within the fit's σ (which now includes u(Kη)), as with the
    simulator's exact calibration."""
    glossy = write_run_file(render(ScanSetup(), SAMPLES[1]), 3, tmp_path / "glossy.h5")
    exact = simulated_camera_calibration("simcam://camera?world=sim&seed=1")
    true_file = tmp_path / "true.json"
    true_file.write_text(json.dumps({
        "system_gain_dn_per_e": exact.noise.system_gain_dn_per_e,
        "read_noise_e": exact.noise.read_noise_e, "saturation_dn": exact.noise.saturation_dn,
        "dark_current_e_per_s": exact.noise.dark_current_e_per_s,
        "quantum_efficiency": exact.quantum_efficiency, "wavelength_nm": exact.wavelength_nm,
        "pupil_diameter_mm": exact.pupil_diameter_mm, "u_responsivity_rel": 0.0,
        "prnu_rel": exact.prnu_rel, "pixel_pitch_um": exact.pixel_pitch_um,
        "focal_length_mm": exact.focal_length_mm, "chief_ray_only": exact.chief_ray_only}))
    fits = {}
    for name, path in (("true", true_file), ("recovered", recovered)):
        red = reduce_run(glossy, ReductionOptions(camera_calibration=str(path),
                                                  u_incident_power_rel=0.0,
                                                  u_distance_mm=0.0))
        fits[name] = analyse(red.points, ["lambert+ggx"], run_cv=False).chosen_fit
    t, r = fits["true"], fits["recovered"]
    assert np.all(np.abs(r.params - t.params) < r.stderr), (r.params, t.params, r.stderr)
    assert np.all(np.abs(r.params - np.array(SAMPLES[1].params)) < 4 * r.stderr)
    # the same through the command: `scatterlab fit --camera-calibration FILE`
    printed = {}
    for name, path in (("true", true_file), ("recovered", recovered)):
        capsys.readouterr()
        assert main(["fit", str(glossy), "--camera-calibration", str(path), "--models",
                     "lambert+ggx", "--no-cv", "--no-write", "--incident-power-u", "0",
                     "--distance-u-mm", "0"]) == 0
        printed[name] = {m[1]: (float(m[2]), float(m[3])) for m in re.finditer(
            r"^\s+(lambert\.rho|ggx\.ks|ggx\.alpha)\s+(\S+) ± (\S+)",
            capsys.readouterr().out, re.MULTILINE)}
    assert len(printed["recovered"]) == 3
    for key, (value, u) in printed["recovered"].items():
        assert abs(value - printed["true"][key][0]) < u, (key, printed)


@pytest.mark.slow
def test_ten_seeds_within_two_sigma(truth_values, tmp_path) -> None:
    """BENCHMARKS.md "camera characterization": every parameter within 2σ for seeds 1–10."""
    worst = {}
    for seed in range(1, 11):
        out = tmp_path / f"cal-{seed}.json"
        assert main(["calibrate", "camera", str(run_ptc(seed, tmp_path)), "-o", str(out),
                     "--no-figure", "--photons-per-pixel-s",
                     repr(truth_values["photons_per_pixel_s"])]) == 0
        z = z_scores(json.loads(out.read_text(encoding="utf-8")), truth_values)
        worst = {k: max(abs(v), worst.get(k, 0.0)) for k, v in z.items()}
    assert all(v < 2.0 for v in worst.values()), worst


def test_a_real_camera_needs_its_wavelength_and_pupil(ptc_run) -> None:
    from dataclasses import replace as dc_replace

    from instrument.pipelines.camera.characterize import optics_for
    from instrument.run.runfile import read_run

    real = dc_replace(read_run(ptc_run), profile_text=(
        '[devices.camera]\ndriver = "opencv_camera"\nurl = "opencv://0"\n'))
    with pytest.raises(ValueError, match="--wavelength-nm and --pupil-diameter-mm"):
        optics_for(real)
    optics = optics_for(real, wavelength_nm=532.0, pupil_diameter_mm=10.0)
    assert (optics.wavelength_nm, optics.pupil_diameter_mm) == (532.0, 10.0)
    assert optics.chief_ray_only is False and optics.pixel_pitch_um is None
