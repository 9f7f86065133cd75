"""The system's Chromium, driven by Playwright, for the dashboard's tests and screenshots.

Debian's ``chromium`` package (``apt-get install chromium chromium-driver``; ``.ci/run``
installs it), never Playwright's own browser download. Playwright is a development
dependency (the ``dev`` extra) and is imported only when a browser is opened.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = ["CHROMIUM", "FLAGS", "WAIT_MS", "browser", "chromium_missing", "open_page",
           "sign_in", "wait_live", "wait_run_state"]

#: The system's Chromium (``SCATTERLAB_CHROMIUM`` names another).
CHROMIUM = os.environ.get("SCATTERLAB_CHROMIUM") or shutil.which("chromium") or \
    "/usr/bin/chromium"
#: Headless (Playwright's ``headless=True`` adds ``--headless``), no sandbox (containers),
#: no GPU, and nothing that talks to the internet on its own.
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
#: Page waits (ms): generous, for a loaded machine; they end as soon as the page is ready.
WAIT_MS = 300_000


def chromium_missing() -> str | None:
    """Why a browser cannot be opened here (one line), or None."""
    if importlib.util.find_spec("playwright") is None:
        return ("dashboard browser tests skipped: Playwright is not installed "
                "(pip install -e '.[dev]')")
    if not Path(CHROMIUM).is_file():
        return (f"dashboard browser tests skipped: no Chromium at {CHROMIUM} "
                "(apt-get install chromium chromium-driver; .ci/run does)")
    return None


@contextlib.contextmanager
def browser() -> Iterator[Any]:
    """A Playwright session; yields ``new_page(profile_dir, width=, height=, args=)``, which
    opens a headless Chromium (more flags in ``args``) with a fresh profile in
    ``profile_dir`` (its ``--user-data-dir``) and returns its page (``page.errors``: the
    page's uncaught script errors). Every browser opened is closed at the end."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        contexts = []

        def new_page(profile_dir: str | Path, *, width: int = 1280, height: int = 900,
                     args: tuple[str, ...] = ()) -> Any:
            context = pw.chromium.launch_persistent_context(
                str(profile_dir), executable_path=CHROMIUM, headless=True,
                args=[*FLAGS, *args],
                viewport={"width": width, "height": height}, accept_downloads=True)
            contexts.append(context)
            context.set_default_timeout(WAIT_MS)
            # Any: the page carries its script errors in an added attribute
            page: Any = context.pages[0] if context.pages else context.new_page()
            page.errors = []
            page.on("pageerror", lambda err: page.errors.append(str(err)))
            return page

        try:
            yield new_page
        finally:
            for context in contexts:
                context.close()


@contextlib.contextmanager
def open_page(profile_dir: str | Path, *, width: int = 1280, height: int = 900) -> Iterator[Any]:
    """One page of a fresh headless Chromium (see :func:`browser`)."""
    with browser() as new_page:
        yield new_page(profile_dir, width=width, height=height)


def sign_in(page: Any, url: str, key: str | None) -> None:
    """Open the dashboard at ``url`` and sign in with ``key`` (None: a loopback server
    without keys); returns once the event stream is live."""
    page.goto(url.rstrip("/") + "/")
    if key is not None:
        page.wait_for_selector("#signin:not([hidden])")
        page.fill("#key", key)
        page.click("#signin-button")
    page.wait_for_selector("#board:not([hidden])")
    wait_live(page)


def wait_live(page: Any) -> None:
    page.wait_for_function("() => document.getElementById('conn').textContent === 'live'",
                           timeout=WAIT_MS)


def wait_run_state(page: Any, state: str) -> None:
    """Until the page shows the run in ``state`` (running, paused, finished, ...)."""
    page.wait_for_function(
        "(s) => document.getElementById('run-title').dataset.state === s", arg=state,
        timeout=WAIT_MS)
