"""The ``scatterlab`` command line.

Each subcommand lives in its own module with a ``register(subparsers)`` function that adds
its parser and sets ``func`` (called with the parsed arguments, returning an exit code).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from drivers.errors import DeviceError
from instrument.bench.profile import ProfileError
from instrument.version import package_version

__all__ = ["main"]

#: Subcommand modules under instrument.cli, in the order `--help` lists them.
SUBCOMMANDS = ("gui", "devices", "serve_sim", "plan", "run", "resume", "runs", "fit",
               "reconstruct", "locate", "spheres")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="scatterlab",
        description="Lab software for optical scattering: goniometer scans, storage, analysis.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in SUBCOMMANDS:
        importlib.import_module(f"instrument.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
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
