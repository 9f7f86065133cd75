"""Starting the server: where it listens, what it refuses to start without, uvicorn.

Loopback (127.0.0.0/8, ::1, ``localhost``) is the default. Any other address needs TLS
(a certificate and its key) and at least one valid API key; otherwise the server does not
start and :class:`ServeRefused` says what is missing (docs/decisions/0082).

On loopback without keys every request acts as the local admin, unauthenticated (a
one-PC bench, as anyone at its keyboard could before); the server says so at start-up,
with how to change it. ``--require-keys`` turns that off: every request needs a key, from
the first one, even on loopback (:func:`access_lines`).
"""

from __future__ import annotations

import ipaddress
import socket
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from instrument.server.service import BenchService

__all__ = ["DEFAULT_LISTEN", "WS_OPTIONS", "Listen", "ServeRefused", "access_lines",
           "check_listen", "parse_listen", "serve"]

DEFAULT_LISTEN = "127.0.0.1:8765"

#: uvicorn's WebSocket settings. No permessage-deflate: compressing every event message
#: once per client (its own zlib stream each) was two thirds of the event loop's time with
#: 50 clients, on the CPU the engine needs (docs/decisions/0086); the event stream is a
#: few hundred kB/s per client at the engine's fastest, small for any lab network.
WS_OPTIONS: dict[str, Any] = {"ws": "websockets-sansio", "ws_per_message_deflate": False}


class ServeRefused(ValueError):
    """The server will not start as asked (the message says what to give)."""


@dataclass(frozen=True)
class Listen:
    host: str
    port: int

    @property
    def loopback(self) -> bool:
        if self.host == "localhost":
            return True
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return False


def parse_listen(text: str) -> Listen:
    """``HOST:PORT`` (``[::1]:PORT`` for IPv6; port 0 picks a free one)."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535 or not host:
        raise ServeRefused(f"--listen {text!r}: expected HOST:PORT, e.g. {DEFAULT_LISTEN}")
    return Listen(host.strip("[]"), int(port))


def check_listen(listen: Listen, *, cert: str | None, key: str | None,
                 has_keys: bool) -> None:
    """Refuse a non-loopback address without TLS and keys."""
    missing = []
    if (cert is None) != (key is None):
        raise ServeRefused("give both --tls-cert and --tls-key, or neither")
    for flag, path in (("--tls-cert", cert), ("--tls-key", key)):
        if path is not None and not Path(path).is_file():
            raise ServeRefused(f"{flag} {path}: no such file")
    if listen.loopback:
        return
    if cert is None:
        missing.append("TLS (--tls-cert CERT.pem --tls-key KEY.pem)")
    if not has_keys:
        missing.append("API keys (scatterlab serve keys add --role admin --name YOU)")
    if missing:
        raise ServeRefused(f"refusing to listen on {listen.host}, which is not loopback, "
                           f"without {' and '.join(missing)}; or listen on 127.0.0.1 and "
                           "reach it through an SSH tunnel")


def access_lines(listen: Listen, *, has_keys: bool, require_keys: bool) -> list[str]:
    """What the server says at start-up about who may do what without a key."""
    if require_keys or not listen.loopback:
        if has_keys:
            return ["every request needs an API key (Authorization: Bearer KEY)"]
        return ["every request needs an API key and none exists yet: add one on this PC "
                "with `scatterlab serve keys add --role admin --name YOU` (no restart "
                "needed)"]
    if has_keys:
        return ["every request needs an API key (keys exist); start with --require-keys "
                "to keep it so if every key is revoked"]
    return ["UNAUTHENTICATED: no API keys yet, so every client on this PC acts as admin "
            "(anyone logged in here, or through an SSH tunnel, may move the stages)",
            "to require keys: add one (`scatterlab serve keys add --role admin --name "
            "YOU`), or start with --require-keys"]


def _bind(listen: Listen) -> socket.socket:
    family = socket.AF_INET6 if ":" in listen.host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((listen.host, listen.port))
        sock.listen(2048)  # connections made as soon as the address is printed wait
    except OSError as err:
        sock.close()
        raise ServeRefused(f"--listen {listen.host}:{listen.port}: {err.strerror or err}") \
            from err
    return sock


def serve(profile_name: str, *, listen: str = DEFAULT_LISTEN, runs: str | Path,
          cert: str | None = None, key: str | None = None, allow: Sequence[str] = (),
          fsync: bool = True, require_keys: bool = False, nice: int = 0,
          say: Callable[[str], None] = print,
          make_service: Callable[..., BenchService] | None = None) -> int:
    """Run the server until SIGINT/SIGTERM; return an exit code.

    ``make_service(profile, runs_dir, fsync=..., allowed=...)`` builds the service
    (default :class:`~instrument.server.service.BenchService`; tests wrap it).
    ``require_keys``: every request needs a key, also on loopback before any key exists.
    ``nice``: run at this much lower CPU priority (:mod:`instrument.server.priority`;
    the local server a GUI starts uses it so that the window gets the CPU first).
    """
    from instrument.server.priority import lower_priority

    try:  # first, so that every thread the server starts inherits it
        niceness = lower_priority(nice)
    except (ValueError, OSError) as err:
        raise ServeRefused(str(err)) from None
    import uvicorn

    from instrument.bench.profile import load_profile
    from instrument.server.app import create_app
    from instrument.server.db import ServerDB
    from instrument.server.keys import KeyStore
    from instrument.server.service import BenchService

    where = parse_listen(listen)
    with ServerDB(runs) as db:
        has_keys = KeyStore(db).any_valid()
    check_listen(where, cert=cert, key=key, has_keys=has_keys)
    profile = load_profile(profile_name)
    sock = _bind(where)
    service = (make_service or BenchService)(profile, runs, fsync=fsync, allowed=allow)
    app = create_app(service, open_local=where.loopback and not require_keys)
    host, port = sock.getsockname()[:2]
    scheme = "https" if cert else "http"
    shown = f"[{host}]" if ":" in host else host
    for item in service.interrupted:
        say(f"queue item {item.id} ({item.name}) was interrupted: start the queue (or "
            "`scatterlab resume`) to continue its run file")
    say(f"serving bench {profile.name!r} on {scheme}://{shown}:{port} (runs in "
        f"{service.runs_dir}); Ctrl-C stops")
    say(f"web dashboard: {scheme}://{shown}:{port}/ (open it in a browser)")
    for line in access_lines(where, has_keys=has_keys, require_keys=require_keys):
        say(line)
    if nice:
        say(f"running at niceness {niceness}: the other programs of its session (the GUI "
            "that started it) get the CPU first when both want it")
    sys.stdout.flush()
    config = uvicorn.Config(app, log_level="warning", ssl_certfile=cert, ssl_keyfile=key,
                            lifespan="on", timeout_graceful_shutdown=5, **WS_OPTIONS)
    server = uvicorn.Server(config)
    server.run(sockets=[sock])
    return 0
