"""The lock-in, shutter and filter-wheel kinds without Qt: the real SR830, SC10 and FW102C
drivers over their emulators' URL handlers, owned by the session's device worker; what the
GUI reads of them, how it words it, and what the worker refuses."""

from __future__ import annotations

import pytest

from drivers.base import FilterWheel, LightSource, LockIn, Shutter
from drivers.stanford_sr830 import Sr830LockIn
from drivers.thorlabs_fw102c import Fw102cWheel
from drivers.thorlabs_sc10 import Sc10Shutter
from drivers.transport import add_url_handler_package
from gui.model import readouts
from gui.model.filters import bands_from_info, slot_label
from gui.model.session import (
    Action,
    BenchSession,
    Connect,
    Home,
    MoveTo,
    SetLight,
    SetSetting,
)
from hw_mocks import registry
from instrument.bench.device_state import kind_of
from instrument.bench.devices import Bench
from tests.gui.helpers import Recorder, fast_profile
from tests.waiting import wait_for

FILTERS = {2: {"center_nm": 550.0, "bandwidth_nm": 10.0, "label": "green"}}


@pytest.fixture
def optics():
    """A session whose bench is an SR830, an FW102C and an SC10 built directly (no axes)."""
    add_url_handler_package("hw_mocks.urlhandler")
    devices = {
        "lockin": Sr830LockIn("simsr830://gui_lockin?seed=3", name="lockin"),
        "wheel": Fw102cWheel("simfw102c://gui_wheel?slots=6&speed=50", name="wheel",
                             filters=FILTERS),
        "shutter": Sc10Shutter("simsc10://gui_shutter", name="shutter"),
    }
    profile = fast_profile("sim")
    rec = Recorder()
    s = BenchSession(rec, opener=lambda p: Bench(p, dict(devices)), fsync=False)
    s.submit(Connect(profile))
    wait_for(lambda: s.connected and set(s.states()) == set(devices), 60, "connection")
    yield s, rec, devices
    assert s.close(20)


def _last(rec, kind):
    return rec.results_of(kind)[-1]


def test_each_device_gets_its_kind_from_its_abc(optics):
    s, _, devices = optics
    assert isinstance(devices["shutter"], LightSource)  # and yet shown as a shutter
    assert {role: kind_of(d).name for role, d in devices.items()} == {
        "lockin": "lockin", "wheel": "filter_wheel", "shutter": "shutter"}
    states = s.states()
    assert states["lockin"].info["identity"]["model"] == "SR830"
    assert states["lockin"].info["sensitivities_v"][0] == pytest.approx(2e-9)
    assert states["wheel"].info["count"] == 6
    assert states["wheel"].value("position") == 1
    assert states["shutter"].value("state") == "closed"


def test_a_lock_in_setting_the_driver_rejects_is_reported_with_its_words(optics):
    s, rec, devices = optics
    s.submit(SetSetting("lockin", "time_constant_s", 1e6))
    assert s.wait_idle(60)
    r = _last(rec, SetSetting)
    assert not r.ok and "outside the instrument's" in r.message and "lockin" in r.message
    assert devices["lockin"].time_constant_s == pytest.approx(0.1)  # unchanged
    s.submit(SetSetting("lockin", "time_constant_s", 0.3))
    wait_for(lambda: s.states()["lockin"].value("time_constant_s") == pytest.approx(0.3), 60)
    assert _last(rec, SetSetting).ok


def test_lock_in_flags_mean_what_the_panel_says(optics):
    s, _, _ = optics
    # No chopper at REF IN: the external reference cannot lock; the smallest range
    # overloads on the input noise alone.
    s.submit(SetSetting("lockin", "reference_source", "external"))
    s.submit(SetSetting("lockin", "sensitivity_v", 2e-9))
    wait_for(lambda: s.states()["lockin"].value("sensitivity_v") == pytest.approx(2e-9)
             and s.states()["lockin"].value("output_overload"), 60, "an overload")
    wait_for(lambda: s.states()["lockin"].value("reference_unlocked"), 60, "unlocked")
    faults = readouts.lockin_faults(s.states()["lockin"].values)
    badges = [f.badge for f in faults]
    assert "OVERLOAD" in badges and "UNLOCKED" in badges
    assert any("Auto-range" in f.advice for f in faults)
    assert "reference external" in readouts.lockin_detail(s.states()["lockin"].values)


def test_the_wheel_moves_changes_speed_and_refuses_a_slot_it_does_not_have(optics):
    s, rec, devices = optics
    s.submit(Action("wheel", "move_to", (2,)))
    wait_for(lambda: s.states()["wheel"].value("position") == 2, 60, "slot 2")
    assert registry.get("simfw102c", "gui_wheel") is not None
    state = s.states()["wheel"]
    bands = bands_from_info(state.info["filters"])
    assert slot_label(bands, state.value("position")) == "slot 2: 550 nm, FWHM 10 nm (green)"
    s.submit(Action("wheel", "move_to", (7,)))
    assert s.wait_idle(60)
    r = _last(rec, Action)
    assert not r.ok and "slot 7 does not exist" in r.message
    assert devices["wheel"].position == 2
    s.submit(SetSetting("wheel", "speed", "normal"))
    wait_for(lambda: s.states()["wheel"].value("speed") == "normal", 60)
    s.submit(SetSetting("wheel", "speed", "warp"))
    assert s.wait_idle(60)
    assert "'normal' or 'high'" in _last(rec, SetSetting).message


def test_the_shutter_opens_and_closes_as_a_light_source(optics):
    s, _, devices = optics
    s.submit(SetLight(True, "shutter"))
    wait_for(lambda: s.states()["shutter"].value("state") == "open", 60, "open")
    assert readouts.shutter_open(s.states()["shutter"].values) is True
    s.submit(SetLight(False, "shutter"))
    wait_for(lambda: s.states()["shutter"].value("state") == "closed", 60, "closed")
    assert devices["shutter"].is_on is False


@pytest.fixture
def spectral():
    rec = Recorder()
    s = BenchSession(rec, fsync=False)
    s.submit(Connect(fast_profile("sim-spectral")))
    wait_for(lambda: s.connected and rec.state_updates > 0, 60, "connection")
    yield s, rec
    assert s.close(20)


def test_on_the_spectral_bench_the_guard_keeps_the_shutter_shut_and_the_worker_free(spectral):
    s, rec = spectral
    devices = s._bench.devices
    assert isinstance(devices["lockin"], LockIn) and isinstance(devices["shutter"], Shutter)
    assert isinstance(devices["filter_wheel"], FilterWheel)
    s.submit(Home("detector_theta"))
    s.submit(Home("sample_theta"))
    wait_for(lambda: all(s.states()[r].value("homed") and not s.states()[r].value("moving")
                         for r in ("detector_theta", "sample_theta")), 60, "homed")
    # the detector arm at home stands in the incident beam: opening is refused
    s.submit(SetLight(True, "shutter"))
    assert s.wait_idle(60)
    r = _last(rec, SetLight)
    assert r.refused and "beam" in r.message and r.message.startswith("shutter")
    assert devices["shutter"].shutter_state.value == "closed"
    # a wheel move holds the worker: refused while an axis moves, done once it is at rest
    s.submit(SetSetting("detector_theta", "velocity", 1.0))
    s.submit(MoveTo("detector_theta", 60.0))
    s.submit(Action("filter_wheel", "move_to", (3,)))
    assert s.wait_idle(60)
    r = _last(rec, Action)
    assert r.refused and "at rest" in r.message
    assert devices["filter_wheel"].position != 3
