"""The type-checking rules that need no type checker (ADR 0095).

mypy itself runs as a CI step (`.ci/run`): a cold run takes about a minute of CPU, too
long for the default pytest run. What is checked here is cheap: every package ships
``py.typed`` and is in the wheel's package data, and every ``# type: ignore`` names its
error code and says why (on its own line or in a comment line at most four lines above).
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("drivers", "analysis", "instrument", "gui", "hw_mocks")
IGNORE = re.compile(r"#\s*type:\s*ignore(?P<codes>\[[a-z, -]+\])?(?P<rest>.*)$")


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


@pytest.mark.parametrize("package", PACKAGES)
def test_package_ships_py_typed(package: str) -> None:
    assert (ROOT / package / "py.typed").is_file(), f"{package}/py.typed is missing"


def test_py_typed_is_package_data() -> None:
    data = _pyproject()["tool"]["setuptools"]["package-data"]
    assert "py.typed" in data.get("*", []), "package-data must carry py.typed for every package"


def test_mypy_checks_every_package() -> None:
    assert sorted(_pyproject()["tool"]["mypy"]["packages"]) == sorted(PACKAGES)


def _ignores_without_code_or_reason() -> list[str]:
    bad = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            lines = path.read_text(encoding="utf-8").splitlines()
            for i, line in enumerate(lines):
                m = IGNORE.search(line)
                if m is None:
                    continue
                where = f"{path.relative_to(ROOT)}:{i + 1}"
                if not m.group("codes"):
                    bad.append(f"{where}: no error code")
                    continue
                if "#" in m.group("rest"):
                    continue  # the reason follows on the line
                # else the reason is a comment line just above: above this line, above
                # the statement it continues, or above a run of ignores that share it
                above = lines[max(0, i - 4):i]
                if not any(a.lstrip().startswith("#") for a in above):
                    bad.append(f"{where}: no reason")
    return bad


def test_every_type_ignore_has_a_code_and_a_reason() -> None:
    assert _ignores_without_code_or_reason() == []
