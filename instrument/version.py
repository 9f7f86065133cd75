"""The installed scatterlab version, as recorded in run files and printed by the CLI.

The version is the git tag the distribution was built or installed from (setuptools-scm,
ADR 0094): ``1.2.0`` for a tagged commit, ``1.2.1.dev3+g1a2b3c4`` three commits later,
``0.0.0`` for a tree without git metadata. An editable install keeps the version of the
moment it was installed.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

__all__ = ["package_version", "software_version"]


def package_version() -> str:
    """The distribution's version (``1.2.0``), or ``unknown`` when not installed."""
    try:
        return version("scatterlab")
    except PackageNotFoundError:
        return "unknown"


def software_version() -> str:
    """What a run file records as its software: ``scatterlab 1.2.0``."""
    v = package_version()
    return "scatterlab (not installed)" if v == "unknown" else f"scatterlab {v}"
