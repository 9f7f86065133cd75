"""`scatterlab devices --bench sim` opens every emulated device through the real drivers."""

from __future__ import annotations

import re

import pytest

from instrument.bench.devices import open_bench, simulation_config
from instrument.bench.profile import load_profile
from instrument.cli import main


def test_devices_lists_identity_homed_state_and_position(capsys):
    assert main(["devices", "--bench", "sim", "--home"]) == 0
    out = capsys.readouterr().out
    for role in ("sample_theta", "detector_theta", "camera_z", "camera", "power_meter",
                 "source"):
        assert re.search(rf"^\s+{role}\s", out, re.M), out
    assert "Thorlabs K10CR1" in out and "Newport SMC100" in out and "PM100USB" in out
    assert out.count("homed, position 0.0000") == 3
    assert "NOT homed" not in out


def test_devices_reports_unhomed_axes_without_home(capsys):
    assert main(["devices", "--bench", "sim"]) == 0
    out = capsys.readouterr().out
    assert "NOT homed" in out


def test_bad_profile_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bench.toml"
    bad.write_text('[bench]\nname = 3\n[devices.x]\ndriver = "nope"\nurl = "x"\n')
    assert main(["devices", "--bench", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bench.name" in err and "devices.x.driver" in err


def test_simulation_config_binds_roles_and_power_meter():
    profile = load_profile("sim")
    world, config = simulation_config(profile)
    assert world == "sim"
    assert config["roles"]["sample_theta"].startswith("simapt://sample_theta")
    assert config["power_meter"]["url"].startswith("simusb://power_meter")
    assert config["arm_length_mm"] == profile.geometry.detector_distance_mm


def test_open_bench_moves_real_stages_and_leaves_safe():
    profile = load_profile("sim")
    with open_bench(profile, roles=["sample_theta", "source"]) as bench:
        axis = bench.axes["sample_theta"]
        axis.enable()
        axis.home(timeout=60)
        axis.move_to(12.5, wait=True, timeout=60)
        assert abs(axis.position - 12.5) <= axis.position_tolerance
        bench.source.turn_on()
        assert bench.source.is_on
    assert bench.source.closed and axis.closed


def test_power_meter_reads_the_world_after_an_emulated_power_cycle():
    from hw_mocks import registry

    profile = load_profile("sim")
    with open_bench(profile, roles=["source", "power_meter"]) as bench:
        bench.source.turn_on()
        lit = bench.power_meter.read_power_w()
    registry.remove("simusb", "power_meter")  # the meter is unplugged and powered again
    from instrument.bench.devices import open_device

    with open_device(profile.device("power_meter")) as meter, \
            open_device(profile.device("source")) as source:
        source.turn_on()
        again = meter.read_power_w()
    # Detector arm at 0 deg looks straight down the beam path onto the sample: a real,
    # positive reading, the same light before and after the power cycle (noise aside).
    assert lit > 1e-8
    assert again == pytest.approx(lit, rel=0.05)


def test_axes_the_plan_does_not_move_are_recorded_with_homed_state():
    from instrument.run.runner import static_axis_positions

    profile = load_profile("sim")
    with open_bench(profile, roles=["sample_theta", "camera_z"]) as bench:
        before = static_axis_positions(bench, moved=("sample_theta",))
        cam = bench.axes["camera_z"]
        cam.enable()
        cam.home(timeout=60)
        cam.move_to(4.0, wait=True, timeout=60)
        after = static_axis_positions(bench, moved=("sample_theta",))
    assert "axis_position.sample_theta" not in before
    assert before["axis_homed.camera_z"] == 0
    assert after["axis_homed.camera_z"] == 1
    assert after["axis_position.camera_z"] == pytest.approx(4.0, abs=cam.position_tolerance)


def test_bad_simulation_table_is_a_field_error_not_a_traceback(tmp_path, capsys):
    text = load_profile("sim").source_text.replace(
        'brdf = "lambert+ggx"', 'brdf = "lambert+ggx"\nglitter = 3')
    bench = tmp_path / "bad.toml"
    bench.write_text(text)
    assert main(["devices", "--bench", str(bench)]) == 2
    err = capsys.readouterr().err
    assert "simulation" in err and "glitter" in err and "Traceback" not in err
