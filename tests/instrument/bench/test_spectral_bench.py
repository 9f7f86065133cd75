"""The lock-in, shutter, filter-wheel and Zaber drivers in bench profiles: the factory opens
them by driver name over their emulators' URLs, the shutter switches the light for dark
frames, and the virtual world's light follows the shutter and the filter wheel."""

from __future__ import annotations

import statistics
from pathlib import Path

import h5py
import numpy as np
import pytest

from drivers.base import FilterWheel, LockIn, MotionAxis, Shutter, ShutterState
from drivers.zaber_ascii import ZaberAxis
from instrument.bench.devices import open_bench
from instrument.bench.profile import ProfileError, load_profile, parse_profile
from instrument.cli import main

ROOT = Path(__file__).resolve().parents[3]

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "shutter darks"
[sample]
name = "spectral"
[scan]
theta_i = [20]
theta_r = [-30, 10]
[acquisition]
detectors = ["camera"]
dark = "per_point"
hdr = false
max_brackets = 1
"""


def _lockin_r(lockin: LockIn, n: int = 5) -> float:
    """Mean R (V rms) of ``n`` snapshots after the output has settled."""
    lockin.settle()
    return statistics.fmean(lockin.snapshot().r_v for _ in range(n))


def test_the_spectral_sim_bench_opens_every_kind_by_driver_name():
    profile = load_profile("sim-spectral")
    assert profile.photodiode == {"responsivity_a_per_w": 0.4, "u_responsivity_rel": 0.02,
                                  "transimpedance_v_per_a": 1e6, "chopper_hz": 137.0}
    with open_bench(profile) as bench:
        assert isinstance(bench.lockin, LockIn) and isinstance(bench.filter_wheel, FilterWheel)
        assert isinstance(bench.shutter, Shutter)
        # the shutter gates the light for dark frames; the source proper stays the source
        assert bench.light_switch is bench.shutter and bench.source is not bench.shutter
        stage = bench.devices["camera_z"]
        assert isinstance(stage, ZaberAxis) and isinstance(stage, MotionAxis)
        stage.home(wait=True)
        stage.move_to(12.5, wait=True)
        assert stage.position == pytest.approx(12.5, abs=0.001)


def test_the_lock_in_sees_the_light_through_the_shutter_and_the_filter():
    """Shutter closed: R is the amplifier's noise; open: the chopped signal. The sample's
    albedo doubles from 450 to 650 nm (0.30 → 0.60): away from specular the signal
    follows it."""
    with open_bench(load_profile("sim-spectral")) as bench:
        for axis in bench.axes.values():
            axis.home(wait=True)
        bench.axes["sample_theta"].move_to(20.0, wait=True)
        bench.axes["detector_theta"].move_to(-40.0, wait=True)
        bench.source.turn_on()
        lockin, wheel, shutter = bench.lockin, bench.filter_wheel, bench.shutter
        lockin.reference_source = "external"  # REF IN from the chopper
        assert lockin.reference_frequency_hz == pytest.approx(137.0)
        r = {}
        for slot in (1, 3):
            wheel.move_to(slot)
            shutter.close_shutter()
            lockin.auto_range()
            r[slot, "closed"] = _lockin_r(lockin)
            shutter.open_shutter()
            lockin.auto_range()
            r[slot, "open"] = _lockin_r(lockin)
        bench.make_safe()
        assert shutter.shutter_state is ShutterState.CLOSED
    # open: ~64 µV at 450 nm ((√2/π)·R·G·P with P ≈ 0.1/sr × 33 µW × cos θr × Ω); closed:
    # the input noise, 10⁻⁸ V
    for slot in (1, 3):
        assert r[slot, "open"] > 1000 * r[slot, "closed"], r
    # diffuse geometry: the signal follows the albedo, 0.60/0.30, within the lobe's share
    # and the noise (a few per cent)
    assert r[3, "open"] / r[1, "open"] == pytest.approx(2.0, rel=0.1), r


def test_the_engine_takes_darks_with_the_shutter_and_leaves_it_closed(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN, encoding="utf-8")
    assert main(["run", str(plan), "--bench", "sim-spectral", "--out", str(tmp_path / "runs"),
                 "--no-fsync", "--quiet"]) == 0
    (path,) = (tmp_path / "runs").glob("*.h5")
    with h5py.File(path, "r") as f:
        light = f["entry/data/frame_light"][()]
        frames = f["entry/data/frames"]
        means = np.array([float(frames[k].mean()) for k in range(frames.shape[0])])
    assert light.sum() == 2 and (~light).sum() == 2
    # a dark frame has no light at all: the lit frames are brighter by several DN, where
    # the mean of 10⁶ pixels scatters by ~0.01 DN
    assert means[light].min() > means[~light].max() + 1.0
    # the bench was left safe: the shutter emulator (the same named controller) is closed
    with open_bench(load_profile("sim-spectral"), roles=["shutter"]) as bench:
        assert bench.shutter.shutter_state is ShutterState.CLOSED


def test_the_real_lock_in_example_profile_validates():
    profile = load_profile(ROOT / "examples" / "bench_lockin_real.toml")
    drivers = {role: spec.driver for role, spec in profile.devices.items()}
    assert drivers == {"sample_theta": "zaber", "detector_theta": "thorlabs_apt",
                       "camera_z": "zaber", "shutter": "sc10", "filter_wheel": "fw102c",
                       "lockin": "sr830", "power_meter": "pm100usb"}
    assert all(spec.url.startswith(("/dev/ttyUSB", "usb://"))
               for spec in profile.devices.values())
    assert len(profile.photodiode["responsivity_nm"]) == 7


BASE = """
[bench]
name = "x"
[devices.lockin]
driver = "sr830"
url = "/dev/ttyUSB0"
"""


@pytest.mark.parametrize(("table", "field"), [
    ("[photodiode]\nresponsivity_a_per_w = 0.4\n", "photodiode.transimpedance_v_per_a"),
    ("[photodiode]\nresponsivity_a_per_w = [0.1, 0.2]\ntransimpedance_v_per_a = 1e6\n",
     "photodiode.responsivity_nm"),
    ("[photodiode]\nresponsivity_a_per_w = [0.1, 0.2]\nresponsivity_nm = [500, 400]\n"
     "transimpedance_v_per_a = 1e6\n", "photodiode.responsivity_nm"),
    ("[photodiode]\nresponsivity_a_per_w = -1\ntransimpedance_v_per_a = 1e6\n",
     "photodiode.responsivity_a_per_w"),
    ("[photodiode]\nresponsivity_a_per_w = 0.4\ntransimpedance_v_per_a = 1e6\ngain = 3\n",
     "photodiode.gain"),
])
def test_a_bad_photodiode_table_names_its_field(table, field):
    with pytest.raises(ProfileError) as err:
        parse_profile(BASE + table)
    assert any(e.path == field for e in err.value.errors), err.value


def test_a_photodiode_without_a_lock_in_is_refused():
    text = BASE.replace('driver = "sr830"', 'driver = "sc10"') + (
        "[photodiode]\nresponsivity_a_per_w = 0.4\ntransimpedance_v_per_a = 1e6\n")
    with pytest.raises(ProfileError, match="needs a device with driver 'sr830'"):
        parse_profile(text)


def test_serve_sim_serves_every_emulated_serial_controller(capsys):
    assert main(["serve-sim", "--bench", "sim-spectral", "--duration", "0.2"]) == 0
    out = capsys.readouterr().out
    for role in ("sample_theta", "detector_theta", "camera_z", "shutter", "filter_wheel",
                 "lockin"):
        assert f"{role}: sim" in out and "/dev/pts/" in out, role


LOCKIN_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "lock-in scan"
[sample]
name = "spectral"
[scan]
theta_i = [20]
theta_r = [-50, 0, 50]
[acquisition]
detectors = ["lockin"]
dark = "none"
frames = 4
"""


def test_a_lock_in_scan_records_its_readings_and_the_filter_per_point(tmp_path):
    """``detectors = ["lockin"]`` through the engine, the SR830 driver and its emulator on
    the spectral sim bench: each point has R (mean of 4 snapshots) with its standard
    error, the range and time constant it was read at, and the filter in the beam. R
    turned back into a BRDF with the documented photodiode model (R = (√2/π)·R_pd·G·P;
    hw_mocks/sim/photodiode.py) is the diffuse albedo's ρ/π = 0.0955 at 450 nm on the
    source side (θr = −50°, 70° from specular), within 10 % (the lobe's tail and the
    aperture's average); on the specular side at +50° the lobe adds more."""
    from instrument.run.recovery import recover
    from instrument.run.runfile import read_run

    plan = tmp_path / "plan.toml"
    plan.write_text(LOCKIN_PLAN, encoding="utf-8")
    assert main(["run", str(plan), "--bench", "sim-spectral", "--out", str(tmp_path / "runs"),
                 "--no-fsync", "--quiet"]) == 0
    (path,) = (tmp_path / "runs").glob("*.h5")
    run = read_run(path)
    r, u = run.lockin_r_v, run.lockin_u_r_v
    assert np.all(np.isfinite(r)) and np.all(r > 0) and np.all((u > 0) & (u < 1e-3 * r))
    # auto-ranged: R below half the full scale, above a tenth of it (ranges step 1-2-5)
    assert np.all((r < 0.5 * run.lockin_sensitivity_v) & (r > 0.1 * run.lockin_sensitivity_v))
    assert np.all(run.lockin_time_constant_s == 0.03) and np.all(run.lockin_overload == 0)
    assert list(run.filter_position) == [1, 1, 1]
    assert np.all(run.wavelength_nm == 450.0) and np.all(run.bandwidth_nm == 10.0)
    power_w = r / (np.sqrt(2) / np.pi * 0.4 * 1e6)
    incident_w = 1e-3 * 10.0 / 300.0  # the flat 300 nm band through a 10 nm filter
    omega = np.pi * 2.5**2 / 300.0**2
    off = np.abs(run.theta_r - 50.0) < 0.1
    brdf = power_w[off] / (incident_w * np.cos(np.radians(run.theta_r[off])) * omega)
    source_side, specular_side = np.sort(brdf)  # θr is stored unsigned: the lobe tells
    assert source_side == pytest.approx(0.30 / np.pi, rel=0.10)
    assert specular_side > source_side
    # the journal carries the readings: a recovery rewrites the same columns
    recover(path)
    again = read_run(path)
    assert np.array_equal(again.lockin_r_v, r) and list(again.filter_position) == [1, 1, 1]


def test_a_jammed_filter_wheel_mid_scan_ends_in_the_retry_policy_with_the_bench_safe(
        tmp_path):
    """The FW102C emulator's wheel stalls at the slot before the one asked for (it prompts
    as if done; the driver reads the position back and raises WheelJammed). With the
    wheel's policy ``attempts = 1, on_failure = "abort"`` the run aborts at the second
    filter, the fault is in the run's event log with the device and the cause, the points
    of the first filter are kept, and the shutter is closed."""
    from hw_mocks import registry
    from instrument.run.runfile import read_events, read_run

    text = load_profile("sim-spectral").source_text.replace(
        'url = "simfw102c://filter_wheel?world=sim-spectral"\noptions',
        'url = "simfw102c://filter_wheel?world=sim-spectral"\n'
        'retry = { attempts = 1, on_failure = "abort" }\noptions')
    assert 'on_failure = "abort"' in text
    bench = tmp_path / "bench.toml"
    bench.write_text(text, encoding="utf-8")
    plan = tmp_path / "plan.toml"
    plan.write_text(LOCKIN_PLAN.replace("theta_r = [-50, 0, 50]", "theta_r = [-50, 50]")
                    + "[spectral]\nfilters = [1, 3]\n", encoding="utf-8")
    with open_bench(load_profile(str(bench)), roles=["filter_wheel"]) as wheel_bench:
        wheel_bench.filter_wheel.move_to(1)  # the first filter needs no move
    registry.get("simfw102c", "filter_wheel").jam("stall")  # the next move: to slot 3
    assert main(["run", str(plan), "--bench", str(bench), "--out", str(tmp_path / "runs"),
                 "--no-fsync", "--quiet"]) == 1
    (path,) = (tmp_path / "runs").glob("*.h5")
    run = read_run(path)
    assert run.status == "aborted" and run.n_points == 2
    assert list(run.filter_position) == [1, 1]
    faults = [e for e in read_events(path) if e.get("kind") == "fault"]
    assert faults and faults[-1]["device"] == "filter_wheel"
    assert "filter_wheel" in faults[-1]["cause"] and faults[-1]["action"] == "abort"
    with open_bench(load_profile(str(bench)), roles=["shutter"]) as after:
        assert after.shutter.shutter_state is ShutterState.CLOSED


def _abort_profile(tmp_path, role: str) -> Path:
    """sim-spectral with ``role``'s retry policy one attempt, then abort."""
    text = load_profile("sim-spectral").source_text
    head = f"[devices.{role}]\n"
    assert head in text
    text = text.replace(head, head + 'retry = { attempts = 1, on_failure = "abort" }\n', 1)
    path = tmp_path / "bench.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _run_aborted(tmp_path, bench: Path, plan_text: str) -> tuple[Path, dict]:
    from instrument.run.runfile import read_events, read_run

    plan = tmp_path / "plan.toml"
    plan.write_text(plan_text, encoding="utf-8")
    assert main(["run", str(plan), "--bench", str(bench), "--out", str(tmp_path / "runs"),
                 "--no-fsync", "--quiet"]) == 1
    (path,) = (tmp_path / "runs").glob("*.h5")
    assert read_run(path).status == "aborted"
    faults = [e for e in read_events(path) if e.get("kind") == "fault"]
    return path, faults[-1]


def test_a_lock_in_that_stays_overloaded_ends_in_its_retry_policy(tmp_path):
    """An input of 2 V rms overloads the SR830's input stage at every range: the engine
    re-ranges three times, then the point fails as a device error of the lock-in and its
    policy (abort) ends the run; nothing is recorded as a reading."""
    from hw_mocks import registry

    bench = _abort_profile(tmp_path, "lockin")
    with open_bench(load_profile(str(bench)), roles=["lockin"]):
        registry.get("simsr830", "lockin").set_input(2.0)
    _path, fault = _run_aborted(tmp_path, bench, LOCKIN_PLAN)
    assert fault["device"] == "lockin" and fault["action"] == "abort"
    assert "overload" in fault["cause"].lower()


def test_a_shutter_that_does_not_answer_is_a_typed_error_before_anything_moves(tmp_path,
                                                                             capsys):
    """The SC10 is off (no answer): opening the bench fails with a typed error naming the
    shutter and what to check, before any axis moves or any file is written (mid-run, the
    same timeout goes to the shutter's retry policy like any device error)."""
    from hw_mocks import registry

    bench = _abort_profile(tmp_path, "shutter")
    with open_bench(load_profile(str(bench)), roles=["shutter"]):
        registry.get("simsc10", "shutter").power_off()
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN, encoding="utf-8")
    try:
        assert main(["run", str(plan), "--bench", str(bench), "--out",
                     str(tmp_path / "runs"), "--no-fsync", "--quiet"]) == 3
    finally:
        registry.get("simsc10", "shutter").power_on()  # closed at power-up
    err = capsys.readouterr().err
    assert err.startswith("device error: shutter:")
    assert not list((tmp_path / "runs").glob("*.h5"))


def test_the_power_meter_sees_the_filter_s_colour_not_the_source_s():
    """The PM100 emulator's photodiode responds at the wavelength of the light that reaches
    it: behind the 450 nm filter, not the broadband source's nominal 550 nm. With the meter
    set to the filter's centre (as the engine sets it) the reading is the true power; set
    to 550 nm it is off by the responsivity ratio R(450)/R(550)."""
    from hw_mocks import usb
    from hw_mocks.firmware.pm100usb import silicon_responsivity_a_per_w as resp

    with open_bench(load_profile("sim-spectral"),
                    roles=["shutter", "filter_wheel", "power_meter", "source",
                           "sample_theta", "detector_theta"]) as bench:
        bench.filter_wheel.move_to(1)
        bench.source.turn_on()
        bench.shutter.turn_on()
        firmware = usb.get_firmware("power_meter")
        firmware.dark_current_a = firmware.noise_floor_a = 0.0  # the light alone
        assert firmware._light_wavelength() == pytest.approx(450.0)
        truth = firmware.true_power_w()
        assert truth > 0
        bench.power_meter.wavelength_nm = 450.0
        assert bench.power_meter.read_power_w() == pytest.approx(truth, rel=0.02)
        bench.power_meter.wavelength_nm = 550.0
        assert bench.power_meter.read_power_w() == pytest.approx(
            truth * resp(450.0) / resp(550.0), rel=0.02)
        bench.shutter.turn_off()


def test_a_resumed_run_keeps_each_point_s_planned_filter(tmp_path):
    """The filter slot is part of a planned point (its meta): the run file stores it with
    the planned points, so ``resume`` (which continues the stored plan, not a rebuilt one)
    puts the same filter in the beam for every remaining point."""
    from types import SimpleNamespace

    from instrument.plans import build_plan, parse_plan
    from instrument.run.runner import plan_from_run

    plan = tmp_path / "plan.toml"
    plan.write_text(LOCKIN_PLAN.replace('detectors = ["lockin"]',
                                        'detectors = ["power_meter"]')
                    + '[spectral]\nfilters = [1, 2]\norder = "motion"\n', encoding="utf-8")
    profile = load_profile("sim-spectral")
    built = build_plan(parse_plan(plan.read_text(encoding="utf-8"), source="plan"), profile)
    assert main(["run", str(plan), "--bench", "sim-spectral", "--out", str(tmp_path / "runs"),
                 "--no-fsync", "--quiet"]) == 0
    (path,) = (tmp_path / "runs").glob("*.h5")
    again = plan_from_run(path, SimpleNamespace(profile=profile))
    assert [dict(p.meta).get("filter") for p in again.points] == \
        [dict(p.meta).get("filter") for p in built.points] == [1, 1, 1, 2, 2, 2]
