"""``scatterlab serve --bench PROFILE``: run the bench server (one process owns the bench;
the queue, run control and manual moves are served to clients), and its local
administration: ``serve keys add|list|revoke`` and ``serve audit``, which read and write
``server.sqlite`` in the runs folder directly (on the bench PC, server running or not)."""

from __future__ import annotations

import argparse
import sys
import time

from instrument.run.paths import DEFAULT_RUNS_DIR

HELP = "run the bench server (queue, run control, events); serve keys | audit"

DEFAULT_LISTEN = "127.0.0.1:8765"  # instrument.server.main.DEFAULT_LISTEN (no import here)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("serve", help=HELP)
    p.add_argument("--bench", default="sim", help="bench profile name or path (default: sim)")
    p.add_argument("--listen", default=DEFAULT_LISTEN, metavar="HOST:PORT",
                   help=f"address to listen on (default: {DEFAULT_LISTEN}; any address but "
                   "loopback needs --tls-cert, --tls-key and API keys; port 0 picks one)")
    _runs(p, top=True)
    p.add_argument("--tls-cert", default=None, metavar="CERT.pem")
    p.add_argument("--tls-key", default=None, metavar="KEY.pem")
    p.add_argument("--allow", action="append", default=[], metavar="DIR",
                   help="a folder besides --runs whose files plans may name (repeatable)")
    p.add_argument("--require-keys", action="store_true",
                   help="every request needs an API key, also on loopback before the first "
                   "key exists (without it, a loopback server with no keys treats every "
                   "local client as admin)")
    p.add_argument("--nice", type=int, default=0, metavar="N",
                   help="run at a lower CPU priority, niceness raised by N (0-19; default: "
                   "0). A local server started by `scatterlab gui` uses 10, so the window "
                   "stays responsive while a fast scan keeps the CPUs busy")
    p.add_argument("--no-fsync", action="store_true",
                   help="do not force each point to stable storage (still safe against a "
                   "crash of the server, not of the computer)")
    cmds = p.add_subparsers(dest="serve_cmd", metavar="{keys,audit}")
    keys = cmds.add_parser("keys", help="API keys: add, list, revoke")
    kc = keys.add_subparsers(dest="keys_cmd", metavar="{add,list,revoke}")
    kc.required = True
    add = kc.add_parser("add", help="make a key (its token is shown once)")
    add.add_argument("--role", required=True, choices=("observer", "operator", "admin"))
    add.add_argument("--name", required=True, help="who holds the key")
    add.add_argument("--expires", default=None, metavar="DAYS|YYYY-MM-DD",
                     help="when the key stops working: a number of days, or a date")
    _runs(add)
    _runs(kc.add_parser("list", help="every key: id, holder, role, state"))
    rev = kc.add_parser("revoke", help="revoke a key by id")
    rev.add_argument("id", type=int)
    _runs(rev)
    audit = cmds.add_parser("audit", help="the audit log: who changed what, when, result")
    audit.add_argument("--limit", type=int, default=50, help="newest N rows (default: 50)")
    _runs(audit)
    p.set_defaults(func=run)


def _runs(p: argparse.ArgumentParser, *, top: bool = False) -> None:
    # given before or after `keys ...`/`audit`: a sub-parser's own default must not hide
    # the value given to `serve`
    p.add_argument("--runs", default=str(DEFAULT_RUNS_DIR) if top else argparse.SUPPRESS,
                   help=f"folder of run files, the catalog and server.sqlite (default: "
                   f"{DEFAULT_RUNS_DIR})")


def run(args: argparse.Namespace) -> int:
    if args.serve_cmd == "keys":
        return _keys(args)
    if args.serve_cmd == "audit":
        return _audit(args)
    from instrument.server.main import ServeRefused, serve

    try:
        return serve(args.bench, listen=args.listen, runs=args.runs, cert=args.tls_cert,
                     key=args.tls_key, allow=args.allow, fsync=not args.no_fsync,
                     require_keys=args.require_keys, nice=args.nice)
    except ServeRefused as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


def parse_expiry(text: str | None, now: float | None = None) -> float | None:
    """``--expires``: days from now (``30``, ``0.5``) or a date (``2027-01-31``, local
    midnight). Raises ValueError naming the option."""
    if text is None:
        return None
    now = time.time() if now is None else now
    try:
        days = float(text)
    except ValueError:
        try:
            return time.mktime(time.strptime(text, "%Y-%m-%d"))
        except ValueError:
            raise ValueError(f"--expires {text!r}: give a number of days or a date "
                             "YYYY-MM-DD") from None
    if not days > 0:
        raise ValueError(f"--expires {text!r}: must be more than 0 days")
    return now + days * 86400.0


def _t(t: float | None) -> str:
    return "-" if t is None else time.strftime("%Y-%m-%d %H:%M", time.localtime(t))


def _keys(args: argparse.Namespace) -> int:
    from instrument.server.db import ServerDB
    from instrument.server.keys import KeyStore

    with ServerDB(args.runs) as db:
        store = KeyStore(db)
        try:
            if args.keys_cmd == "add":
                key, token = store.add(args.name, args.role,
                                       expires=parse_expiry(args.expires))
                print(f"key {key.id} for {key.name} ({key.role}), expires "
                      f"{_t(key.expires) if key.expires else 'never'}:")
                print(f"  {token}")
                print("give it to its holder now: it is not stored and cannot be shown "
                      "again (the holder sets SCATTERLAB_KEY to it)")
            elif args.keys_cmd == "list":
                now = time.time()
                print("  id  role      state    expires           name")
                for k in store.list():
                    print(f"{k.id:>4}  {k.role:<9} {k.state(now):<8} {_t(k.expires):<17} "
                          f"{k.name}")
            else:
                key = store.revoke(args.id)
                print(f"key {key.id} of {key.name} ({key.role}) revoked")
        except (ValueError, KeyError) as err:
            print(f"error: {err.args[0]}", file=sys.stderr)
            return 2
    return 0


def _audit(args: argparse.Namespace) -> int:
    from instrument.server.audit import AuditLog
    from instrument.server.db import ServerDB

    with ServerDB(args.runs) as db:
        rows = AuditLog(db).rows(limit=max(1, args.limit))
    for r in rows:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(r.time))
        who = f"{r.who} ({r.role})" if r.role else r.who
        print(f"{when}  {who:<24} {r.what:<36} {r.status}  {r.result}")
    if not rows:
        print("the audit log is empty")
    return 0
