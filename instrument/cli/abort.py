"""``scatterlab abort``: abort the bench server's run (it stays at the head of the queue,
resumable) and stop the queue."""

from __future__ import annotations

import argparse

from instrument.cli._client import add_server, call

HELP = "abort the bench server's run (it stays at the head, resumable)"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("abort", help=HELP)
    add_server(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    return call(args, lambda c: print(c.abort()))
