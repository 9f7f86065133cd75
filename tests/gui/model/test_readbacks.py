"""What the bench dock is told, without Qt: the run's read-backs and homes, exact jogs,
the age of a reading, the plan form's words."""

from __future__ import annotations

import pytest

from drivers.base import exposure_text
from gui.model.format import STALE_AFTER_S, age
from gui.model.logbook import from_event
from gui.model.planform import LOBE_MODELS, PlanForm, fields_for
from gui.model.session import Home, Jog, MoveTo, StartRun
from instrument.plans import build_plan, parse_plan
from instrument.plans.planfile import KINDS
from instrument.run.events import AxisHomed
from instrument.run.runfile import read_events
from tests.gui.helpers import fast_profile
from tests.gui.model import test_session
from tests.waiting import wait_for

session = test_session.session  # the fixture: a session on its own device worker
_connect = test_session._connect

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "read-backs"
[sample]
name = "s"
[scan]
theta_i = [20.0]
theta_r = { start = 30.0, stop = 60.0, step = 10.0 }
[acquisition]
mode = "fixed"
exposure_us = 1000
detectors = ["power_meter"]
"""


def _at_rest(s, role, where):
    st = s.states()[role]
    return not st.value("moving") and abs(st.value("position") - where) < 0.01


def test_the_run_homes_the_axes_and_the_session_reports_its_read_backs(session, tmp_path):
    s, rec = session
    profile = fast_profile()
    _connect(s, rec, profile)
    assert not s.states()["detector_theta"].value("homed")
    plan = build_plan(parse_plan(PLAN), profile)
    homes: list[AxisHomed] = []
    s.submit(StartRun(plan, tmp_path))
    wait_for(lambda: s.run is not None, 60, "run")
    run = s.run
    run.engine.subscribe(lambda ev: homes.append(ev) if isinstance(ev, AxisHomed) else None)
    started = run.engine.snapshot().elapsed_s
    assert started >= 0
    wait_for(lambda: s.run is None, 60, "run end")
    assert run.finished.status == "finished"
    # while the engine owned the bench, the session passed on its status reads
    readbacks = run.engine.axis_readbacks()
    assert set(plan.axes) <= set(readbacks)
    last, _t = readbacks["detector_theta"]
    assert last.is_homed and not last.is_moving
    assert last.position == pytest.approx(dict(plan.points[-1].targets)["detector_theta"],
                                          abs=0.01)
    # the homes are events (the GUI's log) and lines of the run file's log
    homed_roles = {e.device for e in homes} | {
        e["device"] for e in read_events(run.path) if e["kind"] == "homed"}
    assert {"sample_theta", "detector_theta"} <= homed_roles
    line = from_event(AxisHomed("detector_theta", 0.0, 1.5))
    assert line.level == "info" and line.source == "engine/detector_theta"
    assert "homed by the run" in line.message and "1.5 s" in line.message


def test_states_during_a_run_come_from_the_engine(session, tmp_path):
    s, rec = session
    profile = fast_profile()
    _connect(s, rec, profile)
    plan = build_plan(parse_plan(PLAN), profile)
    seen: list = []
    s.submit(StartRun(plan, tmp_path))
    wait_for(lambda: s.run is not None, 60, "run")
    run = s.run
    run.engine.pause()
    wait_for(lambda: run.engine.state.value == "paused" or s.run is None, 60, "pause")
    wait_for(lambda: s.states()["detector_theta"].value("homed"), 60, "homed state")
    st = s.states()["detector_theta"]
    status, t = run.engine.axis_readbacks()["detector_theta"]
    wait_for(lambda: s.states()["detector_theta"].t == t, 60, "the newest read-back")
    st = s.states()["detector_theta"]
    seen.append(st)
    assert st.value("position") == status.position and st.value("homed")
    assert st.info.get("velocity") is not None  # the info from before the run is kept
    run.engine.abort()
    wait_for(lambda: s.run is None, 60, "run end")


def test_jogs_add_to_the_target_not_to_the_read_back(session):
    s, rec = session
    _connect(s, rec, fast_profile())
    s.submit(Home("sample_theta"))
    wait_for(lambda: s.states()["sample_theta"].value("homed")
             and not s.states()["sample_theta"].value("moving"), 20, "homed")
    s.submit(MoveTo("sample_theta", 1.0))
    wait_for(lambda: _at_rest(s, "sample_theta", 1.0), 60, "at 1")
    for k in range(3):
        s.submit(Jog("sample_theta", 1.0))
        assert s.wait_idle()
        wait_for(lambda k=k: _at_rest(s, "sample_theta", 2.0 + k), 60, f"at {2 + k}")
    # exactly: the K10CR1's read-back of 1° is 0.9995° (its encoder steps), and three
    # jogs from the read-back ended at 3.9985°
    assert s.states()["sample_theta"].value("target") == 4.0


def test_age_is_shown_only_when_old():
    assert age(0.3) == ""
    assert age(STALE_AFTER_S - 0.01) == ""
    assert age(12.0) == "read 12 s ago"
    assert age(125.0) == "read 2 min 05 s ago"
    assert age(float("nan")) == "not read"


@pytest.mark.parametrize(("us", "text"), [(99999999.0, "100 s"), (1e7, "10 s"),
                                          (2500.0, "2.5 ms"), (10.0, "10 µs")])
def test_exposures_are_written_in_operator_units(us, text):
    assert exposure_text(us) == text


@pytest.mark.parametrize("kind", KINDS)
def test_every_field_says_what_it_means(kind):
    for spec in fields_for(kind):
        assert spec.help and spec.help != spec.path, spec.path


def test_the_lobe_model_is_a_list_with_automatic_first():
    spec = next(f for f in fields_for("brdf_in_plane") if f.path == "scan.lobe.prior")
    assert spec.kind == "choice" and spec.choices == LOBE_MODELS
    assert LOBE_MODELS[0] == "" and "lambert+ggx" in LOBE_MODELS and "ggx" in LOBE_MODELS
    form = PlanForm("brdf_in_plane")
    form.set("scan.lobe.points", "10")
    form.set("scan.lobe.prior", "")
    assert "prior" not in form.to_toml()
    form.set("scan.lobe.prior", "lambert+ggx")
    assert 'prior = "lambert+ggx"' in form.to_toml()


def test_an_empty_sample_is_said_in_the_forms_words():
    form = PlanForm("brdf_in_plane")
    form.set("sample.name", "")
    result = form.validate(None)
    messages = result.errors.get("sample.name", [])
    assert messages and all("table" not in m for m in messages)
    assert "required" in messages[0]


def test_built_in_profiles_have_one_naming_and_old_names_still_load():
    from instrument.bench.profile import builtin_profiles, load_profile, same_bench

    names = builtin_profiles()
    assert all("_" not in n for n in names) and "sim-out-of-plane" in names
    old = load_profile("sim_out_of_plane")  # run files and scripts name it so
    assert old.name == "sim-out-of-plane"
    assert same_bench("sim_out_of_plane", old.name) and not same_bench("sim", old.name)
