"""What the client commands (queue, status, watch, pause, abort, resume) share: the server's
address and key, and one line for every refusal."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

ENV_SERVER = "SCATTERLAB_SERVER"  # instrument.client.ENV_SERVER, without importing httpx


def add_server(p: argparse.ArgumentParser) -> None:
    p.add_argument("--server", default=None, metavar="URL",
                   help=f"the bench server, e.g. http://127.0.0.1:8765 (default: "
                   f"${ENV_SERVER}); the key is read from $SCATTERLAB_KEY")


def call(args: argparse.Namespace, fn: Callable[[Any], int | None], *, one_line: bool = False
         ) -> int:
    """Run ``fn(client)``; a refusal or an unreachable server is reported on stderr (exit 2
    for a refusal, 3 when the server cannot be reached). ``one_line``: the refusal's
    reasons (a guard's violations) go on the same line as its message, each once."""
    from instrument.client import BenchClient, ClientError

    try:
        with BenchClient(args.server) as client:
            return int(fn(client) or 0)
    except ClientError as err:
        print(f"error: {refusal_line(err) if one_line else err}", file=sys.stderr)
        return 3 if err.status == 0 else 2


def refusal_line(err: Any) -> str:
    """A :class:`~instrument.client.ClientError` as one line: its message, the reasons it
    does not already state, and the HTTP status."""
    extra = [r for r in dict.fromkeys(err.reasons) if r not in err.message]
    text = "; ".join([err.message, *extra])
    return " ".join(text.split()) + (f" (HTTP {err.status})" if err.status else "")
