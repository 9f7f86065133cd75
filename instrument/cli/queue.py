"""``scatterlab queue add|list|remove|move|start|stop|approve|deny|history``: the bench
server's plan queue (a client command: ``--server URL`` or ``$SCATTERLAB_SERVER``)."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from instrument.cli._client import add_server, call

if TYPE_CHECKING:
    from instrument.client import BenchClient

HELP = "the bench server's plan queue: add, list, remove, move, start, stop"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("queue", help=HELP)
    acts = p.add_subparsers(dest="action", metavar="ACTION")
    acts.required = True
    a = acts.add_parser("add", help="add plan files (in order), or a stop marker")
    a.add_argument("plans", nargs="*", help="plan files (TOML)")
    a.add_argument("--stop", action="store_true", help="add a stop marker (after the plans)")
    a.add_argument("--propose", action="store_true",
                   help="propose the plans for an operator to approve (observer keys)")
    acts.add_parser("list", help="the queue, in order")
    acts.add_parser("history", help="every item's outcome and run file")
    for name, what in (("remove", "remove an item"), ("approve", "approve a proposal"),
                       ("deny", "deny a proposal")):
        r = acts.add_parser(name, help=what)
        r.add_argument("item", type=int, help="item id (scatterlab queue list)")
    m = acts.add_parser("move", help="move an item to a place (0: the head)")
    m.add_argument("item", type=int)
    m.add_argument("index", type=int)
    acts.add_parser("start", help="run the queue (resumes an interrupted or aborted head)")
    acts.add_parser("stop", help="stop the queue after the run in progress")
    for q in acts.choices.values():
        add_server(q)  # on each action (argparse: a sub-parser's default would win)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    return call(args, lambda c: ACTIONS[args.action](c, args))


def _add(c: BenchClient, args: argparse.Namespace) -> int:
    if not args.plans and not args.stop:
        print("error: give plan files, or --stop", file=sys.stderr)
        return 2
    for path in args.plans:
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as err:
            print(f"error: {path}: {err.strerror or err}", file=sys.stderr)
            return 2
        item = c.propose(text) if args.propose else c.add_plan(text)
        print(f"{'proposed' if args.propose else 'added'} item {item['id']}: {item['name']}")
    if args.stop:
        print(f"added item {c.add_stop()['id']}: stop marker")
    return 0


def print_items(items: list[dict[str, Any]], running: bool) -> None:
    print(f"queue {'running' if running else 'stopped'}: {len(items)} item(s)")
    for k, i in enumerate(items):
        extra = f"  {i['run_file']}" if i.get("run_file") else ""
        flag = " (resumable)" if i.get("resumable") else ""
        print(f"  {k:>2}  #{i['id']:<4} {i['state']:<11} {i['name']}  [by {i['added_by']}]"
              f"{flag}{extra}")


def _list(c: BenchClient, args: argparse.Namespace) -> int:
    q = c.queue()
    print_items(q["items"], q["running"])
    return 0


def _history(c: BenchClient, args: argparse.Namespace) -> int:
    for h in c.history():
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(h["time"]))
        run_file = f"  {h['run_file']}" if h["run_file"] else ""
        note = f"  ({h['note']})" if h["note"] else ""
        print(f"{when}  #{h['item_id']:<4} {h['outcome']:<12} {h['name']}{run_file}{note}")
    return 0


ACTIONS: dict[str, Callable[[BenchClient, argparse.Namespace], int | None]] = {
    "add": _add,
    "list": _list,
    "history": _history,
    "remove": lambda c, a: print(c.remove(a.item)),
    "approve": lambda c, a: print(c.approve(a.item)),
    "deny": lambda c, a: print(c.deny(a.item)),
    "move": lambda c, a: print(c.move(a.item, a.index)),
    "start": lambda c, a: print(c.start_queue()),
    "stop": lambda c, a: print(c.stop_queue()),
}
