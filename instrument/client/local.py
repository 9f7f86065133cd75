"""A bench server on this PC for a client that found none: started as a child process.

``scatterlab gui`` without ``--server`` (and without ``SCATTERLAB_SERVER``) uses the local
server of its runs folder: the one it (or an earlier GUI) started, if it still answers,
or a new one — ``scatterlab serve --bench PROFILE --listen 127.0.0.1:0 --runs DIR
--nice 10`` in a process group of its own (so it outlives the GUI, and a Ctrl-C in the
GUI's terminal does not reach it) at a lower CPU priority (the window gets the CPU first
during a fast scan). It stays in the GUI's session, not a new one: with the scheduler's
autogroups a niceness ranks a process only against those of its own session
(``instrument.server.priority``). Its output goes to
``DIR/local-server.log``. ``DIR/local-server.json`` records its address and process id for
the next GUI and for :func:`stop_local_server`.

Only the standard library (and :mod:`instrument.client` for the health check): the
server's code is never imported into the client's process.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

__all__ = ["LOCAL_LOG", "LOCAL_NICE", "LOCAL_STATE", "LocalServer", "LocalServerError",
           "local_server", "stop_local_server"]

LOCAL_STATE = "local-server.json"
LOCAL_LOG = "local-server.log"
#: The niceness of a local server (``scatterlab serve --nice``): the GUI on the same PC
#: gets a CPU first while a fast scan keeps the server's threads busy; an idle GUI costs the
#: run nothing (docs/decisions/0084, amendment on the local server's priority).
LOCAL_NICE = 10
_SERVING = re.compile(r"serving bench '(?P<bench>.*)' on (?P<url>https?://\S+) ")


class LocalServerError(RuntimeError):
    """The local server could not be started (the message quotes its output)."""


@dataclass(frozen=True)
class LocalServer:
    """A server on loopback: its address, process id, bench, and whether this call
    started it."""

    url: str
    pid: int
    bench: str
    runs_dir: Path
    started: bool

    def alive(self) -> bool:
        return _alive(self.pid)

    def stop(self, timeout_s: float = 60.0) -> bool:
        """SIGTERM (a run in progress is aborted, resumable); whether it ended in time
        (then its record in the runs folder is removed)."""
        ended = _terminate(self.pid, timeout_s)
        if ended:
            _forget(self.runs_dir, self.pid)
        return ended


def _forget(runs: Path, pid: int) -> None:
    """Remove the record of the local server ``pid`` (not a newer server's)."""
    rec = _recorded(runs)
    if rec is not None and int(rec.get("pid", -1)) == pid:
        with contextlib.suppress(OSError):
            (runs / LOCAL_STATE).unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    with contextlib.suppress(ChildProcessError):
        done, _ = os.waitpid(pid, os.WNOHANG)  # our own child that exited: reap it
        if done == pid:
            return False
    return True


def _terminate(pid: int, timeout_s: float) -> bool:
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not _alive(pid):
            return True
        time.sleep(0.1)
    return False


def _answers(url: str, key: str | None) -> bool:
    from instrument.client import BenchClient, ClientError

    try:
        with BenchClient(url, key, timeout_s=10.0) as client:
            client.status()
        return True
    except ClientError as err:
        return err.status != 0  # it answered, if only to refuse the key


def _recorded(runs_dir: Path) -> dict[str, Any] | None:
    try:
        # the state file is the JSON object this module writes
        return cast(dict[str, Any],
                    json.loads((runs_dir / LOCAL_STATE).read_text(encoding="utf-8")))
    except (OSError, ValueError):
        return None


def local_server(bench: str, runs_dir: str | Path, *, key: str | None = None,
                 timeout_s: float = 120.0, python: str = sys.executable,
                 nice: int = LOCAL_NICE) -> LocalServer:
    """The local server of ``runs_dir``: the recorded one if it is alive and answers (for
    any bench: the runs folder has one owner), else a new one for ``bench``, at niceness
    ``nice`` (:data:`LOCAL_NICE`: below the GUI's priority).

    Raises
    ------
    LocalServerError
        The new server exited or did not say where it listens within ``timeout_s``.
    """
    runs = Path(runs_dir).resolve()
    runs.mkdir(parents=True, exist_ok=True)
    rec = _recorded(runs)
    if rec and _alive(int(rec["pid"])) and _answers(rec["url"], key):
        return LocalServer(rec["url"], int(rec["pid"]), rec.get("bench", ""), runs, False)
    log_path = runs / LOCAL_LOG
    with open(log_path, "w", encoding="utf-8") as log:
        proc = subprocess.Popen(
            [python, "-m", "instrument.cli", "serve", "--bench", str(bench),
             "--listen", "127.0.0.1:0", "--runs", str(runs), "--nice", str(nice)],
            stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            # its own process group (POSIX): the terminal's Ctrl-C and hang-up go to the
            # GUI's group, not to it
            process_group=0 if os.name == "posix" else None,
            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    deadline = time.monotonic() + timeout_s
    while True:
        text = log_path.read_text(encoding="utf-8", errors="replace")
        m = _SERVING.search(text)
        if m:
            break
        if proc.poll() is not None or time.monotonic() > deadline:
            if proc.poll() is None:
                _terminate(proc.pid, 10.0)
            tail = "\n".join(text.splitlines()[-15:])
            raise LocalServerError(f"the local server for bench {bench!r} did not start "
                                   f"(its output, {log_path}):\n{tail}")
        time.sleep(0.1)
    server = LocalServer(m["url"], proc.pid, m["bench"], runs, True)
    (runs / LOCAL_STATE).write_text(json.dumps(
        {"url": server.url, "pid": server.pid, "bench": server.bench}), encoding="utf-8")
    return server


def stop_local_server(runs_dir: str | Path, timeout_s: float = 60.0) -> str:
    """Stop the local server recorded in ``runs_dir`` (SIGTERM: a run in progress is
    aborted and stays resumable); a sentence saying what happened."""
    runs = Path(runs_dir).resolve()
    rec = _recorded(runs)
    if not rec or not _alive(int(rec["pid"])):
        return f"no local server is running for {runs}"
    ok = _terminate(int(rec["pid"]), timeout_s)
    if ok:
        _forget(runs, int(rec["pid"]))
        return f"stopped the local server (process {rec['pid']}) at {rec['url']}"
    return f"the local server (process {rec['pid']}) did not stop within {timeout_s:.0f} s"
