"""The same surface against the bench server: ``connect(url, key=...)``.

A script that runs ``bench.dry_run(plan)``, ``bench.run(plan)`` and ``open_run(path)`` on
the bench PC runs unchanged in an office against the bench server (ADR 0080–0083):
:func:`connect` returns a :class:`RemoteBench` with the same three methods.

- ``dry_run(plan)`` builds and guards the plan locally against the server's bench profile
  (read from the server), exactly as the server will before it runs it;
- ``run(plan)`` adds the plan to the server's queue (the operator role, and the control
  lease when someone else holds it) and starts the queue; the :class:`RemoteHandle` it
  returns follows the run through the server's event stream: progress, pause, resume,
  abort, wait, and the events (the stream's messages) as an iterator;
- ``open_run(path)`` downloads the run file (the observer role suffices) and opens it as
  :func:`instrument.open_run` does.

What a remote run cannot be is adaptive: the plan object would have to run on the server.
"""

from __future__ import annotations

import queue
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, cast

from instrument.bench.profile import BenchProfile, parse_profile
from instrument.client import BenchClient, ClientError
from instrument.plans.adaptive import AdaptivePlan
from instrument.plans.build import build_plan
from instrument.plans.planfile import PlanSpec, load_plan
from instrument.protocol import Message
from instrument.scripting.bench import DryRun, PlanLike, dry_run_of
from instrument.scripting.handle import RunProgress, RunTimeout
from instrument.scripting.results import Run, open_run

__all__ = ["RemoteBench", "RemoteHandle", "connect"]

#: The events that end a queued run for its handle.
_END = "item_finished"


def connect(url: str, key: str | None = None, *, runs_dir: str | Path | None = None,
            ca: str | None = None) -> RemoteBench:
    """The bench server at ``url`` with the API key ``key`` (the client's environment
    variable when None), as a bench a script uses like :func:`instrument.open_bench`'s
    (``with`` block, ``run``, ``dry_run``, ``open_run``). ``runs_dir`` is where downloaded
    run files go (a temporary folder when None); ``ca`` a CA bundle for a server whose
    certificate is self-signed (as for ``scatterlab`` client commands)."""
    return RemoteBench(BenchClient(url, key, ca=ca), url=url, key=key, ca=ca,
                       runs_dir=runs_dir)


class RemoteBench:
    """A bench server as a script holds it (module docstring). Made by :func:`connect`."""

    def __init__(self, client: BenchClient, *, url: str, key: str | None, ca: str | None,
                 runs_dir: str | Path | None) -> None:
        self._client = client
        self._stream_args = (url, key, ca)
        self._tmp = None if runs_dir is not None else tempfile.TemporaryDirectory(
            prefix="scatterlab-runs-")
        self.runs_dir = Path(runs_dir if runs_dir is not None
                             else cast("tempfile.TemporaryDirectory[str]", self._tmp).name)
        self.runs_dir.mkdir(parents=True, exist_ok=True)
        self._profile: BenchProfile | None = None

    @property
    def profile(self) -> BenchProfile:
        """The server's bench profile (read once)."""
        if self._profile is None:
            got = self._client.request("GET", "/bench/profile")
            self._profile = parse_profile(got["text"], source=f"{got['name']} (server)")
        return self._profile

    def status(self) -> dict[str, Any]:
        return self._client.status()

    def _spec(self, plan: PlanLike | AdaptivePlan) -> PlanSpec:
        if isinstance(plan, AdaptivePlan):
            raise TypeError("an adaptive plan runs where its Python object is: use "
                            "open_bench on the bench PC (the server runs plan files)")
        return plan if isinstance(plan, PlanSpec) else load_plan(plan)

    def dry_run(self, plan: PlanLike) -> DryRun:
        """As :meth:`ScriptBench.dry_run`, on the server's bench profile; nothing moves."""
        return dry_run_of(build_plan(self._spec(plan), self.profile))

    def run(self, plan: PlanLike, *, block: bool = True, progress: bool | None = None,
            on_event: Callable[[Message], Any] | None = None,
            timeout: float | None = None) -> RemoteHandle:
        """Queue ``plan`` on the server and start the queue; with ``block``, wait for the
        run to end (``timeout`` seconds at most, then :class:`RunTimeout`; the run goes
        on). ``on_event(message)`` is called with each of the run's messages, on the
        handle's reading thread.

        Raises
        ------
        PlanError, GuardError
            Locally, before anything is sent.
        ClientError
            The server refused (the key's role, the control lease, its own validation).
        """
        spec = self._spec(plan)
        build_plan(spec, self.profile)  # refused here in the same words as on the bench
        url, key, ca = self._stream_args
        handle = RemoteHandle(BenchClient(url, key, ca=ca), self._client, self,
                              on_event=on_event)
        try:
            item = self._client.add_plan(spec.source_text, spec.name)
            handle._adopt(int(item["id"]))
            if not self._client.queue()["running"]:
                self._client.start_queue()
        except BaseException:
            handle._close()
            raise
        if block:
            show = progress if progress is not None else True
            handle.wait(timeout, show=show)
        return handle

    def open_run(self, path: str | Path) -> Run:
        """Download the run file ``path`` (as the server names it: absolute under its runs
        folder, or relative to it) into ``runs_dir`` and open it."""
        rel = _relative_to_runs(str(path), self.status().get("runs_dir", ""))
        to = self.runs_dir / Path(rel).name
        self._client.download(rel, to)
        return open_run(to)

    def close(self) -> None:
        self._client.close()

    def __enter__(self) -> RemoteBench:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<RemoteBench {self._client.url}>"


def _relative_to_runs(path: str, runs_dir: str) -> str:
    if runs_dir and path.startswith(runs_dir.rstrip("/") + "/"):
        return path[len(runs_dir.rstrip("/")) + 1:]
    return path


class RemoteHandle:
    """A run queued on the server, followed through its event stream.

    ``status`` is ``"queued"`` until the run starts, then the run's state; ``path`` is the
    run file's path on the server (``open_run`` it from the :class:`RemoteBench`).
    """

    def __init__(self, stream: BenchClient, client: BenchClient, bench: RemoteBench, *,
                 on_event: Callable[[Message], Any] | None = None) -> None:
        self._stream = stream
        self._client = client
        self._bench = bench
        self._on_event = on_event
        self._item_id: int | None = None
        self._lock = threading.Lock()
        self._ours = False           # between our run_started and its run_finished
        #: Messages of items whose run started before the server's answer named ours.
        self._early: list[Message] = []
        self._messages: queue.Queue[Message | None] = queue.Queue()
        self._ended = threading.Event()
        self._hello = threading.Event()
        self._state = "queued"
        self._path: str | None = None
        self._n = (0, 0)
        self._t0: float | None = None
        self.outcome: str | None = None
        self._error: ClientError | None = None
        self._thread = threading.Thread(target=self._read, name="remote-run", daemon=True)
        self._thread.start()
        if not self._hello.wait(60.0):
            self._close()
            raise ClientError(0, f"no event stream from {stream.url} within 60 s")

    # the reading thread -----------------------------------------------------------------
    def _read(self) -> None:
        try:
            for msg in self._stream.events():
                if msg.type == "hello":
                    self._hello.set()
                    continue
                self._deliver(msg)
                if self._ended.is_set():
                    break
        except ClientError as err:
            self._error = err
        finally:
            self._hello.set()
            self._ended.set()
            self._messages.put(None)

    def _adopt(self, item_id: int) -> None:
        """This handle's queue item is ``item_id``: take what came for it already."""
        with self._lock:
            self._item_id = item_id
            early, self._early = self._early, []
        for msg in early:
            self._deliver(msg)

    def _deliver(self, msg: Message) -> None:
        if self._take(msg):
            self._messages.put(msg)
            if self._on_event is not None:
                self._on_event(msg)

    def _take(self, msg: Message) -> bool:
        """Whether ``msg`` belongs to this handle's run; updates the state."""
        d = msg.data
        with self._lock:
            if self._item_id is None:  # ours is not known yet: keep what might be
                self._early.append(msg)
                return False
            if msg.type == "run_started" and d.get("item_id") == self._item_id:
                self._ours, self._path, self._state = True, d["path"], "running"
                self._n, self._t0 = (int(d["n_done"]), int(d["n_total"])), time.monotonic()
                return True
            if msg.type == _END and d.get("item_id") == self._item_id:
                self.outcome = d.get("outcome")
                self._path = d.get("run_file") or self._path
                if self._state in ("queued", "running", "paused"):
                    self._state = str(self.outcome)
                self._ended.set()
                return True
            if not self._ours:
                return False
            if msg.type == "progress":
                self._n = (int(d["n_done"]), int(d["n_total"]))
            elif msg.type == "paused":
                self._state = "paused"
            elif msg.type == "resumed":
                self._state = "running"
            elif msg.type == "run_finished":
                self._state, self._ours = str(d["status"]), False
                self._n = (int(d["n_done"]), int(d["n_total"]))
            return msg.type in ("points", "progress", "fault", "paused", "resumed",
                                "run_finished", "axis_homed")

    # the surface of RunHandle -------------------------------------------------------------
    @property
    def path(self) -> str | None:
        return self._path

    @property
    def status(self) -> str:
        return self._state

    @property
    def done(self) -> bool:
        return self._ended.is_set()

    @property
    def progress(self) -> RunProgress:
        with self._lock:
            elapsed = 0.0 if self._t0 is None else time.monotonic() - self._t0
            return RunProgress(self._n[0], self._n[1], elapsed, self._state)

    def pause(self) -> None:
        """Pause the run at the next point boundary."""
        self._client.pause()

    def resume(self, answer: str = "resume") -> None:
        """Continue a paused run (after a device fault: ``"retry"`` or ``"skip"``)."""
        self._client.resume(answer)

    def abort(self) -> None:
        """Stop the run now (motion stopped, light off, file closed resumable)."""
        self._client.abort()

    def wait(self, timeout: float | None = None, *, show: bool = False) -> str:
        """Block until the run has ended; returns its outcome.

        Raises :class:`RunTimeout` after ``timeout`` seconds (the run goes on), and
        :class:`ClientError` when the connection to the server was lost.
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        last = None
        while not self._ended.wait(0.5 if deadline is None
                                   else max(0.0, min(0.5, deadline - time.monotonic()))):
            if show and self._n != last:
                last = self._n
                print(f"\r{self._state}: {self._n[0]}/{self._n[1]} points", end="",
                      flush=True)
            if deadline is not None and time.monotonic() >= deadline:
                raise RunTimeout(f"the run was not over after {timeout:g} s (it goes on)")
        if show:
            print(f"\r{self._state}: {self._n[0]}/{self._n[1]} points", flush=True)
        if self.outcome is None and self._error is not None:
            raise self._error
        self._close()
        return self._state

    def events(self, timeout: float | None = None) -> Iterator[Message]:
        """This run's messages from the server's event stream (``points``, ``progress``,
        ``fault``, ``paused``, ``resumed``, ``run_finished``, then ``item_finished``), as
        they come; ends with the run. ``timeout``: seconds to wait for each message."""
        while True:
            try:
                msg = self._messages.get(timeout=timeout)
            except queue.Empty:
                raise RunTimeout(f"no message for {timeout:g} s (the run goes on)") from None
            if msg is None:
                return
            yield msg
            if msg.type == _END:
                return

    def result(self) -> Run:
        """Wait for the end and open the run file (downloaded)."""
        self.wait()
        if self._path is None:
            raise ClientError(0, f"the queue item {self._item_id} made no run file "
                              f"({self.outcome})")
        return self._bench.open_run(self._path)

    def _close(self) -> None:
        self._stream.close()

    def __repr__(self) -> str:
        return f"<RemoteHandle item {self._item_id}: {self._state}>"
