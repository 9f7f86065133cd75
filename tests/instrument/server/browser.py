"""A real Chromium for the dashboard's tests: Debian's ``chromium`` package, driven by
Playwright (never Playwright's own browser download), headless, with a fresh profile.

:func:`chromium_missing` says in one line why the browser tests cannot run here (they
skip with it); CI installs the package (``.ci/run``), so there they always run.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

#: The system's Chromium (``SCATTERLAB_CHROMIUM`` names another).
CHROMIUM = os.environ.get("SCATTERLAB_CHROMIUM") or shutil.which("chromium") or \
    "/usr/bin/chromium"
#: Headless, no sandbox (containers), no GPU, and nothing that talks to the internet.
#: (``--headless`` itself is Playwright's ``headless=True``.)
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
#: Page waits (ms): generous, for a loaded machine; they end as soon as the page is ready.
WAIT_MS = 300_000


def chromium_missing() -> str | None:
    """Why the browser tests cannot run here, or None."""
    if importlib.util.find_spec("playwright") is None:
        return ("dashboard browser tests skipped: Playwright is not installed "
                "(pip install -e '.[dev]')")
    if not Path(CHROMIUM).is_file():
        return ("dashboard browser tests skipped: no Chromium at " + CHROMIUM +
                " (apt-get install chromium chromium-driver; .ci/run does)")
    return None


@contextlib.contextmanager
def chromium(profile_dir: Path) -> Iterator:
    """A browser context with a fresh profile in ``profile_dir``; yields its first page."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            str(profile_dir), executable_path=CHROMIUM, headless=True, args=FLAGS,
            viewport={"width": 1280, "height": 900}, accept_downloads=True)
        context.set_default_timeout(WAIT_MS)
        errors: list[str] = []
        page = context.pages[0] if context.pages else context.new_page()
        page.on("pageerror", lambda err: errors.append(str(err)))
        page.errors = errors
        try:
            yield page
        finally:
            context.close()


def sign_in(page, url: str, key: str | None) -> None:
    """Open the dashboard and sign in with ``key`` (None: a server without keys)."""
    page.goto(url + "/")
    if key is not None:
        page.wait_for_selector("#signin:not([hidden])")
        page.fill("#key", key)
        page.click("#signin-button")
    page.wait_for_selector("#board:not([hidden])")
    wait_live(page)


def wait_live(page) -> None:
    page.wait_for_function("() => document.getElementById('conn').textContent === 'live'",
                           timeout=WAIT_MS)


def wait_run_state(page, state: str) -> None:
    page.wait_for_function(
        "(s) => document.getElementById('run-title').dataset.state === s", arg=state,
        timeout=WAIT_MS)
