"""Checks that emulator modules stay independent of the code they stand in for (ADR 0003).

The import-linter contract in ``pyproject.toml`` guards the packages; this reads the source
itself, so a test fails next to the emulator when someone adds such an import.
"""

from __future__ import annotations

import ast
from pathlib import Path

#: Project packages an emulator must never import.
FORBIDDEN = ("drivers", "instrument", "gui")


def imported_modules(path: Path) -> list[str]:
    """Every module ``path`` imports (``import x``, ``from x import y``)."""
    tree = ast.parse(Path(path).read_text())
    modules = [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    modules += [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    return modules


def assert_imports_nothing_forbidden(*paths: Path) -> None:
    for path in paths:
        bad = [m for m in imported_modules(path) if m.split(".")[0] in FORBIDDEN]
        assert not bad, f"{path} imports {bad}"
