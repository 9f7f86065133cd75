"""A dual-rotating-retarder scan through the engine on the emulated polarimetric bench.

Real drivers move the K10CR1 emulators that turn the retarders; the power meter reads the
intensity the Stokes world sends through the hidden optics. The run file keeps the mounts'
read-back angles and the optical train; the data-reduction matrix built from the hidden
optics recovers the sample's aperture-averaged Mueller matrix (the world's own truth).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import h5py
import numpy as np
import pytest

from analysis.polarimetry.drr import instrument_matrix, reduce
from hw_mocks.sim.world import find_world
from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.pipelines.brdf.pipeline import fit_run
from instrument.plans import build_plan
from instrument.plans.planfile import PlanError, parse_plan
from instrument.run.runfile import RunFileError, read_run

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "glass, polarimetric"
order = "raster"

[sample]
name = "glass"

[scan]
theta_i = [50.0]
theta_r = [50.0]

[acquisition]
detectors = ["power_meter"]
dark = "per_point"

[polarimetry]
mode = "drr"
steps = 25
"""


def fast_profile(name: str = "sim-polarimetric") -> str:
    # the mounts turn 10× faster than the built-in profile's emulated K10CR1s (ELL14s)
    text = load_profile(name).source_text
    return text.replace("model=K10CR1&speed=50", "model=K10CR1&speed=500").replace(
        "addresses=0123&speed=20", "addresses=0123&speed=200")


def test_a_polarimetric_plan_steps_both_retarders_at_every_geometry():
    plan = build_plan(parse_plan(PLAN.replace("theta_r = [50.0]", "theta_r = [30.0, 50.0]")),
                      load_profile("sim-polarimetric"))
    lit = [p for p in plan.points if p.light]
    assert len(lit) == 2 * 25
    first = lit[:25]
    psg = np.array([p.target_dict()["psg_retarder"] for p in first])
    psa = np.array([p.target_dict()["psa_retarder"] for p in first])
    np.testing.assert_allclose(psg, 180.0 * np.arange(25) / 25)
    np.testing.assert_allclose(psa, (5 * psg) % 360.0)
    assert {p.target_dict()["psg_polariser"] for p in plan.points} == {0.0}
    assert [dict(p.meta)["drr_step"] for p in first] == list(range(25))
    assert len({(p.angles.theta_i, p.angles.theta_r) for p in first}) == 1


MOUNTS = """
[devices.psg_retarder]
driver = "thorlabs_apt"
url = "simapt://psg_retarder?model=K10CR1&speed=50"
stage = "K10CR1"
limits = [-10.0, 370.0]

[devices.psa_retarder]
driver = "thorlabs_apt"
url = "simapt://psa_retarder?model=K10CR1&speed=50"
stage = "K10CR1"
limits = [-10.0, 370.0]

[[optics.source]]
kind = "retarder"
mount = "psg_retarder"
retardance_deg = [95.0, 90.0, 86.0]
retardance_nm = [450.0, 550.0, 650.0]

[[optics.detector]]
kind = "retarder"
mount = "psa_retarder"
retardance_deg = 90.0
"""


def test_polarimetry_across_a_hemisphere_and_a_wavelength_axis(capsys, tmp_path):
    hemisphere = PLAN.replace('kind = "brdf_in_plane"', 'kind = "brdf_hemisphere"').replace(
        "theta_i = [50.0]\ntheta_r = [50.0]",
        "theta_i = [30.0]\nn_directions = 6\ntheta_max_deg = 60.0")
    # the out-of-plane goniometer with a retarder on a mount in each arm
    out_of_plane = tmp_path / "hemisphere.toml"
    out_of_plane.write_text(load_profile("sim-out-of-plane").source_text + MOUNTS,
                            encoding="utf-8")
    plan = build_plan(parse_plan(hemisphere), load_profile(out_of_plane))
    lit = [p for p in plan.points if p.light]
    geometries = {(p.angles.theta_r, p.angles.phi_r) for p in lit}
    assert len(lit) == 25 * len(geometries) and len(geometries) >= 3
    # the spectral bench with a retarder in each arm: K steps at every geometry and filter;
    # the planner judges the retardance table at each filter's wavelength
    bench = tmp_path / "bench.toml"
    bench.write_text(load_profile("sim-spectral").source_text + MOUNTS, encoding="utf-8")
    spectral = PLAN + "\n[spectral]\nfilters = [1, 3]\n"
    plan = build_plan(parse_plan(spectral), load_profile(bench))
    lit = [p for p in plan.points if p.light]
    assert len(lit) == 2 * 25
    assert [dict(p.meta)["filter"] for p in lit] == [1] * 25 + [3] * 25
    assert [dict(p.meta)["drr_step"] for p in lit] == [*range(25)] * 2
    path = tmp_path / "plan.toml"
    path.write_text(spectral, encoding="utf-8")
    assert main(["plan", str(path), "--bench", str(bench), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "at 450 nm (retardances 95° / 90°)" in out
    assert "at 650 nm (retardances 86° / 90°)" in out


@pytest.mark.parametrize(("table", "field"), [
    ('mode = "pem"\nsteps = 25', "polarimetry.steps"),  # PEM mode has no retarder steps
    ('mode = "rotating_analyser"', "polarimetry.mode"),
    ("steps = 12", "polarimetry.steps"),
    ("ratio = 1", "polarimetry.ratio"),
    ("turns = 3", "polarimetry.turns"),
])
def test_a_bad_polarimetry_table_is_refused_by_field(table, field):
    with pytest.raises(PlanError) as err:
        parse_plan(PLAN.replace('mode = "drr"\nsteps = 25', table))
    assert field in {e.path for e in err.value.errors}


def test_a_singular_step_count_and_a_bench_without_optics_are_refused():
    with pytest.raises(PlanError, match="singular"):
        build_plan(parse_plan(PLAN.replace("steps = 25", "steps = 20")),
                   load_profile("sim-polarimetric"))
    with pytest.raises(PlanError, match="names no optical train"):
        build_plan(parse_plan(PLAN), load_profile("sim"))


def test_the_planner_shows_the_condition_number(capsys, tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN, encoding="utf-8")
    assert main(["plan", str(plan), "--bench", "sim-polarimetric", "--out",
                 str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "25 steps per geometry, ratio 5" in out
    # quarter-wave retarders: κ = 13.0 against 3.40 at the optimum retardance (Smith 2002)
    assert "κ = 13 at 633 nm" in out and "κ = 3.4 at 128°" in out
    assert "warning: κ is more than 2× the optimum's" in out


@pytest.mark.slow  # 25 emulated mount moves and aperture integrals: 40-65 s on a loaded box
# the same bench with its K10CR1 mounts, and with four ELL14s on one Elliptec bus, each
# module its own axis of the world (bound by address)
@pytest.mark.parametrize("bench_name", ["sim-polarimetric", "sim-polarimetric-ell14"])
def test_the_engine_records_the_mounts_and_recovers_the_hidden_mueller_matrix(tmp_path,
                                                                           bench_name):
    bench = tmp_path / "bench.toml"
    bench.write_text(fast_profile(bench_name), encoding="utf-8")
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN, encoding="utf-8")
    out = tmp_path / "runs"
    assert main(["run", str(plan), "--bench", str(bench), "--out", str(out), "--no-fsync",
                 "--quiet"]) == 0
    (path,) = out.glob("*.h5")
    run = read_run(path)
    assert run.n_points == 25
    axes = list(run.axes)
    positions = np.asarray(run.positions)
    psg = positions[:, axes.index("psg_retarder")]
    psa = positions[:, axes.index("psa_retarder")]
    # the read-back angles, within the profile's arrival tolerance of the plan's
    np.testing.assert_allclose(psg, 180.0 * np.arange(25) / 25, atol=0.01)
    np.testing.assert_allclose(psa, (5 * 180.0 * np.arange(25) / 25) % 360.0, atol=0.01)
    with h5py.File(path, "r") as f:
        train = json.loads(f["entry/instrument/optical_train"][()].decode())
    assert train["polarimetry"] == {"mode": "drr", "steps": 25, "ratio": 5.0}
    assert train["optics"]["source"][1]["retardance_deg"] == [90.0]

    # the hidden optics (the profile's [simulation.optics]) and the world's truth
    # the meter's dark current (2 nA, not zeroed) off each reading by its own dark
    power = np.asarray(run.power_w) - np.asarray(run.power_dark_w)
    # W is for a unit unpolarised source (0.5 through the polariser); the laser is
    # polarised 98 % along it, 0.3° off: (1 + 0.98 cos 0.6°)/2 of it passes
    laser = 1.0 + 0.98 * math.cos(math.radians(0.6))
    w = laser * instrument_matrix(psg + 2.0, psa - 2.0, psg_retardance=math.radians(94.5),
                                  psa_retardance=math.radians(85.5), psg_polariser_deg=0.3,
                                  psa_polariser_deg=-0.3)
    # the meter's noise (profile: relative_noise, floor; the dark's floor as well)
    sigma = np.hypot(1e-4 * power, math.sqrt(2.0) * 2.6e-10)
    est = reduce(power, sigma, w)
    world = find_world(bench_name)
    state = world.snapshot()
    state = replace(state, source=replace(state.source, on=True))  # off after the run
    head = world.power_meter
    truth = state.scene.mueller_on_aperture(state.pose.detector_dir * head.distance_mm,
                                            -state.pose.detector_dir,
                                            head.aperture_diameter_mm, state)
    m = np.asarray(est.m)
    s = np.asarray(est.sigma)
    # polarisers of extinction 1e-5, which W leaves out, shift m by ~1e-5 of m00 (≪ σ)
    pull = (m - truth) / s
    assert np.all(np.abs(pull) < 4.0), np.round(pull, 2)
    # with the nominal optics (no calibration) the same data are visibly off
    nominal = (1.0 + 0.98) * instrument_matrix(psg, psa, psg_retardance=math.pi / 2,
                                               psa_retardance=math.pi / 2)
    off = reduce(power, sigma, nominal)
    assert np.max(np.abs((np.asarray(off.m) - truth) / np.asarray(off.sigma))) > 10.0
    # Brewster's neighbourhood: strongly p-suppressing at 50° on glass
    assert truth[0, 1] / truth[0, 0] < -0.5
    # the scalar fit would mix the analyser's states: refused, naming the way to reduce it
    with pytest.raises(RunFileError, match=r"polarimetric run.*scatterlab fit"):
        fit_run(path, report=False, write=False)
