"""Installed distributions made on disk for the registry's tests: a ``.dist-info`` folder
with ``METADATA`` and ``entry_points.txt`` and the modules its entry points name, in a
folder put on ``sys.path`` — what ``pip install`` leaves, read by the same
``importlib.metadata`` calls."""

from __future__ import annotations

import itertools
from pathlib import Path

from instrument.bench.driver_registry import ENTRY_POINT_GROUP

_unique = itertools.count()

#: A plugin's module that registers a working power meter: the example plugin's class.
GOOD_MODULE = '''
from instrument.bench.driver_registry import DriverEntry, Option

DRIVER = DriverEntry("power_meter", "example_meter.driver:Em1PowerMeter",
                     options={"reply_timeout": Option(float, 0.01, 10.0)})
'''


def unique(prefix: str) -> str:
    """A module name no other test imports (``sys.modules`` outlives a test)."""
    return f"{prefix}_{next(_unique)}_{id(_unique)}"


def make_dist(root: Path, name: str, version: str, entry_points: dict[str, str],
              modules: dict[str, str] | None = None) -> None:
    """Write distribution ``name`` ``version`` registering ``entry_points`` (driver name →
    ``module:attr``) under the drivers' group, and ``modules`` (module name → source)."""
    info = root / f"{name.replace('-', '_')}-{version}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n",
                                   encoding="utf-8")
    lines = [f"[{ENTRY_POINT_GROUP}]", *(f"{k} = {v}" for k, v in entry_points.items())]
    (info / "entry_points.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
    for module, source in (modules or {}).items():
        (root / f"{module}.py").write_text(source, encoding="utf-8")
