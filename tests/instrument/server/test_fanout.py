"""The event stream's fan-out (instrument/server/fanout.py): frames built once and written
to every client by one callback per batch; 50 clients of a real server process each
receive every lifecycle message; a client that stops reading is cut off, the others get
everything."""

from __future__ import annotations

import asyncio
import json
import socket
import threading

import pytest
import uvicorn
from hypothesis import given, settings
from hypothesis import strategies as st
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed
from websockets.frames import Frame, Opcode

from instrument.bench.profile import parse_profile
from instrument.protocol import API_PREFIX, decode
from instrument.server.app import create_app
from instrument.server.fanout import text_frame
from instrument.server.main import WS_OPTIONS
from instrument.server.service import BenchService
from tests.instrument.server.helpers import fast_profile_text, plan_text
from tests.waiting import wait_for

N_CLIENTS = 50
THETA_R = [-60.0, -40.0, 10.0, 40.0, 60.0]
LIFECYCLE = ["run_started", "run_finished", "item_finished"]


@settings(max_examples=60, deadline=None)
@given(st.one_of(st.integers(0, 300), st.sampled_from([125, 126, 127, 65535, 65536,
                                                      65537])),
       st.characters(min_codepoint=32, max_codepoint=0x10FFFF,
                     blacklist_categories=("Cs",)))
def test_text_frame_is_the_frame_websockets_writes(n, char):
    text = char * n
    expected = Frame(Opcode.TEXT, text.encode("utf-8")).serialize(mask=False, extensions=[])
    assert text_frame(text) == expected


async def _watch(url: str, ready: list, seen: list) -> None:
    async with connect(url, max_size=None) as ws:
        ready.append(1)
        async for text in ws:
            msg = decode(text)
            seen.append(msg)
            if msg.type == "item_finished":
                return


def _clients(url: str, n: int, started: threading.Event, out: list) -> None:
    async def main() -> None:
        ready: list = []
        seen: list[list] = [[] for _ in range(n)]
        tasks = [asyncio.create_task(_watch(url, ready, seen[i])) for i in range(n)]
        while len(ready) < n:
            await asyncio.sleep(0.01)
        started.set()
        await asyncio.wait_for(asyncio.gather(*tasks), 600)
        out.extend(seen)
    asyncio.run(main())


@pytest.mark.timeout(900)
def test_fifty_clients_each_receive_every_lifecycle_message(bench_file, start_server):
    from instrument.client import BenchClient

    server = start_server(bench_file())
    url = "ws" + server.url[4:] + API_PREFIX + "/events"
    started, seen = threading.Event(), []
    t = threading.Thread(target=_clients, args=(url, N_CLIENTS, started, seen), daemon=True)
    t.start()
    assert started.wait(300), "the clients did not connect"
    with BenchClient(server.url) as c:
        c.add_plan(plan_text("crowd", THETA_R))
        c.start_queue()
    t.join(600)
    assert len(seen) == N_CLIENTS
    first = None
    for messages in seen:
        kinds = [m.type for m in messages]
        assert kinds[0] == "hello"
        assert [k for k in kinds if k in LIFECYCLE] == LIFECYCLE
        seqs = [m.seq for m in messages if m.type not in ("hello", "missed")]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
        # a client this far behind nothing: every point arrived, once, in order
        points = [p["index"] for m in messages if m.type == "points" for p in m.data["items"]]
        assert points == list(range(len(THETA_R)))
        lifecycle = [(m.seq, m.type, m.data) for m in messages if m.type in LIFECYCLE]
        first = first or lifecycle
        assert lifecycle == first  # the same messages, the same numbers, for everyone


class Uvicorn:
    """The app of ``service`` on uvicorn with the server's WebSocket options, in this
    process (a thread), on a random loopback port."""

    def __init__(self, service: BenchService) -> None:
        sock = socket.socket()
        sock.bind(("127.0.0.1", 0))
        sock.listen(64)
        self.url = f"ws://127.0.0.1:{sock.getsockname()[1]}{API_PREFIX}/events"
        self.app = create_app(service)
        self.server = uvicorn.Server(uvicorn.Config(self.app, log_level="warning",
                                                    lifespan="on", **WS_OPTIONS))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [sock]},
                                       daemon=True)
        self.thread.start()
        wait_for(lambda: self.server.started, what="uvicorn's start", timeout=120)

    def close(self) -> None:
        self.server.should_exit = True
        self.thread.join(120)


@pytest.fixture
def served(tmp_path):
    profile = parse_profile(fast_profile_text(), source="fast sim")
    service = BenchService(profile, tmp_path / "runs", fsync=False)
    server = Uvicorn(service)
    yield server, service
    server.close()


@pytest.mark.timeout(600)
def test_a_client_that_stops_reading_is_cut_off_and_the_others_get_everything(served):
    from websockets.sync.client import connect as sync_connect

    server, service = served
    # past a client's lifecycle limit (10,000) after what the socket buffers absorb
    n = 14_000
    filler = "x" * 4000
    with sync_connect(server.url, max_size=None) as stalled, \
            sync_connect(server.url, max_size=None) as reader:
        for ws in (stalled, reader):
            assert decode(ws.recv(60)).type == "hello"
        # both served by the one-callback path of uvicorn, not a task per client
        wait_for(lambda: sum(len(f) for f in server.app.state.fanouts.values()) == 2,
                 what="both clients on the fan-out")
        got: list[int] = []

        def read() -> None:
            while len(got) < n:
                m = json.loads(reader.recv(120))
                if m["type"] == "manual":
                    got.append(int(m["data"]["what"]))

        t = threading.Thread(target=read, daemon=True)
        t.start()
        for k in range(n):
            service.hub.publish("manual", {"who": "test", "what": str(k), "message": filler})
        t.join(300)
        assert got == list(range(n))  # the reader: every message, in order
        # the stalled client was cut off (its buffer stopped growing), and is told why
        # once it reads
        wait_for(lambda: sum(len(f) for f in server.app.state.fanouts.values()) == 1,
                 what="the stalled client cut off", timeout=120)
        with pytest.raises(ConnectionClosed) as exc:  # after what was sent before it
            while True:
                stalled.recv(60)
        assert "fell too far behind" in str(exc.value)
