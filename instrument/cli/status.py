"""``scatterlab status``: the bench server's state: bench, run, queue, who holds control."""

from __future__ import annotations

import argparse
import time
from typing import TYPE_CHECKING

from instrument.cli._client import add_server, call

if TYPE_CHECKING:
    from instrument.client import BenchClient

HELP = "the bench server's state: run, queue, control"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("status", help=HELP)
    add_server(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    return call(args, _status)


def _status(c: BenchClient) -> int:
    from instrument.cli.queue import print_items

    s = c.status()
    print(f"server: bench {s['bench']!r} ({'connected' if s['connected'] else 'disconnected'})"
          f", runs in {s['runs_dir']}; you are {s['you']['name']} ({s['you']['role']})")
    ctl = s["control"]
    if ctl["holder"]:
        until = time.strftime("%H:%M:%S", time.localtime(ctl["until"]))
        print(f"control: held by {ctl['holder']} until {until}")
    else:
        print("control: free")
    r = s["run"]
    if r is None:
        print("run: none")
    else:
        line = f"run: {r['state']}, {r['n_done']}/{r['n_total']} points, {r['path']}"
        if r["pause_reason"]:
            line += f"\n  paused: {r['pause_reason']}; answers: {', '.join(r['answers'])}"
        print(line)
    print_items(s["queue"], s["queue_running"])
    return 0
