"""The server's parts without a server: the protocol, the clients' buffers, the queue's
persistence, keys, where it may listen."""

from __future__ import annotations

import json
import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from instrument.cli.serve import parse_expiry
from instrument.protocol import (
    MESSAGE_TYPES,
    PROTOCOL_VERSION,
    Message,
    decode,
    encode,
    role_allows,
)
from instrument.server.db import ServerDB
from instrument.server.hub import ClientBuffer, EventHub
from instrument.server.keys import KeyStore
from instrument.server.main import ServeRefused, check_listen, parse_listen
from instrument.server.queue import PlanQueue, QueueError


# protocol ------------------------------------------------------------------------------
def test_a_message_survives_encoding():
    m = Message(7, "progress", 1.5, {"n_done": 3, "n_total": 9, "elapsed_s": 1.0,
                                     "eta_s": 2.0})
    assert decode(encode(m)) == m
    assert not m.lifecycle and Message(1, "fault", 0.0, {}).lifecycle


def test_a_newer_protocol_is_refused_with_what_to_do():
    text = json.dumps({"v": PROTOCOL_VERSION + 1, "seq": 1, "type": "x", "time": 0,
                       "data": {}})
    with pytest.raises(ValueError, match="update scatterlab"):
        decode(text)


@given(st.one_of(st.text(), st.binary(), st.dictionaries(st.text(), st.integers()).map(
    json.dumps)))
def test_decode_refuses_anything_else_with_a_value_error(text):
    try:
        message = decode(text)
    except ValueError:
        return
    assert isinstance(message, Message)  # a real message among the random ones


def test_roles_are_ordered():
    assert role_allows("admin", "operator") and role_allows("operator", "operator")
    assert not role_allows("observer", "operator") and not role_allows("root", "observer")


# buffers -------------------------------------------------------------------------------
def _msg(seq: int, kind: str) -> Message:
    return Message(seq, kind, 0.0, {})


def test_a_slow_client_loses_display_messages_never_lifecycle_and_is_told():
    buf = ClientBuffer(capacity=3)
    for seq in range(1, 11):
        kind = "progress" if seq % 5 else "fault"
        buf.put(_msg(seq, kind), encode(_msg(seq, kind)))
    got = [decode(t) for t in buf.take()]
    assert got[0].type == "missed"
    assert got[0].data == {"counts": {"progress": 5}, "first_seq": 4, "last_seq": 9}
    assert [m.seq for m in got[1:]] == [1, 2, 3, 5, 10]  # both faults kept
    assert buf.take() == []


def test_a_client_that_stopped_reading_is_cut_off_not_grown_without_bound():
    buf = ClientBuffer(capacity=2, lifecycle_limit=5)
    for seq in range(1, 20):
        buf.put(_msg(seq, "run_started"), "x")
    assert buf.cut_off and len(buf) == 0


def test_the_hub_hands_every_message_to_every_client_in_order():
    hub = EventHub()
    try:
        bufs = [ClientBuffer(capacity=10_000) for _ in range(3)]
        for b in bufs:
            hub.attach(b)
        for k in range(100):
            hub.publish("progress", {"n_done": k, "n_total": 100, "elapsed_s": 0.0,
                                     "eta_s": 0.0})
        assert hub.flush(60)
        for b in bufs:
            assert [decode(t).data["n_done"] for t in b.take()] == list(range(100))
        with pytest.raises(ValueError, match="unknown message type"):
            hub.publish("nonsense", {})
    finally:
        hub.close()


def test_every_message_type_names_its_fields():
    for t in MESSAGE_TYPES.values():
        assert t.doc and isinstance(t.fields, dict)


# queue ---------------------------------------------------------------------------------
def test_the_queue_persists_orders_and_survives_a_restart(tmp_path):
    with ServerDB(tmp_path) as db:
        q = PlanQueue(db)
        a = q.add("plan", "a", "A", "ann")
        b = q.add("plan", "b", "B", "ann")
        s = q.add("stop", "stop marker", None, "ann")
        p = q.add("plan", "p", "P", "obs", proposed=True)
        q.move(s.id, 0)
        assert [i.name for i in q.items()] == ["stop marker", "a", "b", "p"]
        q.move(s.id, 2)
        assert [i.name for i in q.items()] == ["a", "b", "stop marker", "p"]
        q.set_state(a.id, "running", "/runs/a.h5")
        with pytest.raises(QueueError, match="running"):
            q.remove(a.id, "ann")
        with pytest.raises(QueueError, match="not a proposal"):
            q.approve(b.id)
    with ServerDB(tmp_path) as db:  # the server died while a ran
        q = PlanQueue(db)
        (hit,) = q.after_restart()
        assert hit.id == a.id
        head = q.head()
        assert head.id == a.id and head.state == "interrupted" and head.summary()["resumable"]
        q.deny(p.id, "op")
        q.remove(b.id, "op")
        assert [(h.name, h.outcome) for h in q.history()] == [
            ("a", "interrupted"), ("p", "denied"), ("b", "removed")]
        with pytest.raises(QueueError) as err:
            q.get(999)
        assert err.value.status == 404


def test_a_proposal_is_passed_by_until_approved(tmp_path):
    with ServerDB(tmp_path) as db:
        q = PlanQueue(db)
        p = q.add("plan", "p", "P", "obs", proposed=True)
        assert q.head() is None
        q.approve(p.id)
        assert q.head().id == p.id


# keys and listening --------------------------------------------------------------------
def test_a_key_checks_by_its_token_only(tmp_path):
    with ServerDB(tmp_path) as db:
        keys = KeyStore(db)
        key, token = keys.add("ann", "operator")
        assert keys.check(token) == key
        assert keys.check(token + "x") is None and keys.check("") is None
        with pytest.raises(ValueError, match="--role"):
            keys.add("bob", "root")
        with pytest.raises(ValueError, match="past"):
            keys.add("bob", "observer", expires=time.time() - 1)
        with pytest.raises(KeyError):
            keys.revoke(99)


@pytest.mark.parametrize("listen", ["0.0.0.0:8765", "192.168.1.20:80", "[::]:8765",
                                    "bench-pc.lab:8765"])
def test_any_address_but_loopback_needs_tls_and_keys(listen, tmp_path):
    where = parse_listen(listen)
    with pytest.raises(ServeRefused, match=r"TLS .* and API keys"):
        check_listen(where, cert=None, key=None, has_keys=False)
    cert, key = tmp_path / "c.pem", tmp_path / "k.pem"
    cert.write_text("x")
    key.write_text("x")
    with pytest.raises(ServeRefused, match="API keys"):
        check_listen(where, cert=str(cert), key=str(key), has_keys=False)
    with pytest.raises(ServeRefused, match="TLS"):
        check_listen(where, cert=None, key=None, has_keys=True)
    check_listen(where, cert=str(cert), key=str(key), has_keys=True)


@pytest.mark.parametrize("listen", ["127.0.0.1:0", "localhost:8765", "[::1]:9000"])
def test_loopback_needs_nothing(listen):
    check_listen(parse_listen(listen), cert=None, key=None, has_keys=False)


@pytest.mark.parametrize("bad", ["8765", "host:", ":80", "h:99999", "h:x"])
def test_a_malformed_listen_address_is_refused(bad):
    with pytest.raises(ServeRefused, match="HOST:PORT"):
        parse_listen(bad)


def test_expiry_in_days_or_as_a_date():
    assert parse_expiry("1.5", now=1000.0) == 1000.0 + 1.5 * 86400
    assert parse_expiry("2030-01-31") == time.mktime(time.strptime("2030-01-31", "%Y-%m-%d"))
    for bad in ("0", "-3", "tomorrow"):
        with pytest.raises(ValueError, match="--expires"):
            parse_expiry(bad)




# display messages ------------------------------------------------------------------------
def test_a_frame_is_decimated_for_display_by_block_means():
    import numpy as np

    from instrument.server.service import decimate

    frame = np.zeros((1024, 1280), dtype=np.uint16)
    frame[:8, :8] = 4000  # one 8×8 block at full value
    img, scale = decimate(frame, max_px=160)
    assert img.shape == (128, 160) and img.dtype == np.uint8
    assert img[0, 0] == 255 and img[1:, :].max() == 0
    assert scale == pytest.approx(4000 / 255)


def test_engine_events_become_messages_with_null_for_what_was_not_measured():
    import math

    from instrument.run.events import PointCompleted
    from instrument.server.service import event_message

    kind, data = event_message(PointCompleted(3, "sample", "ok", {"detector_theta": 10.0},
                                              None, math.nan, 1e-6, math.nan, 0))
    assert kind == "point" and data["exposure_us"] is None and data["signal"] is None
    assert data["power_w"] == 1e-6
    encode(Message(1, "points", 0.0, {"items": [data]}))  # JSON without NaN
