"""RemoteState: the server's state from its event messages, and who may act (no Qt)."""

from __future__ import annotations

import time

from gui.model.remote import RemoteState
from instrument.protocol import Message
from instrument.server.points import RunPoints


def msg(kind: str, seq: int = 1, **data) -> Message:
    return Message(seq, kind, 1_790_000_000.0, data)


def point(index: int, theta_r: float = 10.0) -> dict:
    return {"index": index, "label": f"p{index}", "status": "ok",
            "positions": {"detector_theta": theta_r}, "angles": [20.0, 180.0, theta_r, 0.0],
            "exposure_us": 1000.0, "power_w": 1e-6 * (index + 1), "signal": None,
            "retries": 0, "nd_slot": -1}


def hello(role: str = "operator", name: str = "ann", run=None, control=None) -> Message:
    return msg("hello", 0, protocol=1, bench="sim", role=role, name=name, status={
        "bench": "sim", "connected": True, "queue_running": run is not None, "run": run,
        "control": control or {"holder": None, "until": None}, "queue": [],
        "runs_dir": "/tmp/runs"})


def test_a_run_is_followed_and_points_are_kept_once_by_index():
    s = RemoteState("http://x")
    s.apply(hello())
    s.apply(msg("run_started", run_id="R1", path="/r/R1.h5", plan_kind="brdf_in_plane",
                n_total=5, n_done=0, estimated_s=1.0, item_id=3))
    s.apply(msg("points", items=[point(0), point(1)]))
    s.apply(msg("points", items=[point(1), point(2)]))  # an overlap: kept once
    snap = s.run.live.snapshot()
    assert snap.index.tolist() == [0, 1, 2]
    assert snap.planned_theta_i.tolist() == [-20.0, -20.0, -20.0]  # φi = 180°: signed < 0
    assert s.run.item_id == 3 and s.run.alive
    s.apply(msg("paused", reason="detector_theta failed", index=3,
                answers=["retry", "skip", "abort"]))
    assert s.run.state == "paused" and s.run.answers == ["retry", "skip", "abort"]
    s.apply(msg("resumed", index=3))
    s.apply(msg("run_finished", status="finished", n_done=5, n_total=5, n_skipped=0,
                path="/r/R1.h5", elapsed_s=1.0, message=""))
    assert s.run.state == "finished" and not s.run.alive


def test_a_client_that_connects_mid_run_gets_the_points_from_the_first():
    rp = RunPoints()
    rp.on_message(msg("run_started", run_id="R2", path="/r/R2.h5", plan_kind="brdf_in_plane",
                      n_total=6000, n_done=0, item_id=1))
    for k in range(0, 6000, 100):
        rp.on_message(msg("points", items=[point(i) for i in range(k, k + 100)]))
    first = rp.page(0)
    assert first["total"] == 6000 and first["next"] == 5000 and len(first["items"]) == 5000
    rest = rp.page(first["next"])
    assert rest["next"] == 6000 and rest["run"]["run_id"] == "R2"
    s = RemoteState("http://x")
    s.apply(hello(run={"state": "running", "n_done": 6000, "n_total": 6000, "path": "/r/R2.h5",
                       "item_id": 1, "answers": [], "pause_reason": None, "elapsed_s": 1.0,
                       "n_skipped": 0}))
    from gui.model.remote import point_event

    items = first["items"] + rest["items"]
    assert s.prefill(first["run"], [(i["index"], point_event(i)) for i in items]) == 6000
    assert s.run.live.snapshot().index[0] == 0


def test_observers_watch_and_another_operators_lease_greys_the_controls():
    s = RemoteState("http://x")
    assert s.may_operate()[0] is False  # not connected yet
    s.apply(hello(role="observer", name="bob"))
    ok, why = s.may_operate()
    assert not ok and "observer" in why
    assert s.may_stop_all() == (False, "Stop all needs an operator key")
    s.apply(hello(role="operator", name="ann",
                  control={"holder": "carl", "until": time.time() + 300}))
    ok, why = s.may_operate()
    assert not ok and "carl" in why
    assert s.may_stop_all() == (True, "")  # Stop all: always, for any operator
    s.apply(msg("control", holder="ann", until=time.time() + 300))
    assert s.may_operate() == (True, "") and s.holds_control()
    s.apply(msg("control", holder="carl", until=time.time() - 1))  # ran out
    assert s.may_operate() == (True, "")


def test_the_drawing_gets_the_homed_axes_positions_only():
    s = RemoteState("http://127.0.0.1:1")
    s.apply(hello())
    assert s.apply(msg("devices", 2, owner="manual", light=False, axes={
        "detector_theta": {"position": 40.0, "homed": True, "moving": False},
        "sample_theta": {"position": 3.0, "homed": False, "moving": False},  # a counter
        "camera_z": {"position": None, "homed": True, "moving": False},
    })) == "devices"
    assert s.homed_positions() == {"detector_theta": 40.0}


def test_device_states_are_kept_by_role_and_replaced_only_when_they_change():
    s = RemoteState("http://127.0.0.1:1")
    s.apply(hello())
    now = time.time()
    meter = {"kind": "power_meter", "connected": True, "error": None, "read_at": now - 5.0,
             "values": {"power_w": 1.5e-6, "wavelength_nm": 633.0},
             "info": {"wavelength_range_nm": [400.0, 1100.0]}}
    wheel = {"kind": "filter_wheel", "connected": True, "error": None, "read_at": now,
             "values": {"position": 2, "speed": "high"},
             "info": {"count": 6, "filters": {"2": [None, None, "ND1", 1.0]}}}
    s.apply(msg("devices", 2, owner="idle", axes={}, states={"pm": meter, "fw": wheel}))
    pm, fw = s.device_states["pm"], s.device_states["fw"]
    assert (pm.role, pm.kind, pm.value("power_w")) == ("pm", "power_meter", 1.5e-6)
    assert 5.0 <= time.monotonic() - pm.t < 60.0  # its age as the server read it
    assert fw.info["filters"] == {"2": [None, None, "ND1", 1.0]}
    # the same state again: the same object (its panel does not redraw); a new reading
    # replaces it; a role the server no longer names is dropped
    s.apply(msg("devices", 3, owner="idle", axes={}, states={"pm": meter, "fw": wheel}))
    assert s.device_states["pm"] is pm and s.device_states["fw"] is fw
    s.apply(msg("devices", 4, owner="run", axes={}, states={
        "pm": {**meter, "values": {"power_w": 2e-6, "wavelength_nm": 633.0}}}))
    assert s.device_states["pm"].value("power_w") == 2e-6 and "fw" not in s.device_states
