"""Neutral-density filters for the specular peak (ADR 0018): the engine reads a point again
through the next denser filter when the camera clips at its shortest exposure and records
the filter per point; the ND calibration plan measures each filter's transmission; the
reduction divides it out with its uncertainty.

The runs use the emulated ``sim`` bench (FW102C wheel over the wire, its hidden true
transmissions 0.1043, 0.00962, 0.001071 for nominal OD 1, 2, 3) with the sharp sample
(Lambert 0.3 + GGX ks 0.5, α 0.05), stages 400× faster than real and, where the fit is not
the point, a 128 × 128 px camera.
"""

from __future__ import annotations

import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from drivers.base import FilterSpec
from hw_mocks.sim.filters import NeutralDensity, parse_bands, transmit
from hw_mocks.sim.state import SourceState
from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.pipelines.brdf.attenuation import (
    Transmission,
    apply_nd,
    calibrate_nd,
    nd_slots,
)
from instrument.pipelines.brdf.reduce import ReductionOptions, reduce_run
from instrument.plans import build_plan, parse_plan
from instrument.plans.planfile import PlanError
from instrument.run.recovery import recover
from instrument.run.runfile import read_run

ROOT = Path(__file__).parents[4]
PROFILES = ROOT / "instrument" / "bench" / "profiles"
TRUE_T = {2: 0.1043, 3: 0.00962, 4: 0.001071}

PEAK_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "the sharp peak"
order = "raster"
[sample]
name = "sharp"
[scan]
skip_beam_points = true
points = [[20, 10], [20, 18], [20, 20], [20, 22], [20, 40]]
[acquisition]
mode = "auto"
exposure_us = 2000
min_exposure_us = 10
max_exposure_us = 200000
hdr = true
dark = "per_point"
detectors = ["camera", "power_meter"]
"""


def sharp_bench(tmp_path: Path, *, small: bool = True, wheel: bool = True) -> Path:
    """The sim bench with the sharp sample (optionally a 128-px camera, no wheel)."""
    text = (PROFILES / "sim.toml").read_text(encoding="utf-8")
    text = text.replace('"lambert.rho" = 0.5, "ggx.ks" = 0.2, "ggx.alpha" = 0.2',
                        '"lambert.rho" = 0.3, "ggx.ks" = 0.5, "ggx.alpha" = 0.05')
    text = text.replace("speed=20", "speed=400")
    if small:
        text = text.replace("simcam://camera?world=sim&seed=1",
                            "simcam://camera?world=sim&seed=1&width=128&height=128")
    if not wheel:
        text = re.sub(r"\[(devices|simulation)\.filter_wheel\].*?\n\n", "", text, flags=re.S)
    assert "ggx.alpha\" = 0.05" in text and ("width=128" in text) == small
    path = tmp_path / ("sharp.toml" if wheel else "sharp-no-wheel.toml")
    path.write_text(text, encoding="utf-8")
    return path


def run_plan(tmp_path: Path, plan_text: str, bench: Path, name: str) -> Path:
    plan = tmp_path / f"{name}.toml"
    plan.write_text(plan_text, encoding="utf-8")
    out = tmp_path / name
    assert main(["run", str(plan), "--bench", str(bench), "--out", str(out), "--no-fsync",
                 "--quiet"]) == 0
    (path,) = out.glob("*.h5")
    return path


# the configuration and the simulated optics ------------------------------------------
def test_a_neutral_density_slot_is_parsed_with_its_calibration_and_checked():
    spec = FilterSpec.parse({"od": 2.0, "transmission": 0.0101, "u_transmission": 1e-4,
                             "label": "ND2"})
    assert spec.is_neutral_density and not spec.is_empty and spec.center_nm is None
    assert FilterSpec().is_empty and not FilterSpec().is_neutral_density
    for bad in ({"od": -1.0}, {"od": 1.0, "center_nm": 600.0, "bandwidth_nm": 10.0},
                {"transmission": 0.1}, {"od": 1.0, "transmission": 1.5},
                {"od": 1.0, "u_transmission": -0.1}, {"od": 1.0, "density": 1.0}):
        with pytest.raises(ValueError):
            FilterSpec.parse(bad)


def test_the_simulated_nd_filter_scales_the_light_at_every_wavelength():
    bands = parse_bands({"2": {"transmission": 0.1043}, "3": {}})
    assert bands == {2: NeutralDensity(0.1043)}
    light = SourceState(on=True, power_w=1e-3, wavelength_nm=633.0)
    through = transmit(light, bands[2])
    assert through.power_w == pytest.approx(1.043e-4, rel=1e-12)
    assert through.wavelength_nm == 633.0
    with pytest.raises(ValueError):
        NeutralDensity(0.0)


def test_the_sim_bench_has_an_open_slot_and_nd_filters_whose_truth_differs_from_nominal():
    profile = load_profile(PROFILES / "sim.toml")
    wheel = profile.devices["filter_wheel"]
    assert wheel.driver == "fw102c" and wheel.url.startswith("simfw102c://")
    filters = wheel.options["filters"]
    assert {int(k): v["od"] for k, v in filters.items()} == {2: 1.0, 3: 2.0, 4: 3.0}
    truth = profile.simulation["filter_wheel"]["filters"]
    for slot, t in TRUE_T.items():
        assert truth[str(slot)]["transmission"] == t
        assert 0.02 < abs(t / 10.0 ** -filters[str(slot)]["od"] - 1) < 0.1


# the reduction's arithmetic ------------------------------------------------------------
def test_readings_are_divided_by_their_filter_and_share_its_calibration_error():
    table = {2: Transmission(2, 0.1, 0.001, "cal"), 3: Transmission(3, 0.01, 0.0002, "cal"),
             4: Transmission(4, 0.001, 1e-4, "nominal", calibrated=False)}
    power = np.array([1.0, 0.1, 0.1, 0.01, 0.001])
    u = np.full(5, 1e-4)
    slots = np.array([-1, 2, 2, 3, 4])
    p, up, cov = apply_nd(power, u, slots, table)
    assert np.allclose(p, [1.0, 1.0, 1.0, 1.0, 1.0])
    assert np.allclose(up[:4], [1e-4, 1e-3, 1e-3, 1e-2])
    # the uncalibrated filter's 10 % is in its point's own σ, not shared
    assert up[4] == pytest.approx(np.hypot(0.1, 0.1))
    expected = np.zeros((5, 5))
    expected[1:3, 1:3] = 0.01**2
    expected[3, 3] = 0.02**2
    assert np.allclose(cov, expected)
    assert apply_nd(power, u, np.full(5, -1), table)[2] is None


# through the engine --------------------------------------------------------------------
def test_the_engine_reads_the_clipping_peak_through_the_next_nd_filter(tmp_path):
    path = run_plan(tmp_path, PEAK_PLAN, sharp_bench(tmp_path), "peak")
    run = read_run(path)
    rows = run.brdf_rows()
    slots = nd_slots(run, rows)
    # the peak (θr = 18–22°) clips the open beam at 10 µs: read through ND1 (slot 2);
    # far from it (θr = 10°) the open beam; the slot in the beam is recorded as well
    assert list(slots[1:4]) == [2, 2, 2] and slots[0] == -1
    assert list(run.filter_position[rows[1:4]]) == [2, 2, 2]
    red = reduce_run(path)
    assert not red.points.clipped.any()
    assert "ND1" in " ".join(red.provenance["nd_filters"])
    assert any("not calibrated" in w for w in red.warnings)
    # the power meter read the same light as the camera: through the filter, ≈ T × open
    # (its dark subtracted; the peak's power changes little between 20° and 22°)
    pm = run.power_w[rows] - run.power_dark_w[rows]
    assert 0.05 < pm[3] / pm[2] < 2.0
    # after the peak the wheel goes back to the open slot within one point
    assert slots[-1] in (-1, 2)
    # the journal carries the filter: a recovery rewrites the same column
    recover(path)
    assert np.array_equal(nd_slots(read_run(path), rows), slots)


def test_without_a_wheel_the_peak_is_clipped_and_the_column_says_open(tmp_path):
    path = run_plan(tmp_path, PEAK_PLAN, sharp_bench(tmp_path, wheel=False), "nowheel")
    run = read_run(path)
    assert np.all(nd_slots(run, run.brdf_rows()) == -1)
    red = reduce_run(path)
    assert red.points.clipped.sum() >= 2


def test_a_file_written_before_the_nd_column_reads_as_open(tmp_path):
    path = run_plan(tmp_path, PEAK_PLAN.replace("[20, 10], [20, 18], [20, 20], [20, 22], "
                                                "[20, 40]", "[20, 40]"),
                    sharp_bench(tmp_path), "old")
    with h5py.File(path, "r+") as f:
        del f["entry/points/nd_position"]
    run = read_run(path)
    assert run.nd_position is None
    assert list(nd_slots(run, run.brdf_rows())) == [-1]


def test_the_nd_calibration_plan_measures_each_filter_against_the_open_slot(tmp_path):
    plan = (ROOT / "examples" / "calibration_nd.toml").read_text(encoding="utf-8")
    plan = plan.replace("points = [[20.0, 10.0], [40.0, 30.0]]", "points = [[20.0, 10.0]]")
    path = run_plan(tmp_path, plan, sharp_bench(tmp_path), "cal")
    run = read_run(path)
    assert list(run.filter_position[run.brdf_rows()]) == [1, 2, 3, 4]
    table = calibrate_nd(path)
    assert sorted(table) == [2, 3, 4]
    for slot, t in TRUE_T.items():
        got = table[slot]
        assert got.calibrated and got.label == f"ND{slot - 1}"
        assert 0 < got.u < 0.01 * got.value
        assert abs(got.value - t) <= 4.0 * got.u, (slot, got, t)


def test_the_nd_calibration_plan_reads_every_filter_and_refuses_band_pass_slots(tmp_path):
    text = (ROOT / "examples" / "calibration_nd.toml").read_text(encoding="utf-8")
    plan = build_plan(parse_plan(text), load_profile(PROFILES / "sim.toml"))
    assert [dict(p.meta)["filter"] for p in plan.points] == [1, 1, 2, 2, 3, 3, 4, 4]
    # a wheel with band-pass filters and an ND filter: a list mixing them is refused
    spectral = (PROFILES / "sim-spectral.toml").read_text(encoding="utf-8")
    spectral = spectral.replace("3 = { center_nm = 650.0, bandwidth_nm = 10.0 } } }",
                                "3 = { center_nm = 650.0, bandwidth_nm = 10.0 }, "
                                "4 = { od = 1.0 } } }", 1)
    assert "4 = { od = 1.0 }" in spectral
    (tmp_path / "mixed.toml").write_text(spectral, encoding="utf-8")
    mixed = text.replace("[1, 2, 3, 4]", "[1, 4]")
    with pytest.raises(PlanError, match="mixes neutral-density filters with band-pass"):
        build_plan(parse_plan(mixed), load_profile(tmp_path / "mixed.toml"))


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_the_sharp_peak_through_calibrated_filters_is_in_the_fit(tmp_path, capsys):
    """1024-px camera (the receiver model is the full sensor's): the peak at θi = 20° read
    through ND1, the filters calibrated by the ND plan, fitted with the true family."""
    bench = sharp_bench(tmp_path, small=False)
    path = run_plan(tmp_path, PEAK_PLAN, bench, "peak")
    cal = run_plan(tmp_path, (ROOT / "examples" / "calibration_nd.toml").read_text(
        encoding="utf-8"), bench, "cal")
    capsys.readouterr()
    assert main(["fit", str(path), "--nd-calibration", str(cal), "--models", "lambert+ggx",
                 "--no-cv", "--no-write"]) == 0
    out = capsys.readouterr().out
    assert "the model describes the data" in out and "clipped" not in out, out
    assert "not calibrated" not in out
    for key, truth in (("lambert.rho", 0.3), ("ggx.ks", 0.5), ("ggx.alpha", 0.05)):
        m = re.search(rf"^\s+{re.escape(key)}\s+([-\d.e+]+) ± ([\d.e+-]+)", out, re.M)
        assert m, out
        value, sigma = float(m.group(1)), float(m.group(2))
        assert abs(value - truth) <= 2.0 * sigma, (key, value, sigma)
    red = reduce_run(path, ReductionOptions(nd_calibration=str(cal)))
    assert not red.points.clipped.any()
    assert "calibration run" in " ".join(red.provenance["nd_filters"])
