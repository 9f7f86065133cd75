"""Duration estimates of this bench: the emulated stages' speed-up from their URLs, the
camera's costs from the profile, and what a plan's estimate makes of them (issue 12 §6)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from instrument.bench.profile import DeviceSpec, ProfileError, load_profile, parse_profile
from instrument.bench.timing import (
    POINT_OVERHEAD_S,
    bench_timing,
    clock_speed,
    exposes_in_wall_time,
)
from instrument.plans import build_plan, load_plan, parse_plan

ROOT = Path(__file__).resolve().parents[3]


def spec(url: str, driver: str = "thorlabs_apt") -> DeviceSpec:
    return DeviceSpec("sample_theta", driver, url)


@pytest.mark.parametrize(("url", "speed"), [
    ("simapt://sample_theta?model=K10CR1&speed=20", 20.0),
    ("simsmc://camera_z?kind=linear&speed=50", 50.0),
    ("simsmc://detector_theta?kind=rotary", 1.0),        # the emulator's default: real time
    ("simzaber://x?device=1&speed=100", 100.0),           # any emulated controller
    ("simapt://x?step=0.001", 1e9),                        # clock steps per reading
    ("simapt://x?speed=-3", 1.0),                          # nonsense is not a speed-up
    ("simapt://x?speed=fast", 1.0),
    ("/dev/ttyUSB0", 1.0),                                 # real hardware runs in real time
    ("loop://?speed=20", 1.0),                             # not an emulated controller
])
def test_the_speed_up_is_what_the_url_of_an_emulated_controller_says(url, speed):
    assert clock_speed(spec(url)) == speed


def test_a_simulated_camera_exposes_in_wall_time_only_when_its_url_says_so():
    assert not exposes_in_wall_time(spec("simcam://camera?world=sim", "sim_camera"))
    assert exposes_in_wall_time(spec("simcam://camera?realtime=1", "sim_camera"))
    assert exposes_in_wall_time(spec("/dev/video0", "opencv_camera"))


def test_camera_timing_keys_are_validated_per_field():
    base = ('[bench]\nname = "t"\n[devices.camera]\ndriver = "{driver}"\nurl = "x"\n'
            '{key} = {value}\n')
    ok = parse_profile(base.format(driver="sim_camera", key="scene_change_s", value=2.5))
    assert ok.devices["camera"].scene_change_s == 2.5
    for driver, key, value, words in [
        ("sim_camera", "frame_overhead_s", -1, "frame_overhead_s"),
        ("sim_camera", "scene_change_s", '"slow"', "scene_change_s"),
        ("pm100usb", "frame_overhead_s", 0.1, "only cameras take 'frame_overhead_s'"),
    ]:
        with pytest.raises(ProfileError) as exc:
            parse_profile(base.format(driver=driver, key=key, value=value))
        assert words in str(exc.value) and f"devices.camera.{key}" in str(exc.value)


def test_motion_on_an_emulated_bench_takes_the_real_time_divided_by_its_speed_up():
    profile = load_profile("sim-lightfield")  # camera_z at speed=50
    plan = build_plan(load_plan(ROOT / "examples" / "lightfield_scan.toml"), profile)
    est = plan.estimate()
    assert est.speedup == pytest.approx(50.0, rel=1e-12)
    assert est.bench_motion_s * 50.0 == pytest.approx(est.motion_s, rel=1e-12)
    assert est.total_s == pytest.approx(est.bench_motion_s + est.bench_acquisition_s)
    # the same bench run in real time: the estimate is the real motion
    real = replace(profile, devices={
        r: replace(d, url=d.url.replace("speed=50", "speed=1")) for r, d in
        profile.devices.items()})
    assert build_plan(plan.spec, real).estimate().bench_motion_s == pytest.approx(
        est.motion_s, rel=1e-12)


def test_acquisition_counts_frames_scene_changes_and_storage():
    profile = load_profile("sim-spheres")
    timing = bench_timing(profile)
    plan = build_plan(load_plan(ROOT / "examples" / "sphere_capture.toml"), profile)
    pol = plan.spec.acquisition
    assert pol.mode == "auto" and pol.hdr and pol.dark == "per_point"
    brackets = (pol.max_brackets + 1) / 2
    n = len(plan.points)  # four lit points, each after a move
    expected = n * (2 * brackets * timing.frame_overhead_s + timing.scene_change_s
                    + POINT_OVERHEAD_S)
    assert plan.estimate().bench_acquisition_s == pytest.approx(expected, rel=1e-12)
    # a fixed exposure, no darks: one frame per point, and a camera exposing in real time
    # adds the exposures
    fixed = replace(plan.spec, acquisition=replace(pol, mode="fixed", hdr=False, dark="none"))
    live = replace(profile, devices={**profile.devices, "camera": replace(
        profile.devices["camera"], url=profile.devices["camera"].url + "&realtime=1")})
    slow = build_plan(fixed, live).estimate().bench_acquisition_s
    quick = build_plan(fixed, profile).estimate().bench_acquisition_s
    assert slow - quick == pytest.approx(n * pol.exposure_us * 1e-6, rel=1e-9)


def test_light_switches_without_moves_count_as_scene_changes():
    """Dark frames at the start, then the lit points at the same position: the light
    coming on is one change of the scene, the lit points after it none."""
    # the example takes a dark per point; here only the flat field's own dark points
    text = (ROOT / "examples" / "calibration_flat.toml").read_text().replace(
        'dark = "per_point"', 'dark = "none"')
    profile = load_profile("sim")
    plan = build_plan(parse_plan(text), profile)
    timing = bench_timing(profile, plan.axes)
    lit = sum(p.light for p in plan.points)
    frames = sum(plan.spec.acquisition.frames for _ in plan.points)
    est = plan.estimate()
    assert lit >= 1 and est.bench_motion_s == 0
    assert est.bench_acquisition_s == pytest.approx(
        frames * timing.frame_overhead_s + timing.scene_change_s
        + len(plan.points) * POINT_OVERHEAD_S, rel=1e-12)


def test_homing_is_estimated_per_axis_and_added_only_for_axes_not_homed(tmp_path):
    from instrument.run.events import RunStarted
    from instrument.run.runner import start_run
    from tests.instrument.helpers import IDEAL_PROFILE, ideal_bench, inplane_plan

    profile = load_profile("sim")
    plan = build_plan(load_plan(ROOT / "examples" / "brdf_inplane.toml"), profile)
    est = plan.estimate()
    speed = {r: clock_speed(profile.devices[r]) for r in plan.axes}
    assert est.homing_s == pytest.approx({r: profile.devices[r].home_s / speed[r]
                                          for r in plan.axes})
    # the ideal bench's axes are always homed: the run's first estimate has no homing in it
    text = IDEAL_PROFILE.replace('on_failure = "pause"', 'on_failure = "pause"\n'
                                 ).replace("acceleration = 10.0\n",
                                           "acceleration = 10.0\nhome_s = 30.0\n", 1)
    bench = ideal_bench(text)
    ideal = build_plan(parse_plan(inplane_plan()), bench.profile)
    assert sum(ideal.estimate().homing_s.values()) == 30.0
    engine = start_run(ideal, bench, runs_dir=tmp_path, fsync=False, catalog=False)
    started = []
    engine.subscribe(lambda ev: started.append(ev) if isinstance(ev, RunStarted) else None)
    engine.run()
    assert started[0].estimated_s == pytest.approx(ideal.estimate().total_s)


def test_a_run_on_freshly_powered_emulated_stages_counts_their_homing(tmp_path):
    from drivers.transport import add_url_handler_package
    from instrument.bench.devices import open_bench
    from instrument.run.events import RunStarted
    from instrument.run.runner import start_run

    add_url_handler_package("hw_mocks.urlhandler")
    profile = load_profile("sim-lightfield")
    plan = build_plan(parse_plan(
        '[plan]\nkind = "lightfield"\nname = "two rows"\n[sample]\nname = "wall"\n'
        '[scan]\ncamera_z = [0.0, 1.0]\n'
        '[acquisition]\nmode = "fixed"\nexposure_us = 5000\ndetectors = ["camera"]\n'),
        profile)
    est = plan.estimate()
    assert est.homing_s["camera_z"] > 0
    with open_bench(profile) as bench:
        engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False, catalog=False)
        started = []
        engine.subscribe(lambda ev: started.append(ev) if isinstance(ev, RunStarted) else None)
        engine.run()
    assert started[0].estimated_s == pytest.approx(est.total_s + est.homing_s["camera_z"])


def _no_camera_costs(text: str) -> str:
    return "\n".join(line for line in text.splitlines()
                     if not line.startswith(("frame_overhead_s", "scene_change_s")))


def test_a_camera_without_cost_keys_takes_its_driver_default_and_says_so():
    """A profile without the camera's costs used to count them as zero (1.8 s estimated
    for a 272 s scan): the simulated camera's measured defaults are assumed, and named."""
    full = load_profile("sim")
    bare = parse_profile(_no_camera_costs(full.source_text), source="bare")
    t_full, t_bare = bench_timing(full), bench_timing(bare)
    assert t_full.assumed == ()
    assert t_bare.frame_overhead_s == pytest.approx(t_full.frame_overhead_s)
    assert t_bare.scene_change_s == pytest.approx(t_full.scene_change_s)
    assert len(t_bare.assumed) == 2 and "camera.frame_overhead_s" in t_bare.assumed[0]
    plan = load_plan(ROOT / "examples" / "brdf_inplane.toml")
    est_full = build_plan(plan, full).estimate()
    est_bare = build_plan(plan, bare).estimate()
    assert est_bare.total_s == pytest.approx(est_full.total_s)
    assert est_bare.assumed == t_bare.assumed




def _lockin_estimate(dark: str = "none", filters: str = "[1]"):
    from tests.instrument.bench.test_spectral_bench import LOCKIN_PLAN

    text = (LOCKIN_PLAN.replace('dark = "none"', f'dark = "{dark}"')
            + f"[spectral]\nfilters = {filters}\n")
    spec_ = parse_plan(text, source="plan")
    return build_plan(spec_, load_profile("sim-spectral")).estimate()


def test_lock_in_settling_and_filter_turns_are_in_the_estimate():
    timing = bench_timing(load_profile("sim-spectral"))
    # 30 ms at the SR830's power-up 12 dB/oct: 7 τ per wait; 4 snapshots and 2 to range
    assert timing.lockin_settle_s == pytest.approx(7 * 0.03)
    reading = timing.lockin_reading_s(4)
    assert reading == pytest.approx(6 * 0.21)
    one = _lockin_estimate()
    assert one.bench_acquisition_s >= 3 * reading
    # with per-point darks every point is read twice, and the emulated photodiode
    # integrates each point's dark pose once (tests/instrument/bench/test_estimate_events.py)
    dark = _lockin_estimate("per_point")
    assert dark.bench_acquisition_s - one.bench_acquisition_s == pytest.approx(
        3 * reading + 3 * timing.lockin_integral_s[1])
    # the wheel: 1 → 3 on a six-slot wheel is 120° at 3 s per half turn, + 0.1 s to settle
    assert timing.wheel_move_s(1, 3) == pytest.approx(2.1)
    assert timing.wheel_move_s(1, 6) == pytest.approx(1.1)  # the shorter way round
    assert timing.wheel_move_s(2, 2) == 0.0
    two = _lockin_estimate(filters="[1, 3]")
    assert two.bench_acquisition_s - 2 * one.bench_acquisition_s == pytest.approx(2.1, abs=0.01)


ND_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "nd turns"
[sample]
name = "s"
[scan]
skip_beam_points = true
theta_i = [20, 50]
theta_r = [-40, 0, 30, 60]
{specular}
[acquisition]
exposure_us = 2000
frames = 2
detectors = {detectors}
"""


def test_neutral_density_turns_near_the_peak_are_in_the_estimate():
    """The sim bench's wheel holds ND1–3 beside an open slot: a camera plan crossing the
    specular direction counts, per run of points near it, a turn to ND1 and back at the
    emulated wheel's speed-up (speed=20) and the point read again; never zero."""
    profile = load_profile("sim")
    timing = bench_timing(profile)
    assert timing.wheel_speed == 20.0
    turn = timing.wheel_move_s(1, 2)  # open slot 1 → ND1 in slot 2: 60°, 1 s + 0.1 s
    assert turn == pytest.approx(1.1 / 20)
    spec = ND_PLAN.format(specular="specular = { half_width_deg = 2, step_deg = 2 }",
                          detectors='["camera"]')
    plan = build_plan(parse_plan(spec), profile)
    est = plan.estimate()
    note = next(a for a in est.predicted if a.startswith("ND filters"))
    # θi = 20° and 50°: the peaks at θr = 20° ± 2° and 50° ± 2°, one run of points each
    assert "2 peak(s) within 2° of specular" in note and "4 wheel turns" in note
    pol = plan.spec.acquisition
    reread = pol.frames * (pol.min_exposure_us * 1e-6 * timing.exposure_factor
                           + timing.frame_overhead_s)
    wanted = 2 * (2 * turn + reread + timing.scene_change_s)
    without = replace(profile, devices={k: v for k, v in profile.devices.items()
                                         if k != "filter_wheel"})
    bare = build_plan(parse_plan(spec), without).estimate()
    assert est.bench_acquisition_s - bare.bench_acquisition_s == pytest.approx(wanted)
    assert not any(a.startswith("ND filters") for a in bare.predicted)
    # no specular window in the plan: points within 5° of the mirror direction; here
    # only the grid's θr = 60° (10° from θi = 50°) is not, and none is within 5°
    none = build_plan(parse_plan(ND_PLAN.format(specular="", detectors='["camera"]')),
                      profile).estimate()
    assert not any(a.startswith("ND filters") for a in none.predicted)
    # only the camera clips: a power-meter plan turns no filter
    pm = build_plan(parse_plan(spec.replace('["camera"]', '["power_meter"]')),
                    profile).estimate()
    assert not any(a.startswith("ND filters") for a in pm.predicted)
