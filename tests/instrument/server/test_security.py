"""Security refusals, each with the right status and no side effect: the queue, its
history, the keys, the control lease, the bench's positions and light are compared before
and after every refused request, and the refusal is in the audit log."""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass

import pytest
from fastapi.testclient import TestClient

from hw_mocks import registry
from hw_mocks.sim.world import get_world
from instrument.bench.profile import parse_profile
from instrument.protocol import API_PREFIX as P
from instrument.server.app import MAX_BODY_BYTES, create_app
from instrument.server.audit import AuditLog
from instrument.server.keys import KeyStore
from instrument.server.service import BenchService
from tests.instrument.server.helpers import fast_profile_text, plan_text
from tests.waiting import wait_for

PLAN = plan_text("secure", [-60.0, 40.0])
AXES = {"simapt": ("sample_theta", "camera_z"), "simsmc": ("detector_theta",)}


@dataclass
class Server:
    service: BenchService
    http: TestClient
    tokens: dict[str, str]

    def call(self, method: str, path: str, who: str | None, **kw):
        headers = kw.pop("headers", {})
        if who is not None:
            headers["Authorization"] = f"Bearer {self.tokens.get(who, who)}"
        return self.http.request(method, P + path, headers=headers, **kw)

    def state(self) -> dict:
        """Everything a request could change."""
        svc = self.service
        positions = {n: round(registry.get(s, n).stage.physical_position(), 9)
                     for s, names in AXES.items() for n in names}
        moving = [n for s, names in AXES.items() for n in names
                  if registry.get(s, n).stage.is_moving()]
        return {"items": svc.queue.items(), "history": svc.queue.history(),
                "keys": KeyStore(svc.db).list(), "lease": svc.status()["control"],
                "running": svc.queue_running, "positions": positions, "moving": moving,
                "light": get_world("sim").snapshot().source.on,
                "connected": svc.bench is not None}

    def audit(self) -> list:
        return AuditLog(self.service.db).rows(limit=1000)


@pytest.fixture
def server(tmp_path):
    profile = parse_profile(fast_profile_text(), source="fast sim")
    service = BenchService(profile, tmp_path / "runs", fsync=False,
                           allowed=[tmp_path / "calibrations"])
    keys = KeyStore(service.db)
    tokens = {role: keys.add(f"{role}-1", role)[1]
              for role in ("observer", "operator", "admin")}
    tokens["operator2"] = keys.add("operator-2", "operator")[1]
    with TestClient(create_app(service)) as http:
        yield Server(service, http, tokens)


def refused(server: Server, status: int, method: str, path: str, who: str | None, **kw):
    """Make the request; assert its status, that nothing changed, and that it was audited
    (state-changing requests); return the response."""
    before = server.state()
    n_audit = len(server.audit())
    r = server.call(method, path, who, **kw)
    assert r.status_code == status, r.text
    assert server.state() == before
    if method != "GET":
        rows = server.audit()[n_audit:]
        assert [(row.what, row.status) for row in rows] == [(f"{method} {P}{path}", status)]
    return r


# 401 and 403 --------------------------------------------------------------------------
@pytest.mark.parametrize("who", [None, "sl_not-a-key", "Basic abc"])
def test_no_key_or_a_wrong_key_is_401_and_changes_nothing(server, who):
    headers = {"Authorization": who} if who == "Basic abc" else {}
    who = None if who == "Basic abc" else who
    r = refused(server, 401, "POST", "/queue", who, json={"plan": PLAN}, headers=headers)
    assert r.headers["www-authenticate"] == "Bearer"
    refused(server, 401, "POST", "/bench/stop-all", who, headers=dict(headers))
    refused(server, 401, "GET", "/status", who, headers=dict(headers))


def test_revoked_and_expired_keys_are_401(server):
    keys = KeyStore(server.service.db)
    key, token = keys.add("leaver", "operator")
    assert server.call("GET", "/status", token).status_code == 200
    keys.revoke(key.id)
    refused(server, 401, "POST", "/queue/start", token)
    short, token2 = keys.add("visitor", "operator", expires=time.time() + 3600)
    with server.service.db.transaction() as db:  # it expired an hour early
        db.execute("UPDATE keys SET expires = ? WHERE id = ?", (time.time() - 1, short.id))
    refused(server, 401, "POST", "/queue/start", token2)


@pytest.mark.parametrize(("who", "method", "path", "body"), [
    ("observer", "POST", "/queue", {"plan": PLAN}),
    ("observer", "POST", "/queue/start", None),
    ("observer", "POST", "/run/abort", None),
    ("observer", "POST", "/bench/move", {"targets": {"sample_theta": 10.0}}),
    ("observer", "POST", "/bench/stop-all", None),
    ("observer", "POST", "/control/take", None),
    ("observer", "POST", "/bench/camera", {"exposure_us": 2000.0}),
    ("operator", "POST", "/keys", {"name": "x", "role": "admin"}),
    ("operator", "POST", "/bench/disconnect", None),
    ("operator", "GET", "/audit", None),
])
def test_a_role_too_low_is_403_and_changes_nothing(server, who, method, path, body):
    r = refused(server, 403, method, path, who, json=body)
    assert "needed" in r.json()["detail"]


def test_the_event_stream_needs_a_key_once_keys_exist(server):
    from starlette.websockets import WebSocketDisconnect

    with pytest.raises(WebSocketDisconnect), server.http.websocket_connect(P + "/events"):
        pass  # opening the stream without a key is the request under test: it is refused
    with server.http.websocket_connect(
            P + "/events", headers={"Authorization": f"Bearer {server.tokens['observer']}"}
    ) as ws:
        hello = json.loads(ws.receive_text())
        assert hello["type"] == "hello" and hello["data"]["role"] == "observer"


# malformed and oversized bodies --------------------------------------------------------
@pytest.mark.parametrize(("path", "content"), [
    ("/queue", b"{not json"),
    ("/queue", json.dumps({"plan": PLAN, "extra": 1}).encode()),
    ("/queue", json.dumps({"plan": 42}).encode()),
    ("/bench/jog", b'{"role": "sample_theta", "step": NaN}'),
    ("/bench/move", json.dumps({"targets": {}}).encode()),
    ("/queue/1/move", json.dumps({"index": -1}).encode()),
    ("/bench/camera", b'{"exposure_us": NaN}'),
    ("/bench/camera", json.dumps({"exposure_us": -5.0}).encode()),
    ("/keys", json.dumps({"name": "x", "role": "root"}).encode()),
])
def test_malformed_bodies_are_422_and_change_nothing(server, path, content):
    who = "admin" if path == "/keys" else "operator"
    r = refused(server, 422, "POST", path, who, content=content,
                headers={"Content-Type": "application/json"})
    assert r.json()["detail"] == "malformed request"


def test_an_oversized_body_is_413_before_it_is_read(server):
    big = b'{"plan": "' + b"#" * (MAX_BODY_BYTES + 10) + b'"}'
    refused(server, 413, "POST", "/queue", "operator", content=big,
            headers={"Content-Type": "application/json"})


# files ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("path", "status"), [
    ("..%2Fsecret.txt", 403), ("%2e%2e/secret.txt", 403), ("%2e%2e%2fsecret.txt", 403),
    ("sub%2F..%2F..%2Fsecret.txt", 403), ("server.sqlite", 403), ("server.sqlite-wal", 403),
    ("%2Fetc%2Fpasswd", 403),
    # an HTTP client resolves plain dot segments itself: the request names another route
    ("../secret.txt", 404), ("sub/../../secret.txt", 404),
])
def test_a_download_path_leaving_the_runs_folder_is_refused(server, tmp_path, path, status):
    (tmp_path / "secret.txt").write_text("not yours")
    r = refused(server, status, "GET", f"/runs/files/{path}", "observer")
    assert "not yours" not in r.text


def test_a_file_in_the_runs_folder_is_served(server):
    (server.service.runs_dir / "note.txt").write_text("a run's note")
    r = server.call("GET", "/runs/files/note.txt", "observer")
    assert r.status_code == 200 and r.text == "a run's note"


@pytest.mark.parametrize(("field", "value"), [
    ("[calibration]\ndark", "/etc/passwd"),
    ("[calibration]\nflat", "../../elsewhere/flat.h5"),
    ("[calibration]\nnd", "~/nd.h5"),
])
def test_a_plan_naming_files_outside_the_allowed_folders_is_refused(server, field, value):
    text = PLAN + f'\n{field} = "{value}"\n'
    r = refused(server, 422, "POST", "/queue", "operator", json={"plan": text})
    assert r.json()["reasons"][0].startswith("calibration.")
    assert "outside the folders" in r.json()["reasons"][0]


def test_a_plan_naming_a_run_id_or_a_file_inside_is_accepted(server, tmp_path):
    text = PLAN + '\n[calibration]\ndark = "20260101-000000-dark-0000"\n' \
        f'flat = "{tmp_path / "calibrations" / "flat.h5"}"\n'
    r = server.call("POST", "/queue", "operator", json={"plan": text})
    assert r.status_code == 200, r.text


def test_an_invalid_plan_is_refused_with_every_field(server):
    r = refused(server, 422, "POST", "/queue", "operator",
                json={"plan": PLAN.replace("exposure_us = 1000", "exposure_us = -1")})
    assert any("exposure_us" in reason for reason in r.json()["reasons"])


# the guard -----------------------------------------------------------------------------
def test_a_move_the_guard_refuses_is_422_with_its_reasons_and_nothing_moves(server):
    r = refused(server, 422, "POST", "/bench/move", "operator",
                json={"targets": {"sample_theta": 89.0}})
    assert any("sample_theta" in reason for reason in r.json()["reasons"])
    r = refused(server, 422, "POST", "/bench/move", "operator",
                json={"targets": {"no_such_axis": 1.0}})
    assert "no axis" in r.json()["detail"]


def test_light_on_with_the_detector_in_the_beam_is_refused(server):
    svc = server.service
    for role in ("sample_theta", "detector_theta"):
        assert server.call("POST", "/bench/home", "operator",
                           json={"role": role}).status_code == 200
    wait_for(lambda: all(a.status().is_homed and not a.status().is_moving
                         for a in svc.bench.axes.values()
                         if a is not svc.bench.axes["camera_z"]), what="homed")
    # detector at 0 with the sample at 0 and the source at 0: the detector is in the beam
    r = refused(server, 422, "POST", "/bench/light", "operator", json={"on": True})
    assert "beam" in r.json()["detail"]


def test_camera_settings_outside_the_cameras_range_are_refused_with_the_range(server):
    cam = server.service.bench.camera
    before = (cam.exposure_us, cam.gain)
    r = refused(server, 422, "POST", "/bench/camera", "operator", json={"gain": 99.0})
    assert "gain 99 outside [0, 24]" in r.json()["detail"]
    refused(server, 422, "POST", "/bench/camera", "operator", json={})  # nothing to set
    assert (cam.exposure_us, cam.gain) == before


def test_camera_settings_are_set_audited_and_published(server):
    r = server.call("POST", "/bench/camera", "operator",
                    json={"exposure_us": 2500.0, "gain": 6.0})
    assert r.status_code == 200, r.text
    assert r.json()["message"] == "camera: exposure 2500 µs, gain 6"
    cam = server.service.bench.camera
    assert (cam.exposure_us, cam.gain) == (2500.0, 6.0)
    row = server.audit()[-1]
    assert (row.who, row.what, row.status) == ("operator-1", f"POST {P}/bench/camera", 200)
    assert row.result == "camera: exposure 2500 µs, gain 6"
    assert server.service._device_states()["camera"] == {"exposure_us": 2500.0, "gain": 6.0}


# the control lease ---------------------------------------------------------------------
def test_one_operator_holds_control_others_are_refused_but_may_stop_all(server):
    r = server.call("POST", "/control/take", "operator", json={"timeout_s": 600})
    assert r.status_code == 200
    status = server.call("GET", "/status", "observer").json()
    assert status["control"]["holder"] == "operator-1"  # shown to everyone
    r = refused(server, 409, "POST", "/queue", "operator2", json={"plan": PLAN})
    assert "operator-1" in r.json()["detail"]
    refused(server, 409, "POST", "/bench/home", "operator2", json={"role": "sample_theta"})
    refused(server, 409, "POST", "/control/take", "operator2")
    assert server.call("POST", "/bench/stop-all", "operator2").status_code == 200
    # the holder releases; then the other operator may act
    assert server.call("POST", "/control/release", "operator").status_code == 200
    assert server.call("POST", "/queue", "operator2", json={"plan": PLAN}).status_code == 200
    # an admin may force it
    r = server.call("POST", "/control/take", "admin", json={"force": True})
    assert r.status_code == 200 and r.json()["holder"] == "admin-1"


def test_a_malformed_request_does_not_take_control(server):
    refused(server, 422, "POST", "/bench/jog", "operator", json={"role": "sample_theta"})
    assert server.service.status()["control"]["holder"] is None


# keys ----------------------------------------------------------------------------------
def test_keys_are_stored_hashed(server):
    raw = server.service.db.path.read_bytes()
    for token in server.tokens.values():
        assert token.encode() not in raw
    digests = {r[0] for r in server.service.db.query("SELECT digest FROM keys")}
    assert hashlib.sha256(server.tokens["admin"].encode()).hexdigest() in digests


def test_an_admin_adds_lists_and_revokes_keys(server):
    r = server.call("POST", "/keys", "admin", json={"name": "night shift", "role": "observer"})
    token = r.json()["token"]
    assert server.call("GET", "/status", token).json()["you"]["role"] == "observer"
    listed = server.call("GET", "/keys", "admin").json()
    assert "digest" not in listed[0] and any(k["name"] == "night shift" for k in listed)
    assert server.call("DELETE", f"/keys/{r.json()['id']}", "admin").status_code == 200
    assert server.call("GET", "/status", token).status_code == 401


def test_every_state_changing_request_is_audited(server):
    server.call("POST", "/queue", "operator", json={"plan": PLAN})
    server.call("POST", "/queue", "observer", json={"plan": PLAN})
    server.call("GET", "/queue", "observer")
    rows = [(r.who, r.what, r.status) for r in server.audit()]
    assert rows == [("operator-1", f"POST {P}/queue", 200),
                    ("observer-1", f"POST {P}/queue", 403)]
    assert server.audit()[0].result.startswith("added item")
