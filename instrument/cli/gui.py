"""``scatterlab gui``: the operator GUI (also installed as ``scatterlab-gui``).

The GUI package is imported only when this command runs, by name: the command line
never loads Qt for its other commands, and ``instrument`` does not depend on ``gui``
(the packages' layering, docs/architecture.md).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from instrument.run.paths import DEFAULT_RUNS_DIR

HELP = "the operator GUI (bench, camera, plans, runs, analyses)"

#: The GUI's entry point, imported by name when the command runs.
GUI_ENTRY = "gui.app"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("gui", help=HELP)
    add_arguments(p)
    p.set_defaults(func=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bench", default=None,
                   help="bench profile name or path (default: the last one used, or sim)")
    p.add_argument("--out", default=None,
                   help=f"folder for run files and the catalog (default: the last one used, "
                   f"or {DEFAULT_RUNS_DIR})")


def run(args: argparse.Namespace) -> int:
    try:
        app = importlib.import_module(GUI_ENTRY)
    except ImportError as err:
        print(f"error: the GUI cannot start: {err} (install scatterlab with its "
              "dependencies: pip install -e .)", file=sys.stderr)
        return 2
    return int(app.main(bench=args.bench, out=args.out))


def main(argv: list[str] | None = None) -> int:
    """``scatterlab-gui [--bench PROFILE] [--out FOLDER]``."""
    parser = argparse.ArgumentParser(prog="scatterlab-gui",
                                     description="The scatterlab operator GUI.")
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
