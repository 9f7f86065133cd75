"""The sample spinner: a plan that asks for spinning runs with the sample turning (the
engine starts the spinner after homing and checks it is at speed) and leaves it stopped
at the end and on a fault; a bench without a spinner refuses such a plan before anything
moves."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from drivers.errors import MotionError
from hw_mocks import registry
from hw_mocks.sim.world import get_world
from instrument.bench.devices import open_bench
from instrument.bench.profile import load_profile, parse_profile
from instrument.cli import main
from instrument.plans import build_plan, parse_plan
from instrument.plans.planfile import PlanError
from instrument.run.runfile import read_events, read_run
from instrument.run.spinner import start_spinner

ROOT = Path(__file__).resolve().parents[3]
SPINNER = """
[devices.sample_spin]
driver = "thorlabs_apt"
url = "simapt://sample_spin?model=K10CR1&speed=20"
stage = "K10CR1"
limits = [-360.0, 360.0]
velocity = 10.0
acceleration = 10.0

[source]
coherence = "laser"
"""

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "spun"
[sample]
name = "sim"
[scan]
theta_i = [40.0]
theta_r = [0.0, 20.0]
[acquisition]
mode = "fixed"
exposure_us = 2000
dark = "none"
detectors = ["camera"]
spin_deg_s = 8.0
"""


def spinning_bench(tmp_path: Path) -> Path:
    text = (ROOT / "instrument" / "bench" / "profiles" / "sim.toml").read_text("utf-8")
    text = text.replace("simcam://camera?world=sim&seed=1",
                        "simcam://camera?world=sim&seed=1&width=96&height=96")
    path = tmp_path / "spin.toml"
    path.write_text(text + SPINNER, encoding="utf-8")
    return path


@pytest.mark.slow
def test_plan_spins_the_sample_and_the_run_leaves_it_stopped(tmp_path: Path) -> None:
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN, encoding="utf-8")
    out = tmp_path / "out"
    assert main(["run", str(plan), "--bench", str(spinning_bench(tmp_path)), "--out",
                 str(out), "--no-fsync", "--quiet"]) == 0
    (path,) = out.glob("*.h5")
    events = [e for e in read_events(path) if e.get("kind") == "spinning"]
    assert events and events[0]["deg_per_s"] == 8.0
    assert read_run(path).acquisition["spin_deg_s"] == 8.0
    emulator = registry.get("simapt", "sample_spin")
    with emulator.lock:
        assert not emulator.stage.is_moving()


def test_spinner_at_speed_then_stopped_by_make_safe(tmp_path: Path) -> None:
    profile = load_profile(spinning_bench(tmp_path))
    with open_bench(profile, roles=["sample_spin"]) as bench:
        emulator = registry.get("simapt", "sample_spin")
        with emulator.clock.held() as clock:
            # the ramp (0.8 s of emulated time) passes while the engine waits it out
            start_spinner(bench.devices, 8.0, sleep=clock.advance)
            assert emulator.stage.velocity_now() == pytest.approx(8.0, rel=1e-12)
            assert get_world("sim").spin()[1] == pytest.approx(8.0, rel=1e-12)
            assert bench.make_safe() == []
            clock.advance(2.0)
            assert not emulator.stage.is_moving()


def test_too_fast_for_the_stage_is_a_typed_error_and_nothing_turns(tmp_path: Path) -> None:
    profile = load_profile(spinning_bench(tmp_path))
    with open_bench(profile, roles=["sample_spin"]) as bench:
        with pytest.raises(MotionError, match="10") as err:  # a K10CR1: 10 °/s at most
            start_spinner(bench.devices, 30.0)
        assert err.value.device == "sample_spin"
        emulator = registry.get("simapt", "sample_spin")
        with emulator.lock:
            assert not emulator.stage.is_moving()


def test_no_spinner_device_is_a_motion_error() -> None:
    with pytest.raises(MotionError, match="cannot turn continuously"):
        start_spinner({}, 5.0)


def test_plan_asking_to_spin_on_a_bench_without_spinner_is_refused() -> None:
    with pytest.raises(PlanError) as err:
        build_plan(parse_plan(PLAN), load_profile("sim"))
    assert any(e.path == "acquisition.spin_deg_s" and "sample_spin" in e.message
               for e in err.value.errors)


def test_spin_rate_is_validated_and_stored() -> None:
    with pytest.raises(PlanError) as err:
        parse_plan(PLAN.replace("spin_deg_s = 8.0", "spin_deg_s = -1.0"))
    assert any(e.path == "acquisition.spin_deg_s" for e in err.value.errors)
    spec = parse_plan(PLAN)
    assert json.loads(spec.acquisition.as_json())["spin_deg_s"] == 8.0


def test_spinner_role_accepted_by_the_profile(tmp_path: Path) -> None:
    profile = parse_profile(spinning_bench(tmp_path).read_text("utf-8"))
    assert "sample_spin" in profile.axes and profile.coherence == "laser"


def test_spinning_with_hdr_brackets_is_refused() -> None:
    # each bracket would see other patterns: the per-pixel merge would bias the value low
    with pytest.raises(PlanError) as err:
        parse_plan(PLAN.replace('mode = "fixed"', 'mode = "auto"\nhdr = true'))
    assert any(e.path == "acquisition.spin_deg_s" and "hdr = false" in e.message
               for e in err.value.errors)


def test_a_pause_stops_the_spinner_and_resume_spins_it_up_before_the_next_exposure(
        tmp_path: Path) -> None:
    """A pause is for a person at the bench: the sample stands still with every axis. On
    resume the spinner is back at speed before the next frame is exposed (the reduction's
    σ assume it turns through every exposure). The spinner's emulated clock is held: its
    ramps pass only as the engine waits them out, and its stop as the test advances it."""
    import threading

    from instrument.run.events import Paused
    from instrument.run.runner import start_run

    profile = load_profile(spinning_bench(tmp_path))
    plan = build_plan(parse_plan(PLAN), profile)
    with open_bench(profile) as bench:
        spinner = registry.get("simapt", "sample_spin")
        assert registry.get("simapt", "sample_theta").clock is not spinner.clock
        with spinner.clock.held() as clock:
            engine = start_run(plan, bench, runs_dir=tmp_path / "runs", fsync=False,
                               catalog=False, wait=clock.advance)
            rates: dict[int, float] = {}
            paused = threading.Event()
            while_paused: list[tuple[bool, float]] = []

            def on(ev: object) -> None:
                if getattr(ev, "index", None) == 0 and type(ev).__name__ == "PointCompleted":
                    engine.pause("door opened")
                if isinstance(ev, Paused):
                    clock.advance(5.0)  # its deceleration, in emulated time
                    with spinner.lock:
                        while_paused.append((spinner.stage.is_moving(),
                                             get_world("sim").spin()[1]))
                    paused.set()

            engine.subscribe(on)
            engine.subscribe_frames(lambda i, _f: rates.setdefault(i, get_world("sim")
                                                                   .spin()[1]))
            engine.start()
            assert paused.wait(120)
            assert while_paused == [(False, 0.0)]
            engine.resume()
            engine.wait(120)
        assert rates == {0: pytest.approx(8.0, rel=1e-12), 1: pytest.approx(8.0, rel=1e-12)}
        kinds = [(e["kind"], e.get("index")) for e in read_events(engine.store.path)
                 if e["kind"] in ("spinning", "paused", "resumed")]
        assert kinds == [("spinning", None), ("paused", 1), ("resumed", 1), ("spinning", 1)]
