"""``scatterlab manual home|jog|move|light|set|stop-all``: manual commands on the bench
server.

Each is one request; the server judges it with the same guard as the GUI's manual moves
(:mod:`instrument.bench.manual`) and the same control lease as every other operator
command (Stop all excepted: any operator may always stop). A refusal is one line on
stderr — the guard's reasons included — and exit status 2; nothing moved.

``set DEVICE FIELD=VALUE…`` changes a lock-in's, filter wheel's or power meter's settings
(``scatterlab manual set filter_wheel position=3``, ``… lockin sensitivity_v=0.001
auto_range=true``). The server answers at once and applies it on its settings worker;
this command waits for the outcome (the ``device_settings`` event), up to ``--timeout``.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING

from instrument.cli._client import add_server, call

if TYPE_CHECKING:
    from instrument.client import BenchClient

HELP = ("manual commands on the bench server: home, jog, move, light, set (device "
        "settings), stop-all (guarded)")
#: Seconds ``manual set`` waits for its outcome by default (a wheel move, an auto-range).
SET_TIMEOUT_S = 120.0


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


def _setting(text: str) -> tuple[str, bool | int | float | str]:
    """``FIELD=VALUE`` with VALUE as JSON would carry it: true/false, an integer, a
    number, else the text."""
    name, sep, raw = text.partition("=")
    if not sep or not name or not raw:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give FIELD=VALUE, e.g. position=3 or sensitivity_v=1e-3")
    if raw.lower() in ("true", "false"):
        return name, raw.lower() == "true"
    for kind in (int, float):
        try:
            return name, kind(raw)
        except ValueError:
            pass
    return name, raw


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
    dev = acts.add_parser("set", help="change a lock-in's, filter wheel's or power meter's "
                          "settings and wait for the outcome")
    dev.add_argument("device", help="the device's role in the bench profile, e.g. "
                     "filter_wheel")
    dev.add_argument("changes", nargs="+", type=_setting, metavar="FIELD=VALUE",
                     help="lock-in: sensitivity_v, time_constant_s, reference_source, "
                     "auto_range=true; filter wheel: position, speed; power meter: "
                     "wavelength_nm, averaging, auto_range=true|false, zero=true")
    dev.add_argument("--timeout", type=float, default=SET_TIMEOUT_S, metavar="S",
                     help=f"seconds to wait for the outcome (default: {SET_TIMEOUT_S:g})")
    dev.add_argument("--no-wait", action="store_true",
                     help="print the request id and return at once")
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
        elif args.action == "set":
            return _set(c, args)
        else:
            message = c.stop_all()
        print(message)
        return 0
    return call(args, act, one_line=True)


def _set(c: BenchClient, args: argparse.Namespace) -> int:
    """Send the change; unless ``--no-wait``, follow the event stream (opened first, so
    the outcome cannot pass unseen) until the request's end."""
    changes = dict(args.changes)
    if len(changes) != len(args.changes):
        print("error: a field is named twice", file=sys.stderr)
        return 2
    if args.no_wait:
        print(c.device_settings(args.device, **changes)["message"])
        return 0
    with c.open_events() as stream:
        accepted = c.device_settings(args.device, **changes)
        print(accepted["message"])
        deadline = time.monotonic() + max(0.0, args.timeout)
        while (left := deadline - time.monotonic()) > 0:
            try:
                msg = stream.recv(timeout_s=min(left, 1.0))
            except EOFError:
                break
            if msg is None or msg.type != "device_settings" or \
                    msg.data.get("request_id") != accepted["request_id"] or \
                    msg.data.get("state") == "applying":
                continue
            done = msg.data.get("state") == "done"
            print(msg.data.get("message", ""), file=sys.stdout if done else sys.stderr)
            return 0 if done else 2
    print(f"error: no outcome of request {accepted['request_id']} within "
          f"{args.timeout:g} s (the device may still be busy: scatterlab watch shows it)",
          file=sys.stderr)
    return 4
