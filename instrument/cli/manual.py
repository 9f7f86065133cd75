"""``scatterlab manual home|jog|move|light|stop-all``: manual commands on the bench server.

Each is one request; the server judges it with the same guard as the GUI's manual moves
(:mod:`instrument.bench.manual`) and the same control lease as every other operator
command (Stop all excepted: any operator may always stop). A refusal is one line on
stderr — the guard's reasons included — and exit status 2; nothing moved.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from instrument.cli._client import add_server, call

if TYPE_CHECKING:
    from instrument.client import BenchClient

HELP = "manual commands on the bench server: home, jog, move, light, stop-all (guarded)"


def _target(text: str) -> tuple[str, float]:
    """``ROLE=VALUE`` as (role, value)."""
    role, sep, value = text.partition("=")
    try:
        if not sep or not role:
            raise ValueError
        return role, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give ROLE=VALUE, e.g. sample_theta=30 (axis units)") from None


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("manual", help=HELP, description=__doc__.splitlines()[0])
    acts = p.add_subparsers(dest="action", metavar="ACTION")
    acts.required = True
    home = acts.add_parser("home", help="home one axis")
    home.add_argument("role", help="the axis's role in the bench profile, e.g. sample_theta")
    jog = acts.add_parser("jog", help="move one homed axis by a step")
    jog.add_argument("role", help="the axis's role, e.g. detector_theta")
    jog.add_argument("step", type=float, help="the step, axis units (negative: backwards)")
    move = acts.add_parser("move", help="move homed axes to absolute targets")
    move.add_argument("targets", nargs="+", type=_target, metavar="ROLE=VALUE",
                      help="targets, axis units, e.g. sample_theta=30 detector_theta=-45")
    light = acts.add_parser("light", help="turn the light source on or off")
    light.add_argument("state", choices=("on", "off"))
    acts.add_parser("stop-all", help="stop every axis now (during a run: abort it); "
                    "allowed to every operator, whoever holds control")
    for q in acts.choices.values():
        add_server(q)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    def act(c: BenchClient) -> int:
        if args.action == "home":
            message = c.home(args.role)
        elif args.action == "jog":
            message = c.jog(args.role, args.step)
        elif args.action == "move":
            targets = dict(args.targets)
            if len(targets) != len(args.targets):
                print("error: an axis is named twice", file=sys.stderr)
                return 2
            message = c.move_to(**targets)
        elif args.action == "light":
            message = c.light(args.state == "on")
        else:
            message = c.stop_all()
        print(message)
        return 0
    return call(args, act, one_line=True)
