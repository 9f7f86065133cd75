"""``scatterlab watch``: the bench server's runs live in the terminal: progress, faults
and what they need, the queue's items as they end. Ctrl-C stops watching (the run goes on)."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, TextIO, cast

from instrument.cli._client import add_server, call

if TYPE_CHECKING:
    from instrument.client import BenchClient
    from instrument.protocol import Message

HELP = "watch the bench server's runs live: progress and faults"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("watch", help=HELP)
    add_server(p)
    p.add_argument("--until-idle", action="store_true",
                   help="stop when the queue has stopped and no run is going on")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        return call(args, lambda c: watch(c, until_idle=args.until_idle))
    except KeyboardInterrupt:
        print("\nstopped watching; the server goes on", file=sys.stderr)
        return 0


def line_for(msg: Message) -> str | None:
    """What the terminal shows for one event message (None: nothing)."""
    d = msg.data
    match msg.type:
        case "hello":
            s = d["status"]
            run = s.get("run")
            now = (f"run {run['state']} {run['n_done']}/{run['n_total']}" if run
                   else "no run")
            return (f"watching bench {d['bench']!r} as {d['name']} ({d['role']}): {now}; "
                    f"queue {'running' if s['queue_running'] else 'stopped'} with "
                    f"{len(s['queue'])} item(s)")
        case "run_started":
            return (f"run started: {d['run_id']} ({d['n_done']}/{d['n_total']} points done) "
                    f"-> {d['path']}")
        case "progress":
            eta = d.get("eta_s")
            return (f"  {d['n_done']}/{d['n_total']} points"
                    + (f", about {eta:.0f} s left" if eta is not None else ""))
        case "fault":
            where = "" if d["index"] is None else f" at point {d['index'] + 1}"
            return f"FAULT {d['device']}{where}: {d['cause']} -> {d['action']}"
        case "paused":
            answers = ", ".join(d.get("answers", []))
            return (f"PAUSED: {d['reason']}; answer with scatterlab resume (--answer retry|"
                    f"skip) or scatterlab abort [{answers}]")
        case "resumed":
            return "resumed"
        case "run_finished":
            return (f"run {d['status']}: {d['n_done']}/{d['n_total']} points "
                    f"({d['n_skipped']} skipped) {d['message']}")
        case "second_pass":
            return f"queue item #{d['item_id']} second pass {d['state']}: {d['message']}"
        case "item_finished":
            return f"queue item #{d['item_id']} {d['name']}: {d['outcome']}"
        case "control":
            return f"control: {d['holder'] or 'free'}"
        case "manual":
            return f"{d['who']}: {d['what']}: {d['message']}"
        case "bench":
            return cast(str | None, d["message"])
        case "missed":
            counts = ", ".join(f"{n} {t}" for t, n in d["counts"].items())
            return f"(fell behind: missed {counts})"
    return None


def watch(client: BenchClient, *, until_idle: bool = False, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    last_progress = None
    running = True
    active = False
    for msg in client.events():
        if msg.type == "hello":
            running = msg.data["status"]["queue_running"]
            active = msg.data["status"]["run"] is not None
        elif msg.type == "queue":
            running = msg.data["running"]
        elif msg.type == "run_started":
            active = True
        elif msg.type == "run_finished":
            active = False
        if msg.type == "progress":
            # one line per tenth of the run at most: a terminal, not a plot
            step = max(1, msg.data["n_total"] // 10)
            bucket = msg.data["n_done"] // step
            if bucket == last_progress and msg.data["n_done"] != msg.data["n_total"]:
                continue
            last_progress = bucket
        text = line_for(msg)
        if text:
            print(text, file=out, flush=True)
        if until_idle and not running and not active:
            return 0
    print("the server closed the event stream", file=out)
    return 1
