"""``scatterlab gui``: the operator GUI (also installed as ``scatterlab-gui``).

The GUI package is imported only when this command runs, by name: the command line
never loads Qt for its other commands, and ``instrument`` does not depend on ``gui``
(the packages' layering, docs/architecture.md).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Any

from instrument.run.paths import DEFAULT_RUNS_DIR

HELP = ("the operator GUI: a client of the bench server (a local one is started if needed), "
        "or with --in-process the full window with the engine in the GUI")

#: The GUI's entry point, imported by name when the command runs.
GUI_ENTRY = "gui.app"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("gui", help=HELP)
    add_arguments(p)
    p.set_defaults(func=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bench", default=None,
                   help="bench profile name or path (default: the last one used, or sim)")
    p.add_argument("--out", default=None,
                   help=f"folder for run files and the catalog (default: the last one used, "
                   f"or {DEFAULT_RUNS_DIR})")
    p.add_argument("--server", default=None, metavar="URL",
                   help="the bench server to connect to (default: $SCATTERLAB_SERVER; "
                   "without either, the local server of --out, started for --bench if "
                   "none runs); the key is $SCATTERLAB_KEY")
    p.add_argument("--stop-server", action="store_true",
                   help="stop the local server of --out (a run in progress is aborted, "
                   "resumable) and exit")
    p.add_argument("--in-process", action="store_true",
                   help="open the full window with the engine in the GUI's process (no "
                   "server; closing the window ends a run): the plan's points on the "
                   "goniometer drawing, the camera's region of interest and the "
                   "analyses' remedies, which the client window does not have yet")


def gui_call(args: argparse.Namespace) -> tuple[str, dict[str, Any]]:
    """The function of :data:`GUI_ENTRY` that the arguments open, with its keyword
    arguments: ``main_in_process`` for ``--in-process`` (the full in-process window),
    else ``main`` (the client window on a server). Raises ValueError for options that
    contradict each other."""
    if args.in_process:
        if args.server is not None:
            raise ValueError("--in-process runs the engine in the GUI and connects to no "
                             "server: drop --server (or --in-process)")
        return "main_in_process", {"bench": args.bench, "out": args.out}
    return "main", {"bench": args.bench, "out": args.out, "server": args.server}


def run(args: argparse.Namespace) -> int:
    if args.stop_server and args.in_process:
        print("error: --stop-server and --in-process: choose one", file=sys.stderr)
        return 2
    if args.stop_server:
        from instrument.client.local import stop_local_server

        print(stop_local_server(args.out or DEFAULT_RUNS_DIR))
        return 0
    try:
        name, kwargs = gui_call(args)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    try:
        app = importlib.import_module(GUI_ENTRY)
    except ImportError as err:
        print(f"error: the GUI cannot start: {err} (install scatterlab with its "
              "dependencies: pip install -e .)", file=sys.stderr)
        return 2
    return int(getattr(app, name)(**kwargs))


def main(argv: list[str] | None = None) -> int:
    """``scatterlab-gui [--server URL | --in-process] [--bench PROFILE] [--out FOLDER]
    [--stop-server]``."""
    parser = argparse.ArgumentParser(prog="scatterlab-gui",
                                     description="The scatterlab operator GUI.")
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
