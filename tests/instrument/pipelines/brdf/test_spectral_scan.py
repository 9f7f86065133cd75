"""A spectral BRDF scan end to end: a three-filter lock-in scan of the spectral sample on
the emulated bench (SR830, SC10, FW102C, chopped photodiode; real drivers over their
emulators), then ``scatterlab fit`` per wavelength. The sample's truth
(instrument/bench/profiles/sim-spectral.toml): ρ = 0.30, 0.45, 0.60 at 450, 550, 650 nm;
GGX α = 0.2 with a Cauchy index n = 1.50 + 0.0045 µm²/λ², so n = 1.5222, 1.5149, 1.5107."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from instrument.bench.profile import load_profile, parse_profile
from instrument.cli import main
from instrument.plans import build_plan, parse_plan
from instrument.plans.planfile import PlanError
from instrument.run.runfile import read_run

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "spectral lock-in scan"
[sample]
name = "spectral"
[scan]
skip_beam_points = true
theta_i = [20, 50]
theta_r = [-60, -40, -20, 0, 10, 30, 40, 60, 70]
specular = { half_width_deg = 4, step_deg = 2 }
[acquisition]
detectors = ["lockin", "power_meter"]
dark = "none"
frames = 4
[spectral]
filters = [1, 2, 3]
order = "motion"
"""

TRUTH = {450.0: (0.30, 1.5 + 0.0045 / 0.45**2), 550.0: (0.45, 1.5 + 0.0045 / 0.55**2),
         650.0: (0.60, 1.5 + 0.0045 / 0.65**2)}


@pytest.mark.slow
@pytest.mark.timeout(900)  # 81 lock-in points, each settled and read four times
def test_a_three_filter_lock_in_scan_recovers_rho_and_n_per_wavelength(tmp_path, capsys):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN, encoding="utf-8")
    assert main(["run", str(plan), "--bench", "sim-spectral", "--out", str(tmp_path / "runs"),
                 "--no-fsync", "--quiet"]) == 0
    (path,) = (tmp_path / "runs").glob("*.h5")
    run = read_run(path)
    # all angles with one filter, then the next (the angles back and forth: "motion")
    slots = list(run.filter_position)
    n = len(slots) // 3
    assert slots == [1] * n + [2] * n + [3] * n
    assert list(np.unique(run.wavelength_nm)) == [450.0, 550.0, 650.0]
    assert np.allclose(run.theta_r[:n], run.theta_r[n:2 * n][::-1], atol=0.01)  # read back
    capsys.readouterr()
    assert main(["fit", str(path)]) == 0
    out = capsys.readouterr().out
    assert "3 wavelengths (lockin)" in out
    with h5py.File(path.parent / path.stem / "fit" / "results.h5", "r") as f:
        g = f["entry/analysis/spectral"]
        lam = g["wavelength_nm"][()]
        names = [x.decode() if isinstance(x, bytes) else str(x) for x in g["param_names"][()]]
        values, errors = g["params"][()], g["stderr"][()]
    for k, wl in enumerate(lam):
        rho, n_true = TRUTH[float(wl)]
        got = dict(zip(names, values[k], strict=True))
        err = dict(zip(names, errors[k], strict=True))
        rho_name = next(x for x in names if x.endswith("rho"))
        n_name = next(x for x in names if x.endswith(".n") or x == "n")
        assert abs(got[rho_name] - rho) <= 2 * err[rho_name], (wl, got, err)
        assert abs(got[n_name] - n_true) <= 2 * err[n_name], (wl, got, err)


def test_a_filter_outside_the_source_band_is_refused_before_the_run():
    profile = load_profile("sim-spectral")
    text = PLAN.replace("filters = [1, 2, 3]", "filters = [1, 4]")
    with pytest.raises(PlanError) as err:
        build_plan(parse_plan(text), profile)
    assert any(e.path == "spectral.filters" and "[4]" in e.message for e in err.value.errors)
    # and a bench without a filter wheel has no wavelength axis (the built-in `sim` with
    # its wheel of neutral-density filters taken out)
    no_wheel = load_profile("sim").source_text
    for table in ("[devices.filter_wheel]", "[simulation.filter_wheel]"):
        start = no_wheel.index(table)
        no_wheel = no_wheel[:start] + no_wheel[no_wheel.index("\n[", start + 1) + 1:]
    with pytest.raises(PlanError, match="no filter wheel"):
        build_plan(parse_plan(PLAN), parse_profile(no_wheel, source="sim without wheel"))


def test_a_power_meter_set_to_another_wavelength_than_the_source_is_refused():
    text = load_profile("sim").source_text
    assert "wavelength_nm = 633.0 }" in text
    profile = parse_profile(text.replace("wavelength_nm = 633.0 }", "wavelength_nm = 532.0 }"))
    plan = PLAN.split("[spectral]")[0]
    with pytest.raises(PlanError) as err:
        build_plan(parse_plan(plan), profile)
    assert err.value.errors[0].path == "devices.power_meter.settings.wavelength_nm"
    assert "532" in err.value.errors[0].message and "633" in err.value.errors[0].message
