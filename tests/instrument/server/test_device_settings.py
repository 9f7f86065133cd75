"""Device settings from clients: ``POST /api/v1/bench/devices/{role}/settings`` on the app
in this process (the emulated sim bench), answered at once with a request id; the outcome
arrives as a ``device_settings`` event. Every wait is on an event the service publishes
(the hub's listener keeps them), with a generous limit (ADR 0020)."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import pytest
from fastapi.testclient import TestClient

from instrument.bench.profile import parse_profile
from instrument.protocol import API_PREFIX as P
from instrument.protocol import MESSAGE_TYPES
from instrument.run import events as ev
from instrument.server.app import create_app
from instrument.server.audit import AuditLog
from instrument.server.device_settings import SettingRefused, check_changes
from instrument.server.keys import KeyStore
from instrument.server.service import BenchService
from tests.instrument.server.helpers import fast_profile_text, plan_text
from tests.waiting import wait_for

HOLD_S = 120.0  # bound on a hang only


class HeldSettings(BenchService):
    """Holds the settings worker inside its next request, where the device command would
    run (a wheel move of seconds): :attr:`inside` is set there, and it goes on once
    :attr:`go_on` is set. With :attr:`hold_run`, holds a run on the engine's thread just
    after its start (announced), until :attr:`run_go` is set: a run that owns the bench
    however fast the machine is."""

    def __init__(self, *args, **kw) -> None:
        self.hold = False
        self.inside = threading.Event()
        self.go_on = threading.Event()
        self.hold_run = False
        self.run_held = threading.Event()
        self.run_go = threading.Event()
        super().__init__(*args, **kw)

    def _on_engine_event(self, event) -> None:
        super()._on_engine_event(event)
        if self.hold_run and isinstance(event, ev.RunStarted):
            self.run_held.set()
            if not self.run_go.wait(HOLD_S):
                raise AssertionError("the test never released the run")

    def _apply_one(self, req, device) -> None:
        if self.hold:
            self.inside.set()
            if not self.go_on.wait(HOLD_S):
                raise AssertionError("the test never released the settings worker")
        super()._apply_one(req, device)


@dataclass
class Server:
    service: HeldSettings
    http: TestClient
    tokens: dict[str, str]
    messages: list

    def post(self, path: str, who: str = "operator", **body):
        return self.http.post(P + path, json=body or None,
                              headers={"Authorization": f"Bearer {self.tokens[who]}"})

    def settings(self, role: str, who: str = "operator", **changes):
        return self.post(f"/bench/devices/{role}/settings", who, changes=changes)

    def events(self, request_id: int | None = None) -> list[dict]:
        return [m.data for m in list(self.messages) if m.type == "device_settings"
                and (request_id is None or m.data["request_id"] == request_id)]

    def ended(self, request_id: int) -> dict:
        wait_for(lambda: any(e["state"] != "applying" for e in self.events(request_id)),
                 HOLD_S, f"the end of request {request_id}")
        return self.events(request_id)[-1]

    def device(self, role: str) -> dict:
        """The device's state in the newest ``devices`` message."""
        for m in reversed(list(self.messages)):
            if m.type == "devices" and role in (m.data.get("states") or {}):
                return m.data["states"][role]
        raise AssertionError(f"no state of {role} published")


@pytest.fixture
def server(tmp_path):
    profile = parse_profile(fast_profile_text(), source="fast sim")
    service = HeldSettings(profile, tmp_path / "runs", fsync=False)
    messages: list = []
    service.hub.listen(messages.append)
    keys = KeyStore(service.db)
    tokens = {role: keys.add(f"{role}-1", role)[1] for role in ("observer", "operator")}
    with TestClient(create_app(service)) as http:
        s = Server(service, http, tokens, messages)
        # the sampler has read the wheel's and the meter's tables (slot count, range)
        wait_for(lambda: all(r in [k for m in list(messages) if m.type == "devices"
                                   for k, v in (m.data.get("states") or {}).items()
                                   if v.get("info")] for r in ("filter_wheel", "power_meter")),
                 HOLD_S, "the first device states")
        yield s
        service.go_on.set()
        service.run_go.set()


def test_a_wheel_move_is_answered_at_once_and_its_end_arrives_as_an_event(server):
    before = server.device("filter_wheel")["values"]["position"]
    target = 3 if before != 3 else 2
    r = server.settings("filter_wheel", position=target)
    assert r.status_code == 202, r.text
    rid = r.json()["request_id"]
    assert f"request {rid}" in r.json()["message"]
    end = server.ended(rid)
    states = [e["state"] for e in server.events(rid)]
    assert states == ["applying", "done"]
    assert end["who"] == "operator-1" and end["device"] == "filter_wheel"
    assert end["changes"] == {"position": target} and end["field"] is None
    assert end["device_state"]["values"]["position"] == target  # the device as it is now
    assert server.service.bench.filter_wheel.position == target
    # the request (accepted) and its end are both in the audit log
    def rows():
        return [(row.who, row.what, row.status) for row in AuditLog(server.service.db).rows()]

    # the end's audit row is written beside the done event, not before it: wait for it
    done = ("operator-1", f"device settings request {rid} (filter_wheel): done", 200)
    wait_for(lambda: done in rows(), what="the request's end in the audit log")
    assert ("operator-1", f"POST {P}/bench/devices/filter_wheel/settings", 202) in rows()
    # the sampler reads the device afresh: the next devices message shows the new slot
    wait_for(lambda: server.device("filter_wheel")["values"]["position"] == target, HOLD_S,
             "the wheel's new slot published")


def test_several_fields_are_applied_in_order_and_shown(server):
    r = server.settings("power_meter", wavelength_nm=532.0, averaging=4, auto_range=False)
    assert r.status_code == 202, r.text
    end = server.ended(r.json()["request_id"])
    assert end["state"] == "done", end
    pm = server.service.bench.power_meter
    assert (pm.wavelength_nm, pm.averaging, pm.auto_range) == (532.0, 4, False)
    assert end["device_state"]["values"]["wavelength_nm"] == 532.0


@pytest.mark.parametrize("role, changes, field, words", [
    ("filter_wheel", {"position": 9}, "filter_wheel.position", "slots 1 … 6"),
    ("filter_wheel", {"position": 2.5}, "filter_wheel.position", "integer"),
    ("filter_wheel", {"colour": "red"}, "filter_wheel.colour", "not a setting"),
    ("power_meter", {"wavelength_nm": 20.0}, "power_meter.wavelength_nm", "outside"),
    ("power_meter", {"zero": False}, "power_meter.zero", "send true"),
    ("power_meter", {"averaging": 0}, "power_meter.averaging", "at least 1"),
    ("sample_theta", {"velocity": 1.0}, "sample_theta", "no settings a client may change"),
    ("nothing", {"position": 1}, "nothing", "has no device 'nothing'"),
])
def test_a_bad_field_is_refused_naming_it_and_nothing_is_sent(server, role, changes, field,
                                                               words):
    wheel, pm = server.service.bench.filter_wheel, server.service.bench.power_meter
    before = (wheel.position, pm.wavelength_nm, pm.averaging)
    r = server.settings(role, **changes)
    assert r.status_code == 422, r.text
    assert words in r.json()["detail"] and r.json()["detail"].startswith(field)
    assert r.json()["reasons"] == [field]
    assert server.events() == []  # nothing accepted, nothing announced
    assert (wheel.position, pm.wavelength_nm, pm.averaging) == before


def test_an_empty_or_malformed_body_is_422(server):
    assert server.post("/bench/devices/filter_wheel/settings", changes={}).status_code == 422
    assert server.post("/bench/devices/filter_wheel/settings",
                       changes={"position": [1]}).status_code == 422
    assert server.events() == []


def test_an_observer_may_not_change_settings(server):
    assert server.settings("filter_wheel", "observer", position=2).status_code == 403
    assert server.events() == []


def test_refused_while_the_queue_runs_or_a_run_owns_the_bench(server):
    svc = server.service
    svc.hold_run = True
    assert server.post("/queue", plan=plan_text("long", [-60.0, -40.0, 10.0, 40.0, 60.0])
                       ).status_code == 200
    assert server.post("/queue/start").status_code == 200
    assert svc.run_held.wait(HOLD_S), "the run never started"
    r = server.settings("filter_wheel", position=2)
    assert r.status_code == 409, r.text
    assert r.json()["detail"].startswith("a run owns the bench")
    assert server.post("/run/pause").status_code == 200  # paused: it still owns the bench
    svc.run_go.set()
    wait_for(lambda: any(m.type == "paused" for m in list(server.messages)), HOLD_S,
             "the run to pause")
    r = server.settings("filter_wheel", position=2)
    assert r.status_code == 409 and r.json()["detail"].startswith("a run owns the bench")
    assert server.events() == []
    assert server.post("/run/resume").status_code == 200
    wait_for(lambda: any(m.type == "item_finished" for m in list(server.messages)), HOLD_S,
             "the run to end")
    wait_for(lambda: not svc.queue_running, HOLD_S, "the queue to stop")
    r = server.settings("filter_wheel", position=2)  # between runs: accepted again
    assert r.status_code == 202, r.text
    assert server.ended(r.json()["request_id"])["state"] == "done"


def test_refused_while_the_queue_runs_before_its_first_run_has_started(server):
    """Between *start queue* and the first run's start (here: the runner waits for a wheel
    move held in progress) no run owns the bench yet, but its next run may take it at any
    moment: a new setting is refused with 409, nothing is sent or announced."""
    svc = server.service
    svc.hold = True
    rid = server.settings("filter_wheel", position=3).json()["request_id"]
    assert svc.inside.wait(HOLD_S), "the worker never started the move"
    assert server.post("/queue", plan=plan_text("next", [-60.0, 40.0])).status_code == 200
    assert server.post("/queue/start").status_code == 200
    assert svc.queue_running and svc.engine is None  # the queue runs; no run yet
    r = server.settings("power_meter", wavelength_nm=800.0)
    assert r.status_code == 409, r.text
    assert r.json()["detail"].startswith("the queue is running")
    assert [e["request_id"] for e in server.events()] == [rid]  # the refused one: no event
    assert not any(m.type == "run_started" for m in list(server.messages))
    assert svc.bench.power_meter.wavelength_nm == 633.0  # never sent
    svc.hold = False
    svc.go_on.set()
    wait_for(lambda: any(m.type == "item_finished" for m in list(server.messages)), HOLD_S,
             "the run to end")
    assert server.events(rid)[-1]["state"] == "done"


def test_the_queue_waits_for_a_setting_in_progress(server):
    """A run never starts while a device is being set: the queue runner waits for it."""
    svc = server.service
    svc.hold = True
    rid = server.settings("filter_wheel", position=4).json()["request_id"]
    assert svc.inside.wait(HOLD_S)
    assert server.post("/queue", plan=plan_text("after", [-60.0, 40.0])).status_code == 200
    assert server.post("/queue/start").status_code == 200
    svc.hold = False
    svc.go_on.set()
    wait_for(lambda: any(m.type == "item_finished" for m in list(server.messages)), HOLD_S,
             "the run to end")
    kinds = [(m.type, m.data.get("state")) for m in list(server.messages)
             if m.type in ("device_settings", "run_started")]
    assert kinds == [("device_settings", "applying"), ("device_settings", "done"),
                     ("run_started", None)]
    assert server.events(rid)[-1]["state"] == "done"


def test_stop_all_does_not_wait_for_a_setting_in_progress_and_cancels_the_waiting_ones(
        server):
    svc = server.service
    svc.hold = True
    first = server.settings("filter_wheel", position=5).json()["request_id"]
    assert svc.inside.wait(HOLD_S), "the worker never started the move"
    second = server.settings("power_meter", wavelength_nm=800.0).json()["request_id"]
    # the wheel's move is in progress (held): Stop all answers now, without its end
    r = server.post("/bench/stop-all")
    assert r.status_code == 200, r.text
    assert f"filter_wheel finishes its setting in progress (request {first})" in \
        r.json()["message"]
    assert [e["state"] for e in server.events(first)] == ["applying"]
    assert [e["state"] for e in server.events(second)] == ["applying", "cancelled"]
    assert "cancelled by Stop all" in server.events(second)[-1]["message"]
    assert server.service.bench.power_meter.wavelength_nm == 633.0  # never sent
    svc.hold = False
    svc.go_on.set()
    assert server.ended(first)["state"] == "done"
    assert server.service.bench.filter_wheel.position == 5


def test_the_device_settings_event_is_in_the_schema_and_the_openapi_doc(server):
    t = MESSAGE_TYPES["device_settings"]
    assert t.lifecycle
    assert set(t.fields) == {"request_id", "who", "device", "kind", "changes", "state",
                             "message", "field", "device_state"}
    schema = server.http.get(P + "/events/schema", headers={
        "Authorization": f"Bearer {server.tokens['observer']}"}).json()
    assert "device_settings" in schema["types"]
    doc = server.http.get("/openapi.json").json()
    op = doc["paths"][f"{P}/bench/devices/{{role}}/settings"]["post"]
    assert "202" in op["responses"]


LOCKIN_INFO = {"sensitivities_v": [2e-9, 5e-9, 1e-3, 1.0],
               "time_constants_s": [1e-5, 0.1, 0.3, 1.0]}


@pytest.mark.parametrize("changes, expected", [
    ({"sensitivity_v": 1e-3}, [1e-3]),
    ({"time_constant_s": 0.3, "reference_source": "external"}, [0.3, "external"]),
    ({"auto_range": True}, [True]),
])
def test_lockin_fields_are_checked_against_its_tables(changes, expected):
    out = check_changes("lockin", "lockin", changes, LOCKIN_INFO)
    assert [c.value for c in out] == expected


@pytest.mark.parametrize("changes, field", [
    ({"sensitivity_v": 2e-3}, "lockin.sensitivity_v"),
    ({"time_constant_s": float("nan")}, "lockin.time_constant_s"),
    ({"reference_source": "chopper"}, "lockin.reference_source"),
    ({"harmonic": 2}, "lockin.harmonic"),
    ({"auto_range": "yes"}, "lockin.auto_range"),
])
def test_a_lockin_value_off_its_tables_is_refused_naming_the_field(changes, field):
    with pytest.raises(SettingRefused) as err:
        check_changes("lockin", "lockin", changes, LOCKIN_INFO)
    assert err.value.field == field
