"""The installed scatterlab version, as recorded in run files and printed by the CLI."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

__all__ = ["package_version", "software_version"]


def package_version() -> str:
    """The distribution's version (``0.1.0``), or ``unknown`` when not installed."""
    try:
        return version("scatterlab")
    except PackageNotFoundError:
        return "unknown"


def software_version() -> str:
    """What a run file records as its software: ``scatterlab 0.1.0``."""
    v = package_version()
    return "scatterlab (not installed)" if v == "unknown" else f"scatterlab {v}"
