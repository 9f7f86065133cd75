"""A real Chromium for the dashboard's tests (:mod:`instrument.server.dashboard.chromium`,
shared with the screenshot script): Debian's ``chromium`` driven by Playwright, headless,
with a fresh profile per test. Where it is missing the tests skip with
:func:`chromium_missing`'s one line; CI installs it (``.ci/run``)."""

from __future__ import annotations

from instrument.server.dashboard.chromium import (
    chromium_missing,
    sign_in,
    wait_live,
    wait_run_state,
)
from instrument.server.dashboard.chromium import open_page as chromium

__all__ = ["chromium", "chromium_missing", "sign_in", "wait_live", "wait_run_state"]
