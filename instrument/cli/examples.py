"""``scatterlab examples list|copy DIR``: the example plans, bench profiles and scripts that
the README and the user guide use, written out where no source tree is at hand.

An installed wheel carries them as the package data ``instrument._examples`` (setup.py
maps the repository's ``examples/`` onto it); a source checkout (an editable install) reads
the repository's ``examples/`` itself. Either way the same files: those matching
:data:`PATTERNS`, which pyproject.toml's package data for ``instrument._examples`` repeats
(``tests/instrument/cli/test_cli_examples.py`` checks that they agree). ADR 0094.
"""

from __future__ import annotations

import argparse
import sys
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

__all__ = ["PATTERNS", "example_files", "examples_source"]

HELP = "list the example plans and profiles, or copy them into a folder (copy DIR)"

#: The example files that travel with the package, relative to the examples folder.
PATTERNS = ("*.toml", "*.json", "*.py", "notebooks/*.ipynb", "scripting/*.py")


class ExamplesNotFound(RuntimeError):
    """Neither the package data nor a source checkout's ``examples/`` is there."""


def examples_source() -> Traversable:
    """Where the examples are read from: the installed package data, else the checkout's
    ``examples/`` beside the ``instrument`` package."""
    packaged = resources.files("instrument") / "_examples"
    if packaged.is_dir():
        return packaged
    checkout = Path(__file__).resolve().parents[2] / "examples"
    if checkout.is_dir():
        return checkout
    raise ExamplesNotFound(
        "examples: neither the package data instrument/_examples nor a source checkout's "
        "examples/ folder was found; reinstall scatterlab from its wheel or the repository")


def _match(name: str, pattern: str) -> bool:
    return Path(name).match(pattern) and name.count("/") == pattern.count("/")


def example_files(source: Traversable | None = None) -> dict[str, Traversable]:
    """The example files by their path relative to the examples folder (``notebooks/…``)."""
    root = examples_source() if source is None else source
    found: dict[str, Traversable] = {}
    for entry in root.iterdir():
        children = ([(f"{entry.name}/{c.name}", c) for c in entry.iterdir()]
                    if entry.is_dir() else [(entry.name, entry)])
        for rel, item in children:
            if item.is_file() and any(_match(rel, p) for p in PATTERNS):
                found[rel] = item
    return dict(sorted(found.items()))


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("examples", help=HELP, description=__doc__.split("\n\n")[0])
    actions = p.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True
    ls = actions.add_parser("list", help="list the example files")
    ls.set_defaults(func=_list)
    cp = actions.add_parser(
        "copy", help="copy the examples into DIR (created if missing), e.g. `examples`")
    cp.add_argument("dir", metavar="DIR", type=Path, help="destination folder")
    cp.add_argument("--force", action="store_true",
                    help="overwrite files that already exist in DIR")
    cp.set_defaults(func=_copy)


def _list(args: argparse.Namespace) -> int:
    for rel in example_files():
        print(rel)
    return 0


def _copy(args: argparse.Namespace) -> int:
    try:
        files = example_files()
    except ExamplesNotFound as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    dest: Path = args.dir
    clashes = [rel for rel in files if (dest / rel).exists()]
    if clashes and not args.force:
        print(f"error: examples: {len(clashes)} file(s) already exist in {dest} "
              f"(first: {dest / clashes[0]}); nothing was copied. Choose another folder "
              "or pass --force to overwrite them", file=sys.stderr)
        return 2
    for rel, item in files.items():
        target = dest / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(item.read_bytes())
    print(f"copied {len(files)} example files into {dest}")
    return 0
