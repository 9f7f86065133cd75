"""``scatterlab pause [--now]``: pause the bench server's run at the end of the point in
progress, or at once (motion stopped, light off; resumable in the same file)."""

from __future__ import annotations

import argparse

from instrument.cli._client import add_server, call

HELP = "pause the bench server's run (at the end of the point, or --now)"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("pause", help=HELP)
    add_server(p)
    p.add_argument("--now", action="store_true",
                   help="stop at once instead of at the end of the point in progress")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    return call(args, lambda c: print(c.pause(now=args.now)))
