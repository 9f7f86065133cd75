"""The bench service in this process, held at chosen places by hooks on its own threads:
Stop all between two queue items, and the device states it publishes (no HTTP: the
service's methods are what the endpoints call)."""

from __future__ import annotations

import threading

import pytest

from instrument.bench.profile import load_profile, parse_profile
from instrument.server.service import STATE_KINDS, BenchService, Caller
from tests.instrument.server.helpers import fast_profile_text, plan_text
from tests.waiting import wait_for

OPERATOR = Caller("operator-1", "operator")
THETA_R = [-60.0, -40.0, 10.0, 40.0, 60.0]
HOLD_S = 120.0  # bound on a hang only (tests/waiting.py)


class BetweenItems(BenchService):
    """Holds the queue runner after the first item ended and before it takes the next:
    :attr:`between` is set there, and the runner goes on once :attr:`go_on` is set."""

    def __init__(self, *args, **kw) -> None:
        self.between = threading.Event()
        self.go_on = threading.Event()
        self.n_asked = 0
        self.taken: list[int | None] = []
        super().__init__(*args, **kw)

    def _next_item(self):
        self.n_asked += 1
        if self.n_asked == 2:  # the runner's first call took the first item
            self.between.set()
            if not self.go_on.wait(HOLD_S):
                raise AssertionError("the test never released the runner")
        item = super()._next_item()
        self.taken.append(None if item is None else item.id)
        return item


@pytest.fixture
def service(tmp_path):
    svc = BetweenItems(parse_profile(fast_profile_text(), source="fast sim"),
                       tmp_path / "runs", fsync=False)
    messages: list = []
    svc.hub.listen(messages.append)
    svc.messages = messages
    yield svc
    svc.go_on.set()
    svc.close()


@pytest.mark.timeout(600)
def test_stop_all_between_items_stops_the_queue_before_the_next_item(service):
    first = service.add_plan(OPERATOR, plan_text("first", THETA_R))
    second = service.add_plan(OPERATOR, plan_text("second", THETA_R))
    service.start_queue(OPERATOR)
    assert service.between.wait(HOLD_S), "the first item never ended"
    assert [h.outcome for h in service.queue.history()] == ["finished"]
    assert service.engine is None  # between items: no run owns the bench

    assert service.stop_all(OPERATOR) == "all axes stopped"
    status = service.status()
    assert status["queue_running"] is False and status["run"] is None
    assert [(i["id"], i["state"]) for i in status["queue"]] == [(second.id, "queued")]
    service.go_on.set()  # the runner asks for the next item: a stopped queue has none

    service.start_queue(OPERATOR)  # only an operator's start runs the second item
    wait_for(lambda: service.taken[1:] == [second.id], HOLD_S, "the second item taken")
    wait_for(lambda: [h.outcome for h in service.queue.history()] == ["finished"] * 2,
             HOLD_S * 2, "the second item to finish")
    assert service.taken == [first.id, second.id]
    # on the event stream: the first item ended, Stop all, the queue stopped; the second
    # run started only after the queue was started again
    seq = [(m.type, m.data) for m in service.messages]
    stop = next(k for k, (t, d) in enumerate(seq) if t == "manual"
                and d["what"] == "stop all")
    ended = next(k for k, (t, d) in enumerate(seq) if t == "item_finished"
                 and d["item_id"] == first.id)
    restarted = next(k for k, (t, d) in enumerate(seq) if k > stop and t == "queue"
                     and d["running"])
    started = [k for k, (t, d) in enumerate(seq) if t == "run_started"]
    assert ended < stop < restarted < started[1] and len(started) == 2
    assert any(t == "queue" and not d["running"] for t, d in seq[stop:restarted])


def test_the_devices_message_carries_the_lock_in_wheel_and_meter(tmp_path):
    """On sim-spectral the sampler reads the three devices as the GUI's device worker
    does; the message is plain JSON (no NaN, lists, string keys)."""
    import json

    svc = BenchService(load_profile("sim-spectral"), tmp_path / "runs", fsync=False)
    try:
        states = svc._device_states()["states"]
        assert set(states) == {"lockin", "filter_wheel", "power_meter"}
        assert {s["kind"] for s in states.values()} == set(STATE_KINDS)
        lockin = states["lockin"]
        assert lockin["connected"] and lockin["error"] is None
        assert lockin["values"]["sensitivity_v"] == 1.0
        assert lockin["info"]["sensitivities_v"][0] == 2e-9
        wheel = states["filter_wheel"]
        assert wheel["values"] == {"position": 1, "speed": "high"}
        assert wheel["info"]["filters"]["1"][:2] == [450.0, 10.0]
        assert states["power_meter"]["values"]["wavelength_nm"] == 550.0
        json.dumps(states, allow_nan=False)
    finally:
        svc.close()
