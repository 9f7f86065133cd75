"""``scatterlab control take|release|show``: the bench server's operator lease (one
operator holds control at a time; Stop all is allowed to every operator regardless)."""

from __future__ import annotations

import argparse
import time
from typing import TYPE_CHECKING

from instrument.cli._client import add_server, call

if TYPE_CHECKING:
    from instrument.client import BenchClient

HELP = "take, release or show the bench server's operator control"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("control", help=HELP)
    acts = p.add_subparsers(dest="action", metavar="ACTION")
    acts.required = True
    take = acts.add_parser("take", help="take (or renew) control")
    take.add_argument("--timeout", type=float, default=None, metavar="S",
                      help="seconds the lease lasts after your last command (default: the "
                      "server's, 300)")
    take.add_argument("--force", action="store_true",
                      help="take it from another operator (admin keys)")
    acts.add_parser("release", help="give control back")
    acts.add_parser("show", help="who holds control, until when")
    for q in acts.choices.values():
        add_server(q)
    p.set_defaults(func=run)


def _until(t: float | None) -> str:
    return time.strftime("%H:%M:%S", time.localtime(t)) if t else "-"


def run(args: argparse.Namespace) -> int:
    def act(c: BenchClient) -> int:
        if args.action == "take":
            lease = c.take_control(args.timeout, force=args.force)
            print(f"control held by {lease['holder']} until {_until(lease['until'])}")
        elif args.action == "release":
            print(c.release_control())
        else:
            ctl = c.status()["control"]
            print(f"control held by {ctl['holder']} until {_until(ctl['until'])}"
                  if ctl["holder"] else "control is free")
        return 0
    return call(args, act)
