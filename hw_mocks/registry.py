"""Named emulator instances, shared by URL links, pty servers and the virtual bench.

Opening ``simapt://sample_theta`` twice reaches the *same* emulated controller, as
reconnecting a cable reaches the same device: its state (position, homed flag, latched
errors, stale messages) survives. Tests reach the emulator's backdoor (fault injector,
stage mechanics) with :func:`get`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from hw_mocks.emulator import FirmwareEmulator

__all__ = ["all_emulators", "find_world", "get", "get_or_create", "parse_url",
           "register_world_lookup", "remove", "reset"]

_lock = threading.Lock()
_instances: dict[tuple[str, str], FirmwareEmulator] = {}
#: How a device finds the virtual bench its URL names (``world=sim``); installed by
#: :mod:`hw_mocks.sim.world` when it is imported, so devices need not import the world (and
#: no world can exist before that module is).
_world_lookup: Callable[[str], Any] | None = None


def parse_url(url: str) -> tuple[str, str, dict[str, str]]:
    """``scheme://name?k=v&...`` → (scheme, name, options)."""
    parts = urlsplit(url)
    if not parts.scheme or not parts.netloc:
        raise ValueError(f"expected scheme://name[?options], got {url!r}")
    options = dict(parse_qsl(parts.query, keep_blank_values=True))
    return parts.scheme, parts.netloc, options


def get_or_create(
    scheme: str, name: str, factory: Callable[[str, dict[str, str]], FirmwareEmulator],
    options: dict[str, str] | None = None,
) -> FirmwareEmulator:
    """The emulator registered under (scheme, name), created by ``factory`` if new.

    Options apply only when the instance is created (like settings of a device that is
    already powered).
    """
    with _lock:
        key = (scheme, name)
        if key not in _instances:
            _instances[key] = factory(name, dict(options or {}))
        return _instances[key]


def get(scheme: str, name: str) -> FirmwareEmulator:
    with _lock:
        try:
            return _instances[(scheme, name)]
        except KeyError:
            raise KeyError(f"no emulator {scheme}://{name} has been created") from None


def remove(scheme: str, name: str) -> None:
    with _lock:
        _instances.pop((scheme, name), None)


def all_emulators() -> list[FirmwareEmulator]:
    with _lock:
        return list(_instances.values())


def reset() -> None:
    """Forget every instance (power-cycle the whole emulated bench)."""
    with _lock:
        _instances.clear()


def register_world_lookup(lookup: Callable[[str], Any]) -> None:
    """Install the function that finds a virtual bench by name (see ``_world_lookup``)."""
    global _world_lookup
    _world_lookup = lookup


def find_world(name: str) -> Any:
    """The virtual bench called ``name``, or ``None`` if none has been made."""
    return None if _world_lookup is None else _world_lookup(name)
