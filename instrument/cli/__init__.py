"""The ``scatterlab`` command line.

Each subcommand lives in its own module with a ``HELP`` line and a ``register(subparsers)``
function that adds its parser and sets ``func`` (called with the parsed arguments,
returning an exit code).

Start-up time: a subcommand module imports only the standard library at module level and
does its heavy imports (HDF5, SciPy, matplotlib, OpenCV, the engine) inside its functions;
and only the subcommand being run is registered in full (the others get a one-line parser
from their ``HELP``), so ``scatterlab --help`` and the parsing of one command load nothing
of the others (``tests/instrument/cli/test_cli_startup.py``).
"""

from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["main"]

#: Subcommand modules under instrument.cli, in the order `--help` lists them.
SUBCOMMANDS = ("gui", "devices", "serve_sim", "plan", "run", "resume", "runs", "fit",
               "reconstruct", "locate", "spheres", "calibrate", "batch", "serve", "queue", "status",
               "watch", "pause", "abort", "control", "manual", "examples")


def _command_of(argv: list[str]) -> str | None:
    """The subcommand named on the command line (its first positional word), if any."""
    for word in argv:
        if not word.startswith("-"):
            return word.replace("-", "_") if word.replace("-", "_") in SUBCOMMANDS else None
    return None


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser; the subcommand named in ``argv`` is registered in full, every other one
    (all of them when ``argv`` names none) only with its help line."""
    from instrument.version import package_version

    parser = argparse.ArgumentParser(
        prog="scatterlab",
        description="Lab software for optical scattering: goniometer scans, storage, analysis.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    wanted = _command_of(sys.argv[1:] if argv is None else argv)
    for name in SUBCOMMANDS:
        module = importlib.import_module(f"instrument.cli.{name}")
        help_line = getattr(module, "HELP", None)
        if name == wanted or help_line is None:
            module.register(sub)
        else:
            sub.add_parser(name.replace("_", "-"), help=help_line)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    from drivers.errors import DeviceError
    from instrument.bench.profile import ProfileError

    try:
        return int(args.func(args) or 0)
    except ProfileError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except DeviceError as err:
        print(f"device error: {err}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
