"""The point detectors' dark readings: planned like the camera's dark frames, read by the
engine with the light off, subtracted by the reduction with their uncertainty; a fit whose
residuals are a reading offset says so.

The end-to-end runs use the emulated bench (PM100USB firmware over the pyusb backend, its
photodiode's 2 nA dark current, ≈5.3 nW at 633 nm) with a Lambertian sample of ρ = 0.5.
"""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from analysis.brdf.goodness import offset_pattern
from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.pipelines.brdf.dark import lockin_dark, net_lockin_r, power_meter_dark
from instrument.pipelines.brdf.reduce import ReductionOptions, reduce_run
from instrument.plans import build_plan, parse_plan
from instrument.run.runfile import read_run

PROFILES = Path(__file__).parents[4] / "instrument" / "bench" / "profiles"

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "white standard on the power meter"
[sample]
name = "white"
[scan]
skip_beam_points = true
theta_i = [20, 50]
theta_r = [-70, -50, -30, 0, 10, 30, 50, 70, 80]
[acquisition]
detectors = ["power_meter"]
dark = "{dark}"
"""


def _lambert_bench(tmp_path: Path, rho: float = 0.5) -> Path:
    text = (PROFILES / "sim.toml").read_text(encoding="utf-8")
    text = re.sub(r'brdf = "lambert\+ggx"\nparams = \{[^}]*\}',
                  f'brdf = "lambert"\nparams = {{ rho = {rho} }}', text)
    assert f"rho = {rho}" in text
    path = tmp_path / "lambert.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _run(tmp_path: Path, dark: str) -> Path:
    plan = tmp_path / f"plan-{dark}.toml"
    plan.write_text(PLAN.format(dark=dark), encoding="utf-8")
    out = tmp_path / f"runs-{dark}"
    assert main(["run", str(plan), "--bench", str(_lambert_bench(tmp_path)), "--out",
                 str(out), "--no-fsync", "--quiet"]) == 0
    (path,) = out.glob("*.h5")
    return path


def _rho(out: str) -> tuple[float, float]:
    m = re.search(r"^\s+(?:lambert\.)?rho\s+([-\d.e+]+) ± ([\d.e+-]+)", out, re.M)
    assert m, out
    return float(m.group(1)), float(m.group(2))


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_power_meter_rho_of_a_lambert_half_sample_is_half_within_sigma(tmp_path, capsys):
    path = _run(tmp_path, "per_point")
    run = read_run(path)
    rows = run.brdf_rows()
    # the engine read the meter with the source off at every point: the dark current
    dark = run.power_dark_w[rows]
    assert np.all(np.abs(dark - 5.3e-9) < 1.5e-9), dark
    capsys.readouterr()
    assert main(["fit", str(path), "--detector", "power_meter", "--models",
                 "lambert,oren_nayar,lambert+ggx", "--no-cv", "--no-write"]) == 0
    out = capsys.readouterr().out
    assert "chosen model lambert " in out and "the model describes the data" in out, out
    rho, sigma = _rho(out)
    assert 0.0 < sigma < 0.01
    assert abs(rho - 0.5) <= 2.0 * sigma, (rho, sigma)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_without_a_dark_the_fit_names_the_offset_and_the_fix(tmp_path, capsys):
    path = _run(tmp_path, "none")
    capsys.readouterr()
    assert main(["fit", str(path), "--detector", "power_meter", "--models",
                 "lambert,lambert+ggx", "--no-cv", "--no-write"]) == 0
    out = capsys.readouterr().out
    assert "the model does not describe the data" in out
    assert "power-meter dark not measured" in out
    assert "residuals look like a constant offset" in out
    assert 'dark = "per_point"' in out


def test_a_dark_at_the_start_is_subtracted_from_every_point_as_one_shared_error(tmp_path):
    path = _run(tmp_path, "start")
    run = read_run(path)
    assert list(run.label[:1]) == ["dark"] and np.isnan(run.theta_i[0])
    red = reduce_run(path, ReductionOptions(detector="power_meter"))
    assert "dark points: 1 dark reading(s)" in red.provenance["detector_dark"]
    # one dark reading: its noise is not measured, and the report says so
    assert any("noise floor not measured" in w for w in red.warnings)
    # every point is ρ/π within its noise: the ≈5 nW dark (15–45 % of these readings) is
    # gone; the shared dark's error is a covariance, not independent noise
    pts = red.points
    assert pts.cov_corr is not None and np.all(pts.cov_corr > 0)
    u = np.sqrt(pts.u_stat**2 + pts.u_angle**2 + np.diag(pts.cov_corr))
    assert np.all(np.abs(pts.brdf - 0.5 / np.pi) < 4 * u), (pts.brdf * np.pi, u * np.pi)


def test_per_row_darks_come_before_every_row_of_theta_i():
    spec = parse_plan(PLAN.format(dark="per_row"), source="plan")
    plan = build_plan(spec, load_profile("sim"))
    labels = [p.label for p in plan.points]
    rows = [p.angles.theta_i for p in plan.points if p.angles is not None]
    starts = [k for k, p in enumerate(plan.points) if p.label == "dark"]
    assert len(starts) == len(set(rows)) == 2
    for k in starts:
        nxt = plan.points[k + 1]
        assert not plan.points[k].light and not plan.points[k].targets
        assert nxt.label == "sample"
        assert k == 0 or plan.points[k - 1].angles.theta_i != nxt.angles.theta_i
    assert labels.count("sample") == len(rows)


def _fake_run(power, dark_col=None, labels=None):
    n = len(power)
    return SimpleNamespace(
        power_w=np.asarray(power, float), power_dark_w=None if dark_col is None
        else np.asarray(dark_col, float), label=np.array(labels or ["sample"] * n),
        point_status=np.zeros(n, int), lockin_dark_x_v=None, lockin_dark_y_v=None,
        lockin_dark_u_v=None, lockin_x_v=None, lockin_y_v=None, lockin_u_r_v=None)


def test_per_point_darks_measure_the_noise_floor_from_their_spread():
    rng = np.random.default_rng(3)
    d = 5e-9 + 2e-10 * rng.standard_normal(40)
    run = _fake_run(30e-9 + d, d)
    dark = power_meter_dark(run, np.arange(40))
    assert dark.policy == "per_point" and np.array_equal(dark.level, d)
    assert dark.noise_floor == pytest.approx(2e-10, rel=0.3)  # 40 readings: ±11 % (1σ)
    assert np.all(dark.group == -1) and not np.any(dark.shared_covariance())


def test_dark_points_are_matched_to_the_latest_one_before_and_share_their_error():
    labels = ["dark", "sample", "sample", "dark", "sample", "dark"]
    power = [5e-9, 30e-9, 31e-9, 5.2e-9, 32e-9, 5.1e-9]
    run = _fake_run(power, labels=labels)
    rows = np.array([1, 2, 4])
    dark = power_meter_dark(run, rows)
    assert dark.policy == "dark points" and dark.n_readings == 3
    assert list(dark.level) == [5e-9, 5e-9, 5.2e-9]
    floor = np.std([5e-9, 5.2e-9, 5.1e-9], ddof=1)
    assert dark.noise_floor == pytest.approx(floor)
    cov = dark.shared_covariance()
    assert cov[0, 1] == pytest.approx(floor**2) and cov[0, 2] == 0.0
    none = power_meter_dark(_fake_run(power[1:3]), np.arange(2))
    assert not none.measured and np.all(none.level == 0)


def test_a_lock_in_dark_is_subtracted_as_a_phasor():
    n = 3
    run = _fake_run(np.zeros(n))
    run.lockin_dark_x_v = np.array([1e-6, 1e-6, 1e-6])
    run.lockin_dark_y_v = np.array([-1e-6, -1e-6, -1e-6])
    run.lockin_dark_u_v = np.full(n, 2e-8)
    dark = lockin_dark(run, np.arange(n))
    x = np.array([11e-6, 1e-6, 4e-6])
    y = np.array([-1e-6, 9e-6, 3e-6])
    r, u = net_lockin_r(x, y, np.full(n, 3e-8), dark)
    assert r == pytest.approx([10e-6, 10e-6, 5e-6])
    assert u == pytest.approx(np.full(n, np.hypot(3e-8, 2e-8)))
    assert lockin_dark(_fake_run(np.zeros(n)), np.arange(n)).policy == "none"


def test_the_offset_pattern_is_found_and_a_model_shape_is_not_taken_for_one():
    rng = np.random.default_rng(7)
    tr = np.radians(np.linspace(-75, 80, 30))
    sigma = np.full(tr.size, 0.01)
    template = 1 / np.cos(tr)
    noise = sigma * rng.standard_normal(tr.size)
    jac = np.ones((tr.size, 1))  # a constant model (Lambert)

    def residuals(y):  # of the constant model's least-squares fit
        return (y - np.mean(y)) / sigma

    # a reading offset of 0.2 (data units at normal incidence) on a constant BRDF of 0.16
    pat = offset_pattern(residuals(0.16 + 0.2 * template + noise), sigma, template,
                         jacobian=jac, dof=tr.size - 1)
    assert pat.looks_like_offset() and pat.amplitude == pytest.approx(0.2, rel=0.05)
    # a misfit of another shape (a lobe near θr = 20°) is not called an offset
    lobe = 0.3 * np.exp(-((np.degrees(tr) - 20) / 5) ** 2)
    pat = offset_pattern(residuals(0.16 + lobe + noise), sigma, template, jacobian=jac,
                         dof=tr.size - 1)
    assert not pat.looks_like_offset()




def test_the_lock_in_reads_its_dark_with_the_shutter_closed_at_every_point(tmp_path):
    """On the spectral sim bench (SR830 emulator, SC10 shutter, chopped photodiode) the
    engine reads the lock-in a second time with the shutter closed: X, Y of the input
    noise alone (no coherent pickup in the emulator: |X_d, Y_d| a few 10⁻⁸ V at a 30 ms
    time constant), orders of magnitude below the light's R."""
    from instrument.pipelines.brdf.spectral import (
        SpectralOptions,
        reduce_group,
        wavelength_groups,
    )
    from tests.instrument.bench.test_spectral_bench import LOCKIN_PLAN

    plan = tmp_path / "plan.toml"
    plan.write_text(LOCKIN_PLAN.replace("theta_r = [-50, 0, 50]", "theta_r = [-50, 50]")
                    .replace('dark = "none"', 'dark = "per_point"'), encoding="utf-8")
    assert main(["run", str(plan), "--bench", "sim-spectral", "--out", str(tmp_path / "runs"),
                 "--no-fsync", "--quiet"]) == 0
    (path,) = (tmp_path / "runs").glob("*.h5")
    run = read_run(path)
    dx, dy, du = run.lockin_dark_x_v, run.lockin_dark_y_v, run.lockin_dark_u_v
    assert np.all(np.isfinite(dx)) and np.all(np.isfinite(dy)) and np.all(du > 0)
    assert np.all(np.hypot(dx, dy) < 1e-3 * run.lockin_r_v)
    (group,) = wavelength_groups(run)
    red = reduce_group(run, group, SpectralOptions(), detector="lockin")
    assert red.provenance["detector_dark"].startswith("per_point: 2 dark reading(s)")
    assert not any("dark not measured" in w for w in red.warnings)
