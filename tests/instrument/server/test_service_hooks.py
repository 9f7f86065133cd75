"""The bench service in this process, held at chosen places by hooks on its own threads:
Stop all between two queue items, and the device states it publishes (no HTTP: the
service's methods are what the endpoints call)."""

from __future__ import annotations

import threading

import pytest

from instrument.bench.profile import load_profile, parse_profile
from instrument.run.journal import read_journal
from instrument.run.locks import hold
from instrument.run.paths import writer_lock_path
from instrument.run.storage import journal_path
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


class LockedByAnother(BenchService):
    """Another holder takes the writer lock of each new run file the moment the service
    has opened it, as a ``scatterlab resume`` of the same file in another process would."""

    def __init__(self, *args, **kw) -> None:
        self.other_holders: list = []
        super().__init__(*args, **kw)

    def _engine_for(self, item, bench):
        engine, note = super()._engine_for(item, bench)
        if engine is not None:
            held = hold(writer_lock_path(engine.store.path), "scatterlab resume (test)")
            held.__enter__()  # a second open file: flock refuses the service's own
            self.other_holders.append(held)
        return engine, note


@pytest.mark.timeout(600)
def test_a_run_file_locked_by_another_process_fails_the_item_and_is_left_alone(tmp_path):
    svc = LockedByAnother(parse_profile(fast_profile_text(), source="fast sim"),
                          tmp_path / "runs", fsync=False)
    try:
        item = svc.add_plan(OPERATOR, plan_text("locked", THETA_R))
        svc.start_queue(OPERATOR)
        wait_for(lambda: [h.outcome for h in svc.queue.history()] == ["failed"], HOLD_S,
                 "the item to fail")
        (entry,) = svc.queue.history()
        assert entry.item_id == item.id
        assert "is being continued by" in entry.note and "scatterlab resume (test)" in entry.note
        assert svc.status()["queue_running"] is False and svc.engine is None
        # the service closed its handles without writing: the run's status and journal
        # stay the other holder's to write
        (run_file,) = (tmp_path / "runs").rglob("*.h5")
        records, _ = read_journal(journal_path(run_file))
        assert records and not [r for r in records if r.get("t") == "status"]
    finally:
        for held in svc.other_holders:
            held.__exit__(None, None, None)
        svc.close()


class SeenAtPublish(BenchService):
    """Notes, in the publishing thread at the moment ``run_finished`` or ``item_finished``
    is handed to the hub, what a client reacting to it would find: the history's outcomes
    and the status's run. (A client hears a message only after it was published, so
    whatever holds at that moment holds for every client.)"""

    def __init__(self, *args, **kw) -> None:
        self.seen: list[tuple[str, list[str], object]] = []
        super().__init__(*args, **kw)
        publish = self.hub.publish

        def noting(kind, data):
            if kind in ("run_finished", "item_finished"):
                self.seen.append((kind, [h.outcome for h in self.queue.history()],
                                  self.status()["run"]))
            publish(kind, data)
        self.hub.publish = noting


@pytest.mark.timeout(600)
def test_run_finished_is_published_after_the_history_row_and_the_status_cleared(tmp_path):
    """A client that lists the history in its ``run_finished`` handler finds the run's
    row: the runner records it, and clears the run from the status, before the engine's
    ``run_finished`` goes out; ``item_finished`` follows."""
    svc = SeenAtPublish(parse_profile(fast_profile_text(), source="fast sim"),
                        tmp_path / "runs", fsync=False)
    try:
        svc.add_plan(OPERATOR, plan_text("first", THETA_R))
        svc.start_queue(OPERATOR)
        wait_for(lambda: len(svc.seen) == 2, HOLD_S, "the item to finish")
        assert svc.seen == [("run_finished", ["finished"], None),
                            ("item_finished", ["finished"], None)]
    finally:
        svc.close()
