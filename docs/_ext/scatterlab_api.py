"""The API reference's pages, one per module, written before the build reads its sources.

``api_packages`` in conf.py names the packages and modules the reference covers; each
module gets ``api/generated/<module>.rst`` with an ``automodule`` (its docstring and the
objects defined in it) and, for a package, a table of contents of its submodules. The
pages are written here rather than by autosummary's generator because that one looks a
name up as an attribute of the parent first, and in ``analysis.lightfield`` the name
``reconstruct`` is both a submodule and the function the package re-exports (ADR 0093).
"""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path


def _modules(root: str) -> list[str]:
    module = importlib.import_module(root)
    if not hasattr(module, "__path__"):
        return [root]
    names = [root]
    for info in pkgutil.iter_modules(module.__path__, prefix=f"{root}."):
        names += _modules(info.name) if info.ispkg else [info.name]
    return names


def _page(name: str, subs: list[str]) -> str:
    lines = [name, "=" * len(name), "", f".. automodule:: {name}", ""]
    if subs:
        lines += [".. toctree::", "   :maxdepth: 1", "", *(f"   {s}" for s in subs), ""]
    return "\n".join(lines)


def write_pages(app) -> None:
    out = Path(app.srcdir) / "api" / "generated"
    out.mkdir(parents=True, exist_ok=True)
    wanted: dict[str, str] = {}
    for root in app.config.api_packages:
        for name in _modules(root):
            direct = [m for m in _modules(name) if m != name and "." not in m[len(name) + 1:]]
            wanted[f"{name}.rst"] = _page(name, direct)
    for stale in out.glob("*.rst"):
        if stale.name not in wanted:
            stale.unlink()
    for filename, text in wanted.items():
        path = out / filename
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")  # unchanged pages keep their mtime


def setup(app):
    app.add_config_value("api_packages", [], "env")
    app.connect("builder-inited", write_pages)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
