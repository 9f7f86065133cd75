"""``scatterlab serve-sim``: serve the bench's emulated controllers on pseudo-terminals.

A driver in another process (or another program) opens the printed paths with plain
``serial.Serial(path)``. Runs until interrupted or for ``--duration`` seconds.
"""

from __future__ import annotations

import argparse
import importlib
import time

PTY_ENTRY = ("hw_mocks.pty_server", "serve_url")
HELP = "serve the emulated serial controllers on ptys"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve-sim", help=HELP)
    p.add_argument("--bench", default="sim", help="profile name or path (default: sim)")
    p.add_argument("--duration", type=float, default=None,
                   help="stop after this many seconds (default: until Ctrl-C)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from instrument.bench.profile import load_profile

    profile = load_profile(args.bench)
    module, func = PTY_ENTRY
    serve_url = getattr(importlib.import_module(module), func)
    servers = []
    try:
        for role, spec in profile.devices.items():
            if spec.url.split("://", 1)[0] in ("simapt", "simsmc"):
                server = serve_url(spec.url)
                servers.append(server)
                print(f"{role}: {spec.url} -> {server.path}", flush=True)
        if not servers:
            print("this bench has no emulated serial controllers")
            return 1
        print("serving; press Ctrl-C to stop", flush=True)
        deadline = None if args.duration is None else time.monotonic() + args.duration
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    finally:
        for server in servers:
            server.close()
    return 0
