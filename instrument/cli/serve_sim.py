"""``scatterlab serve-sim``: serve the bench's emulated controllers on pseudo-terminals.

A driver in another process (or another program) opens the printed paths with plain
``serial.Serial(path)``. Runs until interrupted or for ``--duration`` seconds.

The pty numbers change from one start to the next; ``--link-dir DIR`` also makes a stable
symbolic link ``DIR/<role>`` to each, so a bench profile can name the ports by role
(``examples/bench_serve_sim.toml`` uses ``/tmp/scatterlab-ptys``), the way a real bench
names its adapters by ``/dev/serial/by-id``. The links are removed on exit.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import time
from pathlib import Path

PTY_ENTRY = ("hw_mocks.pty_server", "serve_url")
HELP = "serve the emulated serial controllers on ptys"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("serve-sim", help=HELP)
    p.add_argument("--bench", default="sim", help="profile name or path (default: sim)")
    p.add_argument("--duration", type=float, default=None,
                   help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--link-dir", default=None, metavar="DIR",
                   help="also make a link DIR/<role> to each pty (stable names for a "
                        "profile; removed on exit)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from instrument.bench.devices import serial_emulator_schemes
    from instrument.bench.profile import load_profile

    profile = load_profile(args.bench)
    module, func = PTY_ENTRY
    serve_url = getattr(importlib.import_module(module), func)
    servers = []
    links: list[Path] = []
    try:
        schemes = serial_emulator_schemes()  # every driver's emulator, plugins' too
        for role, spec in profile.devices.items():
            handlers = schemes.get(spec.url.split("://", 1)[0])
            if handlers is not None:
                server = serve_url(spec.url, handlers=handlers)
                servers.append(server)
                where = server.path
                if args.link_dir is not None:
                    links.append(_link(Path(args.link_dir), role, server.path))
                    where += f" (link {links[-1]})"
                print(f"{role}: {spec.url} -> {where}", flush=True)
        if not servers:
            print("this bench has no emulated serial controllers")
            return 1
        print("serving; press Ctrl-C to stop", flush=True)
        deadline = None if args.duration is None else time.monotonic() + args.duration
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    except OSError as err:
        print(f"error: --link-dir {args.link_dir}: {err}")
        return 2
    finally:
        for link in links:
            with contextlib.suppress(OSError):
                link.unlink()
        for server in servers:
            server.close()
    return 0


def _link(folder: Path, role: str, target: str) -> Path:
    """``folder/role`` → ``target``, replacing a stale link of an earlier run (never a
    file that is not a link)."""
    folder.mkdir(parents=True, exist_ok=True)
    link = folder / role
    if link.is_symlink():
        link.unlink()
    elif link.exists():
        raise OSError(f"{link} exists and is not a link; choose another folder")
    link.symlink_to(target)
    return link
